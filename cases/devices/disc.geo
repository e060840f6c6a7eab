// A PZT-5H disc, poled along its axis z, electrodes on its two faces, pressed onto a
// conductive pad over a circular area. Size: diameter 10 mm, thickness 1 mm, a common
// catalogue disc (e.g. the 10 x 1 mm discs of the CTS / PI Ceramic ranges); the project's
// stored sources name no specific part, so the size is a typical one, not a cited product.
// Parts: the top face is held by a rigid, earthed fixture (clamped: u = 0, phi = 0); the
// bottom face carries a ring electrode (role electrode) around a central circle of radius
// 3 mm that rests on the pad (the contact part, flat, outward normal -z; its potential comes
// from the pad through the contact conductance); the rim is free.
// The circles are drawn as regular 32-gons (area 0.64 % below the circle's): gmsh's split
// refinement puts the new nodes of a curved face on the curve, so the levels of a true
// cylinder do not nest (a finer level's rim nodes lie outside the coarser mesh); with flat
// faces every coarse tetrahedron is a union of fine ones. Sizes in metres; lc is the
// coarsest mesh's size (the thickness).
R = 5e-3;        // disc radius
t = 1e-3;        // thickness
rc = 3e-3;       // radius of the pad's contact circle
N = 32;          // sides of the polygons
lc = t;
For i In {0:N - 1}
  Point(1 + i) = {R * Cos(2 * Pi * i / N), R * Sin(2 * Pi * i / N), 0, lc};
  Point(101 + i) = {rc * Cos(2 * Pi * i / N), rc * Sin(2 * Pi * i / N), 0, lc};
EndFor
For i In {0:N - 1}
  Line(1 + i) = {1 + i, 1 + (i + 1) % N};
  Line(101 + i) = {101 + i, 101 + (i + 1) % N};
EndFor
Curve Loop(1) = {1:N};
Curve Loop(2) = {101:100 + N};
Plane Surface(1) = {1, 2};   // the electrode ring
Plane Surface(2) = {2};      // the pad's circle
Extrude {0, 0, t} { Surface{1, 2}; }
e = 1e-7;
top[] = Surface In BoundingBox{-R - e, -R - e, t - e, R + e, R + e, t + e};
all[] = CombinedBoundary{ Volume{:}; };
rim[] = all[];
rim[] -= top[];
rim[] -= {1, 2};
Physical Surface("fixture") = top[];
Physical Surface("pad") = {2};
Physical Surface("bottom_electrode") = {1};
Physical Surface("rim") = rim[];
Physical Volume("PZT-5H") = {Volume{:}};
