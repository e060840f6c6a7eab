"""PETSc's options as a scene chooses them (`run.petsc_options`): the measured defaults, and
what the options ask for that the scene must provide (coarser meshes for a geometric
multigrid) or that the memory guard must count (a factorisation). Read by the scene, the
plugin (harness/run/petsc_plugin.py) and the solver study; no PETSc is needed to read them.
"""

from __future__ import annotations


# MUMPS's LU through PETSc, kept as GMRES's preconditioner across Newton steps while it
# serves (freefem/petsc_linear_solver.idp), as MUMPS_seq is; -mat_mumps_icntl_35 2 adds
# block low-rank compression, -mat_mumps_icntl_22 1 puts the factors out of core.
MUMPS_LU = "-ksp_type gmres -pc_type lu -pc_factor_mat_solver_type mumps"


def field_split_options(fields: tuple[str, ...]) -> str:
    """GMRES preconditioned by one block Gauss-Seidel sweep over the fields in order, each
    block by one BoomerAMG V-cycle (one field: BoomerAMG alone)."""
    if len(fields) == 1:
        return "-ksp_type gmres -pc_type hypre"
    blocks = " ".join(f"-fieldsplit_{f}_ksp_type preonly -fieldsplit_{f}_pc_type hypre" for f in fields)
    return f"-ksp_type gmres -pc_type fieldsplit -pc_fieldsplit_type multiplicative {blocks}"


# GMRES (flexible: the smoothers are Krylov methods) preconditioned by one V-cycle of
# geometric multigrid over the scene's nested meshes (run.multigrid_levels coarser ones),
# the levels' operators Galerkin products of the Newton tangent; on each level but the
# coarsest three GMRES iterations with ILU(0) as the smoother, MUMPS's LU on the coarsest.
# Chosen by measurement (docs/solvers.md): 3D h = 1/32 in 3 Newton steps of 3-8 Krylov
# iterations each, in 1.5 GB where a factorisation needs ~35.
MULTIGRID_KRYLOV = "-ksp_type fgmres -pc_type mg -mg_levels_ksp_type gmres -mg_levels_ksp_max_it 3"
MULTIGRID_COARSE = "-mg_coarse_pc_type lu -mg_coarse_pc_factor_mat_solver_type mumps"
# The ILU(0) is the plugin's own (-pc_type ilu0lean, freefem/lean_ilu.hpp): PETSc's ILU(0) in the
# operator's pattern with single-precision values, a third of PETSc's factor (4 bytes an entry
# against 12) for the same Krylov and Newton counts (docs/solvers.md, "Memory at the peak").
MULTIGRID = f"{MULTIGRID_KRYLOV} -mg_levels_pc_type ilu0lean {MULTIGRID_COARSE}"
# The same with PETSc's own ILU(0), the smoother before ilu0lean: the reference it is tested against.
MULTIGRID_PETSC_ILU = f"{MULTIGRID_KRYLOV} -mg_levels_pc_type ilu {MULTIGRID_COARSE}"


# On MPI ranks (run.ranks > 1, freefem/petsc_ranks.idp) the same multigrid over the ranks: an
# ILU is sequential, so each level's smoother is block Jacobi with the lean ILU(0) on each rank's
# block (paper3d h = 1/32 on 2 ranks, against PETSc's ILU there: per-rank peaks 1,340 / 1,297 ->
# 1,152 / 1,116 MiB, the same Krylov counts 5 5 12, 31.9 -> 31.3 s); the coarsest level's LU is
# MUMPS's, parallel.
# The Galerkin products by PETSc's all-at-once algorithm (-matptap_via allatonce), which forms no
# intermediate product A P: paper3d h = 1/32 on 2 ranks, the set-up's raise 382 -> 178 MiB a
# rank, the same Krylov counts.
MULTIGRID_ON_RANKS = (f"{MULTIGRID_KRYLOV} -mg_levels_pc_type bjacobi -mg_levels_sub_pc_type ilu0lean {MULTIGRID_COARSE}"
                      " -matptap_via allatonce")


# Options only a solve across ranks reads: the plugin hands -matptap_via on to the Galerkin
# products of a multigrid over the ranks (freefem/petsc_solver.cpp); the one-rank scheme forms
# its products with PETSc's sequential algorithms, which never read it, and its check of unread
# options would blame it. A level too small for run.ranks runs there without them.
RANKS_ONLY = ("-matptap_via",)


def one_rank_options(options: str) -> str:
    """`options` without RANKS_ONLY's (each with its value), for a level run on one rank."""
    words = options.split()
    kept: list[str] = []
    skip = False
    for i, word in enumerate(words):
        if skip:
            skip = False
            continue
        if word in RANKS_ONLY:
            skip = i + 1 < len(words) and not words[i + 1].startswith("-")
            continue
        kept.append(word)
    return " ".join(kept)


def option_pairs(options: str) -> list[tuple[str, str]]:
    words = options.split()
    return list(zip(words, words[1:]))


def multigrid(options: str) -> bool:
    """Whether PETSc's options ask for geometric multigrid (-pc_type mg, on the Newton
    system or one of its blocks): the run then needs the coarser meshes."""
    return any(a.endswith("pc_type") and b == "mg" for a, b in option_pairs(options))


def factorising(options: str) -> bool:
    """Whether PETSc's options factorise the matrix or a block of it (any -..._pc_type lu or
    cholesky: for the memory guard, a block's factor counts as the whole's, erring high). A
    multigrid's coarse solve (-mg_...) factorises only the coarsest level: not counted."""
    return any(a.endswith("pc_type") and b in ("lu", "cholesky") and not a.startswith("-mg_")
               for a, b in option_pairs(options))


def default_options(dimension: int, fields: tuple[str, ...], ranks: int = 1) -> str:
    """run.petsc_options when blank, chosen by measurement (docs/solvers.md, results/solvers/):
    geometric multigrid in 3D, MUMPS's LU in 2D; on several ranks the distributed multigrid
    in both (docs/scale-out.md), a factorisation of the whole being what ranks are to avoid. The field split with AMG needs 30-300
    Krylov iterations a Newton step once the electric contact conductance couples u_nu to
    phi with its gain k_e/eps_e; multigrid on the whole coupled system, its coarse levels
    Galerkin products of the tangent, sees that coupling on every level. `fields` is the
    seam for choices of their own."""
    if ranks > 1:
        return MULTIGRID_ON_RANKS
    return MULTIGRID if dimension == 3 else MUMPS_LU
