"""Meshes: one level's mesh file for any scene (the rectangle's, the box's, a gmsh scene's split or
remeshed levels), the general simplex geometry (measures, orientation, facets, quality), the
uniform and the adaptive refinements, and the mesh checks.

May import: `core`, `scene`.
"""
