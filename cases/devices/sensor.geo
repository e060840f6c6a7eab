// A force sensor: a PZT-5H disc, poled along its axis z, between two plates. Size: diameter
// 10 mm, thickness 1 mm, the catalogue disc of cases/devices/disc.geo (a typical size, not a
// cited product). Parts: the bottom face is bonded to a rigid earthed base plate (clamped:
// u = 0, phi = 0); the top face carries an electrode left open (floating: its potential is
// the measured voltage, its net charge 0) through which the upper plate presses with a
// uniform pressure (the case's traction); the rim is free. The circle is a regular 32-gon
// (flat faces, so the split levels nest: disc.geo says why). Sizes in metres; lc is the
// coarsest mesh's size (the thickness).
R = 5e-3;        // disc radius
t = 1e-3;        // thickness
N = 32;          // sides of the polygon
lc = t;
For i In {0:N - 1}
  Point(1 + i) = {R * Cos(2 * Pi * i / N), R * Sin(2 * Pi * i / N), 0, lc};
EndFor
For i In {0:N - 1}
  Line(1 + i) = {1 + i, 1 + (i + 1) % N};
EndFor
Curve Loop(1) = {1:N};
Plane Surface(1) = {1};      // the base
Extrude {0, 0, t} { Surface{1}; }
e = 1e-7;
top[] = Surface In BoundingBox{-R - e, -R - e, t - e, R + e, R + e, t + e};
all[] = CombinedBoundary{ Volume{:}; };
rim[] = all[];
rim[] -= top[];
rim[] -= {1};
Physical Surface("base") = {1};
Physical Surface("top_electrode") = top[];
Physical Surface("rim") = rim[];
Physical Volume("PZT-5H") = {Volume{:}};
