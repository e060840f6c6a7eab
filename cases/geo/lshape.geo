// The L-shaped domain (-1,1)^2 minus the quadrant (0,1) x (-1,0), the classical known answer of
// adaptive refinement: its re-entrant corner at the origin (interior angle 3 pi / 2) makes the
// harmonic r^(2/3) sin(2 phi / 3) singular there (cases/mms/lshape.toml, lshape_phi.toml), and
// Williams' mode-I displacement too (cases/mms/lshape_u.toml). Two parts: the corner's two faces
// (lines 1 and 6, along phi = 0 and phi = 3 pi / 2), which the displacement case leaves free of
// traction, and the outer four lines. Split levels: every level is nested in the next.
h = 0.5;
Point(1) = {0, 0, 0, h};
Point(2) = {1, 0, 0, h};
Point(3) = {1, 1, 0, h};
Point(4) = {-1, 1, 0, h};
Point(5) = {-1, -1, 0, h};
Point(6) = {0, -1, 0, h};
For i In {1:5}
  Line(i) = {i, i + 1};
EndFor
Line(6) = {6, 1};
Curve Loop(1) = {1:6};
Plane Surface(1) = {1};
Physical Curve("faces") = {1, 6};
Physical Curve("outer") = {2:5};
Physical Surface("body") = {1};
