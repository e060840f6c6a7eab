#!/usr/bin/env bash
# Installs FreeFEM from Debian's packages when it is missing. Both FreeFEM packages are
# needed: the plugins (gmsh, iovtk, MUMPS_seq) live in libfreefem++. OpenBLAS replaces the
# reference BLAS under MUMPS and UMFPACK (Debian's alternatives): at h = 1/64 the
# factorisation drops from 1.16 s to 0.60 s (results/bench/). libfreefem++-dev brings
# macro_ddm.idp, the mesh decomposition of a solve on MPI ranks (run.ranks > 1,
# freefem/ranks.idp); FreeFem++-mpi, ff-mpirun and OpenMPI come with freefem++.
# libpetsc-real3.18-dev (PETSc 3.18 with hypre, MUMPS, ML; mpicxx comes with it) is what the
# project's PETSc plugin is built against on first use (run.linear_solver = "petsc",
# harness/run/petsc_plugin.py).
set -euo pipefail
have_openblas() { ls /usr/lib/*/openblas-pthread/libblas.so.3 >/dev/null 2>&1; }
DDM=/usr/include/freefem++/idp/macro_ddm.idp
PETSC=/usr/lib/petscdir/petsc-real/include/petscksp.h
if command -v FreeFem++ >/dev/null 2>&1 && [ -f /usr/lib/freefem++/MUMPS_seq.so ] && have_openblas && [ -f "$DDM" ] \
   && [ -f "$PETSC" ] && command -v mpicxx >/dev/null 2>&1; then
  exit 0
fi
bash "$(dirname "$0")/apt-install.sh" freefem++ libfreefem++ libfreefem++-dev libopenblas0-pthread
# --no-install-recommends: PETSc's recommends pull in ~1 GB of documentation and tools.
bash "$(dirname "$0")/apt-install.sh" --no-install-recommends libpetsc-real3.18-dev
command -v FreeFem++ >/dev/null || { echo "error: FreeFem++ still missing after apt-get install" >&2; exit 1; }
[ -f /usr/lib/freefem++/MUMPS_seq.so ] || { echo "error: FreeFEM's MUMPS_seq plugin is missing after apt-get install" >&2; exit 1; }
[ -f "$DDM" ] || { echo "error: $DDM (libfreefem++-dev) is missing after apt-get install" >&2; exit 1; }
[ -f "$PETSC" ] || { echo "error: $PETSC (libpetsc-real3.18-dev) is missing after apt-get install" >&2; exit 1; }
