// The benchmark of Ouafik (2019) section 4.2, cases/paper.toml, drawn in gmsh: the block
// (0,4) x (0,1) in three vertical strips x in [0,1], [1,3], [3,4], so that the contact part
// [1,3] x {0} and the loaded part [1,3] x {1} are curves of their own. Each strip is a
// transfinite surface cut along its SW-NE diagonals with h = 1/2, which is cases/paper.toml's
// mesh at n = 2; gmsh's split refinement of it is paper's mesh at n = 4, 8, ...
h = 0.5;
xs[] = {0, 1, 3, 4};
For i In {0:3}
  Point(1 + i) = {xs[i], 0, 0};
  Point(5 + i) = {xs[i], 1, 0};
EndFor
For i In {0:2}
  Line(1 + i) = {1 + i, 2 + i};        // bottom
  Line(4 + i) = {6 + i, 5 + i};        // top, right to left
EndFor
For i In {0:3}
  Line(7 + i) = {1 + i, 5 + i};        // verticals, upwards
EndFor
For i In {0:2}
  Curve Loop(1 + i) = {1 + i, 8 + i, 4 + i, -(7 + i)};
  Plane Surface(1 + i) = {1 + i};
  Transfinite Curve{1 + i, 4 + i} = Round((xs[i + 1] - xs[i]) / h) + 1;
  Transfinite Surface{1 + i} = {1 + i, 2 + i, 6 + i, 5 + i} Right;
EndFor
Transfinite Curve{7:10} = Round(1 / h) + 1;

Physical Curve("ends") = {7, 10};             // x = 0 and x = 4
Physical Curve("foundation") = {2};           // [1,3] x {0}
Physical Curve("bottom_free") = {1, 3};
Physical Curve("pressed") = {5};              // [1,3] x {1}
Physical Curve("top_free") = {4, 6};
Physical Surface("BaTiO3") = {1, 2, 3};
