// tests/data/block.toml's free 2 x 1 block turned by 30 degrees about the origin: its
// contact face is the segment from (0, 0) to (2 cos 30, 2 sin 30), outward normal
// (sin 30, -cos 30). Structured (transfinite) at h = 1/2, refined by split.
alpha = Pi / 6;
Point(1) = {0, 0, 0};
Point(2) = {2, 0, 0};
Point(3) = {2, 1, 0};
Point(4) = {0, 1, 0};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
Transfinite Curve{1, 3} = 5;
Transfinite Curve{2, 4} = 3;
Transfinite Surface{1} = {1, 2, 3, 4} Right;
Rotate {{0, 0, 1}, {0, 0, 0}, alpha} { Surface{1}; }
Physical Curve("base") = {1};
Physical Curve("top") = {3};
Physical Curve("sides") = {2, 4};
Physical Surface("block") = {1};
