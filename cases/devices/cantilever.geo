// The tutorial's first device (docs/tutorial.md): a PZT-5H cantilever, 20 mm long and 1 mm
// thick, in its length-thickness section (x along the beam, y the thickness and poling axis),
// plane strain. Its first 2 mm are held in an earthed clamp (top and bottom faces); the rest
// of the bottom face is the ground electrode, the top face the driven electrode from 0.5 mm
// past the clamp (an unelectroded margin keeps the driven electrode off the earthed clamp:
// a point on both would be held at two potentials). The free end x = 20 mm meets a
// conductive stop (the contact part, outward normal +x).
// Sizes in metres. lc: the coarsest mesh's cell (half the thickness, two cells through it);
// the transfinite strips make right triangles that the split levels nest.
L = 20e-3;       // length
t = 1e-3;        // thickness
a = 2e-3;        // clamped length
m = 0.5e-3;      // unelectroded margin on the top face past the clamp
lc = t / 2;
Point(1) = {0, 0, 0};
Point(2) = {a, 0, 0};
Point(3) = {a + m, 0, 0};
Point(4) = {L, 0, 0};
Point(5) = {L, t, 0};
Point(6) = {a + m, t, 0};
Point(7) = {a, t, 0};
Point(8) = {0, t, 0};
Line(1) = {1, 2};    // bottom, clamped
Line(2) = {2, 3};    // bottom, ground electrode under the margin
Line(3) = {3, 4};    // bottom, ground electrode
Line(4) = {4, 5};    // free end, against the stop
Line(5) = {5, 6};    // top, driven electrode
Line(6) = {6, 7};    // top, margin
Line(7) = {7, 8};    // top, clamped
Line(8) = {8, 1};    // base
Line(9) = {2, 7};    // inner lines between the strips (unlabelled: inside the body)
Line(10) = {3, 6};
Curve Loop(1) = {1, 9, 7, 8};
Plane Surface(1) = {1};
Curve Loop(2) = {2, 10, 6, -9};
Plane Surface(2) = {2};
Curve Loop(3) = {3, 4, 5, -10};
Plane Surface(3) = {3};
Transfinite Curve{1, 7} = Round(a / lc) + 1;
Transfinite Curve{2, 6} = Round(m / lc) + 1;
Transfinite Curve{3, 5} = Round((L - a - m) / lc) + 1;
Transfinite Curve{4, 8, 9, 10} = Round(t / lc) + 1;
Transfinite Surface{1} = {1, 2, 7, 8};
Transfinite Surface{2} = {2, 3, 6, 7};
Transfinite Surface{3} = {3, 4, 5, 6};

Physical Curve("clamp") = {1, 7};
Physical Curve("ground_electrode") = {2, 3};
Physical Curve("free_end") = {4};
Physical Curve("driven_electrode") = {5};
Physical Curve("margin") = {6};
Physical Curve("base") = {8};
Physical Surface("PZT-5H") = {1, 2, 3};
