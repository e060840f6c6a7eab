// A series bimorph bender in its length-thickness section (x along the bender, y the
// thickness and poling axis), plane strain: two PZT-5H layers bonded to a brass shim.
// The part: Piezo Systems T220-H4-103X, decoded by the maker's part-number key (Piezo
// Systems Inc., "Explanation of part numbers for piezoelectric benders and extenders",
// piezo.com/prodauxpartno2.html): T unmounted, 2 piezo layers, thickness designation 20 =
// 0.020" (0.508 mm) overall, H4 = PSI-5H4E (a PZT-5H type), blank = brass centre shim,
// -103 = 1.25" x 0.125" (31.75 x 3.175 mm), X = poled for 2-wire series operation.
// Layers: the 0.0075" (0.1905 mm) piezo plates of a series-poled bender (BJ Ultrasonic,
// "What is the process of attaching a bender element?", bjultrasonic.com/piezoceramics-faqs),
// so the shim is 0.020" - 2 x 0.0075" = 0.005" (0.127 mm): derived, not printed by the maker.
// The width (3.175 mm) is the plane-strain direction; the model is per metre of width.
// Chosen here (not from a source): the clamp holds the first 3.75 mm (free length 28 mm),
// both electrodes leave a 0.5 mm margin past the clamp (a point on the earthed clamp and the
// driven electrode would hold two potentials) and stop 1 mm before the tip, where the top
// face is the unelectroded pad that meets the stop.
// Parts: bottom and top faces held in an earthed clamp over [0, a]; the driven electrode
// under the lower layer and the ground electrode over the upper one, over [a+m, L-c]; the
// margins and the underside of the tip free; the pad [L-c, L] on top the contact part
// (outward normal +y); the end faces free. Regions lower, shim, upper: the case file maps
// them to materials and poling directions.
// Sizes in metres. Every piece is a transfinite rectangle cut along its diagonals into
// right triangles that gmsh's split refinement nests; the coarsest mesh has one cell through
// each layer and cells 0.25 mm long.
L = 31.75e-3;     // length
tp = 0.1905e-3;   // each piezo layer
ts = 0.127e-3;    // brass shim
a = 3.75e-3;      // clamped length
m = 0.5e-3;       // unelectroded margin past the clamp
c = 1e-3;         // unelectroded pad at the tip, against the stop
dx = 0.25e-3;     // the coarsest cell's length
X[] = {0, a, a + m, L - c, L};
Y[] = {0, tp, tp + ts, 2 * tp + ts};
// Point (i, j) = 1 + i + 5 j; horizontal line (i, j) = 100 + 10 j + i from point (i, j) to
// (i+1, j); vertical line (i, j) = 200 + 10 j + i from point (i, j) to (i, j+1); the
// rectangle (i, j) = 300 + 10 j + i.
For j In {0:3}
  For i In {0:4}
    Point(1 + i + 5 * j) = {X[i], Y[j], 0};
  EndFor
EndFor
For j In {0:3}
  For i In {0:3}
    Line(100 + 10 * j + i) = {1 + i + 5 * j, 2 + i + 5 * j};
    Transfinite Curve{100 + 10 * j + i} = Round((X[i + 1] - X[i]) / dx) + 1;
  EndFor
EndFor
For j In {0:2}
  For i In {0:4}
    Line(200 + 10 * j + i) = {1 + i + 5 * j, 6 + i + 5 * j};
    Transfinite Curve{200 + 10 * j + i} = 2;   // one cell through each layer
  EndFor
EndFor
For j In {0:2}
  For i In {0:3}
    Curve Loop(300 + 10 * j + i) = {100 + 10 * j + i, 201 + 10 * j + i, -(110 + 10 * j + i), -(200 + 10 * j + i)};
    Plane Surface(300 + 10 * j + i) = {300 + 10 * j + i};
    Transfinite Surface{300 + 10 * j + i} = {1 + i + 5 * j, 2 + i + 5 * j, 7 + i + 5 * j, 6 + i + 5 * j};
  EndFor
EndFor

Physical Curve("clamp") = {100, 130};
Physical Curve("margin") = {101, 131};
Physical Curve("driven_electrode") = {102};
Physical Curve("ground_electrode") = {132};
Physical Curve("underside") = {103};
Physical Curve("pad") = {133};
Physical Curve("base") = {200, 210, 220};
Physical Curve("end") = {204, 214, 224};
Physical Surface("lower") = {300:303};
Physical Surface("shim") = {310:313};
Physical Surface("upper") = {320:323};
