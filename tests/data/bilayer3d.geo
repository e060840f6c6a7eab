// tests/data/bilayer.geo in 3D: the unit cube cut at z = 1/2 into "lower" and "upper",
// one conforming tetrahedral mesh (the interface is a surface of the mesh at every level).
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 1, 1, 0.5};
Box(2) = {0, 0, 0.5, 1, 1, 0.5};
BooleanFragments{ Volume{1, 2}; Delete; }{}
e = 1e-6;
bottom[] = Surface In BoundingBox{-e, -e, -e, 1 + e, 1 + e, e};
top[] = Surface In BoundingBox{-e, -e, 1 - e, 1 + e, 1 + e, 1 + e};
x0[] = Surface In BoundingBox{-e, -e, -e, e, 1 + e, 1 + e};
x1[] = Surface In BoundingBox{1 - e, -e, -e, 1 + e, 1 + e, 1 + e};
y0[] = Surface In BoundingBox{-e, -e, -e, 1 + e, e, 1 + e};
y1[] = Surface In BoundingBox{-e, 1 - e, -e, 1 + e, 1 + e, 1 + e};
lower[] = Volume In BoundingBox{-e, -e, -e, 1 + e, 1 + e, 0.5 + e};
upper[] = Volume In BoundingBox{-e, -e, 0.5 - e, 1 + e, 1 + e, 1 + e};
Physical Surface("bottom") = bottom[];
Physical Surface("top") = top[];
Physical Surface("sides_x") = {x0[], x1[]};
Physical Surface("sides_y") = {y0[], y1[]};
Physical Volume("lower") = lower[];
Physical Volume("upper") = upper[];
