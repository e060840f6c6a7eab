// The 2 x 1 x 1 box of cases/mms/contact3d.toml drawn with OpenCASCADE and turned by 10
// degrees about the axis (1, 1, 0) through the origin, so that no face normal is a
// coordinate axis: the contact part (the face z = 0 before the turn) gets the outward normal
// R (0, 0, -1). gmsh meshes it unstructured at h = 1/2; the levels are split from there.
// Parts are picked by bounding box before the turn; their tags survive it.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 2, 1, 1};
e = 1e-6;
ends[] = Surface In BoundingBox{-e, -e, -e, e, 1 + e, 1 + e};
ends[] += Surface In BoundingBox{2 - e, -e, -e, 2 + e, 1 + e, 1 + e};
base[] = Surface In BoundingBox{-e, -e, -e, 2 + e, 1 + e, e};
top[] = Surface In BoundingBox{-e, -e, 1 - e, 2 + e, 1 + e, 1 + e};
all[] = Boundary{ Volume{1}; };
sides[] = all[];
sides[] -= ends[];
sides[] -= base[];
sides[] -= top[];
Rotate {{1, 1, 0}, {0, 0, 0}, 10 * Pi / 180} { Volume{1}; }
Physical Surface("ends") = ends[];
Physical Surface("base") = base[];
Physical Surface("top") = top[];
Physical Surface("sides") = sides[];
Physical Volume("box") = {1};
