// cases/paper3d.toml's block (0,4) x (0,1) x (0,1) drawn with OpenCASCADE as three boxes
// glued along x = 1 and x = 3, so that the contact part [1,3] x [0,1] x {0} and the loaded
// part [1,3] x [0,1] x {1} are surfaces of their own; gmsh meshes it unstructured.
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 1, 1, 1};
Box(2) = {1, 0, 0, 2, 1, 1};
Box(3) = {3, 0, 0, 1, 1, 1};
BooleanFragments{ Volume{1}; Delete; }{ Volume{2, 3}; Delete; }
e = 1e-6;
ends[] = Surface In BoundingBox{-e, -e, -e, e, 1 + e, 1 + e};
ends[] += Surface In BoundingBox{4 - e, -e, -e, 4 + e, 1 + e, 1 + e};
foundation[] = Surface In BoundingBox{1 - e, -e, -e, 3 + e, 1 + e, e};
pressed[] = Surface In BoundingBox{1 - e, -e, 1 - e, 3 + e, 1 + e, 1 + e};
all[] = CombinedBoundary{ Volume{:}; };
rest[] = all[];
rest[] -= ends[];
rest[] -= foundation[];
rest[] -= pressed[];
Physical Surface("ends") = ends[];
Physical Surface("foundation") = foundation[];
Physical Surface("pressed") = pressed[];
Physical Surface("sides") = rest[];
Physical Volume("BaTiO3") = {1, 2, 3};
