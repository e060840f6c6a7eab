# Front door. Each target installs what it lacks: FreeFEM from Debian's packages and a
# project venv (.venv) from pyproject.toml's pinned versions, rebuilt when that file changes.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
VENV_STAMP := $(VENV)/.installed
# Every target's prerequisite: the venv, and the harness byte-compiled whenever a source
# changes, as pip compiles an installed package. Each `python -m harness` process then loads
# bytecode instead of compiling ~60 modules (70 ms of a `solve` where the environment sets
# PYTHONDONTWRITEBYTECODE, as on this project's machines; issue 23's overhead).
STAMP := harness/__pycache__/.compiled

.PHONY: convergence scenes test baseline freefem clean-runs
# scenes, stress and branches on a Dask cluster (docs/scale-out.md), e.g.
#   make stress CLUSTER_FLAGS="--cluster local:2"   or   CLUSTER_FLAGS="--scheduler tcp://host:8786"
CLUSTER_FLAGS ?=

convergence: $(STAMP) freefem
	$(PY) -m harness convergence cases/paper.toml

# The paper's block in 3D on both branches, h = 1/2 ... 1/64 against h = 1/64 (PETSc's geometric
# multigrid at the finest levels; h = 1/64 has 5.4 M unknowns and peaks near 11 GB), into
# results/paper3d/ and results/paper3d_pressed/, one branch after the other. A machine whose
# large runs take turns names its lock: make paper3d PAPER3D_LOCK="flock /work/bigmem.lock".
PAPER3D_LOCK ?=
.PHONY: paper3d
paper3d: $(STAMP) freefem
	$(PAPER3D_LOCK) $(PY) -m harness convergence cases/paper3d.toml
	$(PAPER3D_LOCK) $(PY) -m harness convergence cases/paper3d.toml --set scene.coarsest_guess=pressed --set scene.name=paper3d_pressed

# A convergence study of every scene in cases/ and one table of their unknowns, dofs,
# times and slopes (results/scenes/summary.csv). paper3d's study is make paper3d's zero branch,
# to h = 1/64 (~11 GB; its levels are reused when make paper3d has run them).
scenes: $(STAMP) freefem
	$(PY) -m harness scenes $(CLUSTER_FLAGS)

# The suite without its long tests (each marked `heavy`: 10 s or more); make test-heavy runs
# those, make test-all both.
.PHONY: test-heavy test-all
test: $(STAMP) freefem getfem
	$(PY) -m pytest -q -m "not heavy"
	@echo "left out: the tests marked heavy (about 2 min more); run them with make test-heavy, or everything with make test-all"

test-heavy: $(STAMP) freefem getfem
	$(PY) -m pytest -q -m heavy

test-all: $(STAMP) freefem getfem
	$(PY) -m pytest -q

# Gold data: what tests compare with lives in tests/gold/, apart from results/ (which the
# study targets rewrite), and changes only by these targets. Regenerate only for an intended
# change of the scheme, and commit tests/gold/.
# baseline: the fast study the slope-regression test compares with (tests/test_regression.py).
baseline: $(STAMP) freefem
	-$(PY) -m harness convergence cases/paper.toml --levels 2,4,8,16,32 --set scene.name=paper_fast --force --results tests/gold

# gold: the baseline, and the tables that `make verify` (the manufactured errors,
# tests/test_mms.py), `make cost` (peak memory per level, tests/test_reliability.py) and
# `make paper3d` (each 3D level's unknowns and peak memory, both branches, the memory guard's
# test in tests/test_reliability.py) last wrote into results/, pinned as the tests' references.
.PHONY: gold
gold: baseline
	cp results/verification/mms_levels.csv tests/gold/mms_levels.csv
	cp results/cost/scaling.csv tests/gold/scaling.csv
	$(PY) scripts/paper3d_memory_gold.py results

freefem:
	@bash scripts/install-freefem.sh

# GetFEM 5.4 for Debian's Python (python3-getfem): the cross-check's second code only.
.PHONY: getfem crosscheck
getfem:
	@bash scripts/install-getfem.sh

# FreeFEM against the GetFEM peer (issue 21, docs/crosscheck.md): the paper's scene in 2D and
# 3D on both branches, then every scene of cases/ and cases/hard/ at its coarse levels (up
# to n = 8 in 2D, 4 in 3D), field by field, into results/crosscheck/ (crosscheck.csv, .md,
# .png). Exit 6 when a field differs by more than 1e-8 relative, naming field and level.
# Every law, material region, poling and floating electrode of the scenes is in the peer.
crosscheck: $(STAMP) freefem getfem
	$(PY) -m harness crosscheck cases/paper.toml cases/paper3d.toml --branches zero,pressed --out results/crosscheck/paper
	$(PY) -m harness crosscheck $(wildcard cases/*.toml cases/hard/*.toml)

# The paper's Figs. 2-3 from both codes side by side with their difference (deformed mesh,
# von Mises stress, phi, theta): the paper's scene at h = 1/64 and its 3D block at h = 1/8
# (mid-plane y = 1/2), both branches, into results/paper/figures/ (~10 min on 2 cores).
.PHONY: paper-figures
paper-figures: $(STAMP) freefem getfem
	$(PY) -m harness crosscheck cases/paper.toml --levels 64 --branches zero,pressed --figures results/paper/figures --out results/paper/figures/h64
	$(PY) -m harness crosscheck cases/paper3d.toml --levels 8 --branches zero,pressed --figures results/paper/figures --out results/paper/figures/3d_h8

$(VENV_STAMP): pyproject.toml
	bash scripts/make-venv.sh $(PYTHON) $(VENV)

$(STAMP): $(VENV_STAMP) $(wildcard harness/*.py harness/*/*.py)
	$(PY) -m compileall -q harness
	touch $@

# Per-level run folders (good, failed, half-swapped) and meshes; not the committed
# CSV/JSON/PNG baseline.
clean-runs:
	find results -mindepth 2 -maxdepth 3 -type d \( -name 'n[0-9]*' -o -name meshes -o -name '.tmp-*' -o -name '.old-*' \) -exec rm -rf {} +

# docs/modules.md, generated from the code's layers and docstrings (a test fails when stale).
.PHONY: modules-doc
modules-doc: $(STAMP)
	$(PY) scripts/modules_doc.py

# Adaptive refinement driven by the error estimate (docs/adaptivity.md): the paper's scene,
# the strip actuator and the disc on its pad (3D), each against its uniform levels, and the
# singular known answers on the L-shaped domain (temperature, potential, displacement) against
# their exact fields, into results/adapt/<case>/. The disc's reference (~800k dofs, multigrid
# over the adapted steps) peaks near 2.6 GB.
.PHONY: adapt
adapt: $(STAMP) freefem
	$(PY) -m harness adapt cases/paper.toml --steps 40 --max-dofs 30000
	$(PY) -m harness adapt cases/strip_actuator.toml --steps 40 --max-dofs 30000
	$(PY) -m harness adapt cases/mms/lshape.toml --steps 40 --max-dofs 40000
	$(PY) -m harness adapt cases/mms/lshape_phi.toml --steps 40 --max-dofs 40000
	$(PY) -m harness adapt cases/mms/lshape_u.toml --steps 40 --max-dofs 40000
	$(PY) -m harness adapt cases/disc_pad.toml --steps 40 --max-dofs 100000

# Goal-oriented error estimates (docs/goals.md): each goal's dual-weighted estimate against the
# exact value of the manufactured solutions (2D n = 4..32, 3D n = 2..8) and Richardson's value on
# the paper's scene (both branches, n = 4..32) and the strip actuator (n = 2..16), into
# results/goals/ (effectivity.csv, effectivity.md); then adaptive refinement marked by a goal's
# indicators beside uniform levels, the paper's heat through the contact (zero branch, uniform
# n = 4..64) and the strip actuator's electrode charge (n = 2..32), into adapt.csv and adapt.md.
# About 3 + 2 minutes on one core.
.PHONY: goals
goals: $(STAMP) freefem
	$(PY) -m harness goals
	$(PY) -m harness goals --adapt

# Verification beyond self-convergence (issue 6): true errors of the manufactured cases
# (cases/mms/, h = 1/4 ... 1/32) and the three-grid GCI of the paper's scene (its runs are
# reused when cached), into results/verification/ and results/paper/gci.csv.
.PHONY: verify
verify: $(STAMP) freefem
	$(PY) -m harness verify --levels 4,8,16,32

# The stress suite (issue 4): every case of cases/hard/ on its levels, each converged or
# failing with a classified reason, with the physical checks, into results/stress/
# (summary.csv, summary.md), and the paper scene's Newton iterations per level
# (paper_iterations.csv). Exits 1 on an unexpected failure or a failed check.
.PHONY: stress branches
stress: $(STAMP) freefem
	$(PY) -m harness stress $(CLUSTER_FLAGS)

# Branch stability: every hard case (as its file asks, and from its coarsest start alone) and
# every scene of cases/ at one level (n = 8 in 2D, 4 in 3D), then five more times with its loads
# scaled by 1 +- a few 1e-12 or its interior nodes jittered by 1e-9 h; each against the
# unperturbed solve, to 1e-8 in every field's norm and contact resultant, status and checks,
# into results/stability/ (stability.csv, stability.md, sensitive.json; ~5 min on 2 cores).
# Exits 1 when a case is branch-sensitive and not documented so (docs/hard-cases.md).
.PHONY: stability
stability: $(STAMP) freefem
	$(PY) -m harness stability

# Both solution branches of the paper's scene, from zero and from the pressed start, each a
# convergence study on levels 2 ... 64, into results/branches/ (branches.csv, branches.md);
# then the same for the paper drawn in gmsh, into results/branches_paper_gmsh/ (equal to the
# paper's table to its digits).
branches: $(STAMP) freefem
	$(PY) -m harness branches $(CLUSTER_FLAGS)
	$(PY) -m harness branches cases/paper_gmsh.toml $(CLUSTER_FLAGS)

# What accuracy costs (issue 5): P1, P2, P1 with a loose Newton tolerance, P1 on a mesh
# graded towards the ends of Gamma_3 and P1 on the adaptive loop's meshes (docs/adaptivity.md),
# against one P2 reference (h = 1/64); the P1 chain on
# to h = 1/256 for time and memory against dofs; into results/cost/ (cost.csv, fits.csv,
# frontier.md/.csv, scaling.csv, PNGs; ~5 min).
# Cached runs keep their old timings: COST_FLAGS=--force reruns every level.
# `make bench` repeats the timings that matter (finest level alone, the sweep, the CLI, and
# `python -m harness solve CASE --n FINEST --force` as a whole process beside its own FreeFEM
# run: `process`) five times, medians and min-max, into results/bench/ (bench.csv, bench.md); it waits
# (up to 20 min) for a 1-minute load below 1.2 first. Then FreeFEM beside the GetFEM peer
# (docs/crosscheck.md): the paper's scene at h = 1/64 and its 3D block at h = 1/8, both from
# zero, as whole processes, the two codes alternating, medians of 5 and their ratio per phase,
# into results/bench/getfem/ (timing.md, timing.csv).
.PHONY: cost bench budget
cost: $(STAMP) freefem
	$(PY) -m harness cost cases/paper.toml $(COST_FLAGS)

# The error budget (docs/cost.md): each quantity's error at n = 16 in its mesh, penalty and
# Newton parts, beside their wall times, for the paper's scene on both branches and the strip
# actuator, into results/budget/<case>/ (budget.csv, budget.md).
budget: $(STAMP) freefem
	$(PY) -m harness budget cases/paper.toml --n 16 --set scene.name=paper_zero
	$(PY) -m harness budget cases/paper.toml --n 16 --set scene.coarsest_guess=pressed --set scene.name=paper_pressed
	$(PY) -m harness budget cases/strip_actuator.toml --n 16

bench: $(STAMP) freefem getfem
	$(PY) -m harness bench cases/paper.toml $(BENCH_FLAGS)
	$(PY) -m harness solvers $(SOLVERS_FLAGS)
	$(PY) -m harness crosscheck cases/paper.toml --levels 64 --repeat 5 --out results/bench/getfem/2d
	$(PY) -m harness crosscheck cases/paper3d.toml --levels 8 --repeat 5 --out results/bench/getfem/3d

# The mesh of a 3D level made and written (the Kuhn box at h = 1/32, the disc on its pad split
# from gmsh's tetrahedra at h = 1/8: generator, checks, MSH file), five times, medians, into
# results/bench/mesh/<case>/ (bench.csv, bench.md). Like make bench it first waits for a quiet
# machine (BENCH_MESH_FLAGS="--max-load 100" does not).
.PHONY: bench-mesh
bench-mesh: $(STAMP)
	$(PY) -m harness bench cases/paper3d.toml --only mesh --levels 32 --results results/bench/mesh/paper3d $(BENCH_MESH_FLAGS)
	$(PY) -m harness bench cases/disc_pad.toml --only mesh --levels 8 --results results/bench/mesh/disc_pad $(BENCH_MESH_FLAGS)

# The solver table alone (issue 20): MUMPS_seq, UMFPACK64, PETSc field split + AMG, PETSc MUMPS
# with and without BLR, PETSc geometric multigrid, on the paper scene at h = 1/64 and its 3D block at h = 1/16 (medians of
# 3), into results/solvers/. Larger points: SOLVERS_FLAGS="--points paper:256,paper3d:32".
# Then the direct solvers at 2D h = 1/256 (results/solvers/h256/), and the rank table: the paper scene at h = 1/64 on 1, 2, 4, 8 MPI ranks (GMRES iterations
# of one-level Schwarz; oversubscribed past the cores), results/solvers/ranks.csv.
.PHONY: solvers
solvers: $(STAMP) freefem
	$(PY) -m harness solvers $(SOLVERS_FLAGS)
	$(PY) -m harness solvers --points paper:256 --only mumps,petsc-mumps,petsc-mumps-blr --results results/solvers/h256
	$(PY) -m harness solvers --ranks 1,2,4,8
	$(MAKE) multigrid

# Geometric multigrid (issue 20): against MUMPS_seq and PETSc's MUMPS in one run at 2D h = 1/64
# and 3D h = 1/16 (results/solvers/multigrid/), then alone where no factorisation fits: 3D
# h = 1/32 (702,405 dofs, medians of 3) and 2D h = 1/512 (4.2 M dofs, once), into
# results/solvers/h32/ and results/solvers/h512/ (~20 min).
.PHONY: multigrid
multigrid: $(STAMP) freefem
	$(PY) -m harness solvers --points paper:64,paper3d:16 --only mumps,petsc-mumps,petsc-mg --results results/solvers/multigrid
	$(PY) -m harness solvers --points paper3d:32 --only petsc-mg --results results/solvers/h32
	$(PY) -m harness solvers --points paper:512 --only petsc-mg --repeats 1 --results results/solvers/h512

# Where a 3D solve's time and memory go (docs/solvers.md, "Profile"): the paper's block at
# h = 1/16, three runs alone from the chain below, each piece's CPU seconds, share and peak,
# into results/solvers/profile3d.csv and .md (~2 min). With h = 1/32 (~10 min, ~2 GB):
#   make profile3d PROFILE_FLAGS="--levels 16,32"
.PHONY: profile3d
profile3d: $(STAMP) freefem
	$(PY) -m harness profile cases/paper3d.toml --levels 16 $(PROFILE_FLAGS)

# Past one machine (issue 15): the paper scene solved on 1 and 2 MPI ranks, in 2D and 3D
# (time, Krylov iterations, per-rank memory, agreement), the 3D paper scene with PETSc across
# 1, 2, 4 and 8 ranks (3 runs each, medians), and the stress suite in this process against
# local Dask clusters of 1 and 2 workers, each started and warmed before the suite is timed
# (5 runs each, medians), into results/scale/ (mpi.csv, mpi3d.csv, petsc3d_n<N>.csv,
# stress.csv, scale.md). Small sizes by default; on an idle machine:
#   make scale SCALE_FLAGS="--mpi-levels 64,256 --mpi-3d-levels 8,16 --stress-levels="
# PETSc alone at h = 1/16, and at 1/32 on 1 and 2 ranks (4 GB a run: on a shared machine under a lock):
#   make scale SCALE_FLAGS="--parts petsc3d --petsc-3d-levels 16"
#   flock LOCKFILE make scale SCALE_FLAGS="--parts petsc3d --petsc-3d-levels 32 --petsc-ranks 1,2 --repeats 1"
.PHONY: scale
scale: $(STAMP) freefem
	$(PY) -m harness scale $(SCALE_FLAGS)
