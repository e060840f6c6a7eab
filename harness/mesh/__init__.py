"""Meshes: one level's mesh file for any scene (the rectangle's, the box's, a gmsh scene's split or
remeshed levels), each generator returning the one mesh record (`SimplexMesh`) that the one MSH
2.2 writer writes; the general simplex geometry (measures, orientation, facets, role measures,
quality), the uniform and the adaptive refinements, and the mesh checks.

May import: `core`, `scene`.
"""
