# Front door. Each target installs what it lacks: FreeFEM from Debian's packages and a
# project venv (.venv) from pyproject.toml's pinned versions, rebuilt when that file changes.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: convergence scenes test baseline freefem clean-runs

convergence: $(STAMP) freefem
	$(PY) -m harness convergence cases/paper.toml

# A convergence study of every scene in cases/ and one table of their unknowns, dofs,
# times and slopes (results/scenes/summary.csv).
scenes: $(STAMP) freefem
	$(PY) -m harness.scenes

test: $(STAMP) freefem
	$(PY) -m pytest -q

# The fast study the slope-regression test compares with (tests/test_regression.py).
# Regenerate only for an intended change of the scheme, and commit results/paper_fast/.
baseline: $(STAMP) freefem
	-$(PY) -m harness convergence cases/paper.toml --levels 2,4,8,16,32 --set scene.name=paper_fast --force

freefem:
	@bash scripts/install-freefem.sh

$(STAMP): pyproject.toml
	bash scripts/make-venv.sh $(PYTHON) $(VENV)

# Per-level run folders (good, failed, half-swapped) and meshes; not the committed
# CSV/JSON/PNG baseline.
clean-runs:
	find results -mindepth 2 -maxdepth 2 -type d \( -name 'n[0-9]*' -o -name meshes -o -name '.tmp-*' -o -name '.old-*' \) -exec rm -rf {} +

# Verification beyond self-convergence (issue 6): true errors of the manufactured cases
# (cases/mms/, h = 1/4 ... 1/32) and the three-grid GCI of the paper's scene (its runs are
# reused when cached), into results/verification/ and results/paper/gci.csv.
.PHONY: verify
verify: $(STAMP) freefem
	$(PY) -m harness.verify --levels 4,8,16,32
