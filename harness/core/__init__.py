"""The house's tools, which every layer may use and which import nothing of the harness above
them: the integers shared with FreeFEM (`contract`), the error classes and exit codes (`errors`),
signals, faults and atomic writes, the study lock, the results tree (`layout`), the guards on
sizes, memory and disk, and the external programs as processes (FreeFEM, native builds, gmsh's
session). FreeFEM's invocation lives here and not in `run` because the scene asks FreeFEM for a
material's constants before any level is meshed.

May import: nothing of the harness but `core`.
"""
