// tests/data/bilayer.geo drawn in millimetres (2 x 1 mm, the interface at 0.5 mm): its cells
// (3e-8 m^2 at the coarsest level) are below gmshload's area threshold, so every level is
// read by freefem/dimension.idp's own reader (tests/test_regions.py).
s = 1e-3;
t1 = 0.5 * s;
Point(1) = {0, 0, 0}; Point(2) = {2 * s, 0, 0}; Point(3) = {2 * s, t1, 0}; Point(4) = {0, t1, 0};
Point(5) = {2 * s, s, 0}; Point(6) = {0, s, 0};
Line(1) = {1, 2};  // bottom
Line(2) = {2, 3};  // right, lower
Line(3) = {4, 3};  // interface
Line(4) = {1, 4};  // left, lower
Line(5) = {3, 5};  // right, upper
Line(6) = {6, 5};  // top
Line(7) = {4, 6};  // left, upper
Curve Loop(1) = {1, 2, -3, -4};
Plane Surface(1) = {1};
Curve Loop(2) = {3, 5, -6, -7};
Plane Surface(2) = {2};
Transfinite Curve{1, 3, 6} = 9;
Transfinite Curve{2, 4, 5, 7} = 3;
Transfinite Surface{1} = {1, 2, 3, 4} Right;
Transfinite Surface{2} = {4, 3, 5, 6} Right;

Physical Curve("bottom") = {1};
Physical Curve("top") = {6};
Physical Curve("sides") = {2, 4, 5, 7};
Physical Surface("lower") = {1};
Physical Surface("upper") = {2};
