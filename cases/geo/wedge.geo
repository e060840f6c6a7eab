// A trapezoid, 4 wide at its base and 3 at its top, 1 high, standing on its base and turned
// by 10 degrees about the origin: the contact part [1,3] of the base has the outward normal
// (sin 10, -cos 10); the slanted ends are clamped; the middle of the top [1.5, 2.5] is
// loaded. gmsh meshes it unstructured at each level (geometry.levels = "remesh").
alpha = 10 * Pi / 180;
Point(1) = {0, 0, 0};
Point(2) = {1, 0, 0};
Point(3) = {3, 0, 0};
Point(4) = {4, 0, 0};
Point(5) = {3.5, 1, 0};
Point(6) = {2.5, 1, 0};
Point(7) = {1.5, 1, 0};
Point(8) = {0.5, 1, 0};
For i In {1:7}
  Line(i) = {i, i + 1};
EndFor
Line(8) = {8, 1};
Curve Loop(1) = {1:8};
Plane Surface(1) = {1};
Rotate {{0, 0, 1}, {0, 0, 0}, alpha} { Surface{1}; }
Physical Curve("ends") = {4, 8};
Physical Curve("base_contact") = {2};
Physical Curve("base_free") = {1, 3};
Physical Curve("top_loaded") = {6};
Physical Curve("top_free") = {5, 7};
Physical Surface("body") = {1};
