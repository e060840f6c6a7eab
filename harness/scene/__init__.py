"""The scene: a case file and its `--set` overrides read into a frozen `Scene` (the schema, its
sections, the geometry kinds: rectangle segments, box patches, gmsh drawings), the materials and
their regions and poling, the electrodes, the well-posedness rule, the field list, the linear
solver choices and the manufactured solutions.

May import: `core`.
"""
