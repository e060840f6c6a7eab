// A PZT-5H strip actuator in its length-thickness section (x along the strip, y the
// thickness and poling axis), plane strain. Dimensions of the piezo bender MTP35x2.1x0.7
// (Rphotronics, "Piezo Bender" product page, rphotronics.com/b/product05/1536): 35 mm long,
// 0.7 mm thick, an actuating length of 28 mm, the remaining 7 mm the non-actuating region
// "used for fixation". That product is two PZT layers on a metal shim; the harness has one
// material per scene, so the strip is modelled as ONE PZT-5H body of the same outline: a
// d31 extender, not a bender (no shim, no second layer).
// Parts: the first 7 mm of the bottom face is mounted (clamped, earthed); the rest of the
// bottom face is the ground electrode, the top face over the actuating length the driven
// electrode (an unelectroded margin over the mount keeps it away from the earthed clamp);
// the tip face x = 35 mm meets a conductive stop (the contact part, outward normal +x).
// Sizes in metres. lc: the coarsest mesh's cell (half the thickness); the transfinite
// strips make right triangles that gmsh's split refinement nests.
L = 35e-3;       // length
t = 0.7e-3;      // thickness
a = 7e-3;        // mounted (non-actuating) length
lc = t / 2;
Point(1) = {0, 0, 0};
Point(2) = {a, 0, 0};
Point(3) = {L, 0, 0};
Point(4) = {L, t, 0};
Point(5) = {a, t, 0};
Point(6) = {0, t, 0};
Line(1) = {1, 2};   // bottom, mounted
Line(2) = {2, 3};   // bottom, ground electrode
Line(3) = {3, 4};   // tip
Line(4) = {4, 5};   // top, driven electrode
Line(5) = {5, 6};   // top, margin
Line(6) = {6, 1};   // base
Line(7) = {2, 5};   // inner line between the two strips (unlabelled: inside the body)
Curve Loop(1) = {1, 7, 5, 6};
Plane Surface(1) = {1};
Curve Loop(2) = {2, 3, 4, -7};
Plane Surface(2) = {2};
Transfinite Curve{1, 5} = Round(a / lc) + 1;
Transfinite Curve{2, 4} = Round((L - a) / lc) + 1;
Transfinite Curve{3, 6, 7} = Round(t / lc) + 1;
Transfinite Surface{1} = {1, 2, 5, 6};
Transfinite Surface{2} = {2, 3, 4, 5};

Physical Curve("mount") = {1};
Physical Curve("ground_electrode") = {2};
Physical Curve("tip") = {3};
Physical Curve("driven_electrode") = {4};
Physical Curve("margin") = {5};
Physical Curve("base") = {6};
Physical Surface("PZT-5H") = {1, 2};
