"""One FreeFEM run of one level: its main script, its options, the PETSc plugin and the MPI shim, the
launch on one or several ranks, the content key of its cache, and the typed record of its
run.json (`record`, run.json's only reader); also the GetFEM peer's run.

May import: `core`, `scene`, `mesh`.
"""
