// The unit cube turned by 30 degrees about the axis (1, 1, 0) through the origin: its face
// z = 0, the contact part, gets the outward normal R (0, 0, -1) (tests/test_gmsh.py). Parts
// are picked by bounding box before the turn; their tags survive it.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 1, 1, 1};
e = 1e-6;
base[] = Surface In BoundingBox{-e, -e, -e, 1 + e, 1 + e, e};
top[] = Surface In BoundingBox{-e, -e, 1 - e, 1 + e, 1 + e, 1 + e};
all[] = Boundary{ Volume{1}; };
sides[] = all[];
sides[] -= base[];
sides[] -= top[];
Rotate {{1, 1, 0}, {0, 0, 0}, Pi / 6} { Volume{1}; }
Physical Surface("base") = base[];
Physical Surface("top") = top[];
Physical Surface("sides") = sides[];
Physical Volume("cube") = {1};
