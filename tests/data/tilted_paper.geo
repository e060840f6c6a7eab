// cases/geo/paper.geo turned by 30 degrees about the origin: the paper's scene with its
// contact part [1,3] x {0} on a tilted line, outward normal (sin 30, -cos 30).
Include "../../cases/geo/paper.geo";
Rotate {{0, 0, 1}, {0, 0, 0}, Pi / 6} { Surface{1:3}; }
