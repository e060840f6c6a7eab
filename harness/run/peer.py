"""The process boundary to the GetFEM peer (peer_getfem/peer.py, run by Debian's Python): its
input file (the scene's data and the material's values), its launch, its output.

The venv never imports getfem: the peer is a separate process with files in and out, the
way FreeFEM is run. See docs/crosscheck.md."""

from __future__ import annotations

import json
import math
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.core.contract import ROLE_LABELS
from harness.core.errors import PeerMissing, RunError

SYSTEM_PYTHON = "/usr/bin/python3"
PACKAGE = "python3-getfem"
RUNNER = Path(__file__).resolve().parents[2] / "peer_getfem" / "peer.py"

@dataclass(frozen=True)
class PeerRun:
    record: dict[str, Any]  # the peer's output.json
    wall_s: float  # the whole process, as the harness saw it
    peak_rss_mb: float  # the peer's own high-water mark


def require_getfem() -> None:
    """One line naming the package when Debian's Python has no GetFEM."""
    try:
        probe = subprocess.run([SYSTEM_PYTHON, "-c", "import getfem"], capture_output=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired):
        raise PeerMissing(f"{SYSTEM_PYTHON} cannot run: the GetFEM peer needs Debian's Python with {PACKAGE}") from None
    if probe.returncode != 0:
        raise PeerMissing(f"GetFEM is not installed for {SYSTEM_PYTHON}: apt-get install {PACKAGE} (or make getfem)")


def finite(value: Any) -> Any:
    """JSON has no infinity: an unbounded value (L = inf) is written as 1e300, as for FreeFEM."""
    return 1e300 if isinstance(value, float) and math.isinf(value) else value


def problem(table: dict[str, dict[str, Any]], effects: tuple[str, ...], dimension: int, material: dict[str, Any],
            mesh: Path, start: str, pressed_depth: float = 2e-6, poling: tuple[float, ...] | None = None,
            regions: tuple[PeerRegion, ...] = (), plane: str = "strain") -> dict[str, Any]:
    """The peer's input: everything one solve depends on. `table`: the data FreeFEM gets
    (Scene.solver_parameters: sections of effects that are off left out); `material`: the
    material file's values in its own axes, poled along `poling` (None: its own axis 3);
    `regions`: with material regions, each one's cells, values and poling instead;
    `pressed_depth`: how far the pressed start pushes Gamma_3 in, 2 max(eps_e, eps_c) [m]; `plane`: a 2D
    scene's geometry.plane (the peer condenses sigma_22 = 0 out of the material itself)."""
    sections = ("loads", "contact", "electric_contact", "thermal_contact", "newton")
    return {
        "mesh": str(mesh), "dimension": dimension, "labels": dict(ROLE_LABELS), "effects": list(effects),
        "material": material, "poling": None if poling is None else list(poling),
        "regions": [{"label": r.label, "material": r.material, "poling": list(r.poling)} for r in regions],
        "start": start, "pressed_depth": pressed_depth, **({"plane": plane} if plane != "strain" else {}),
        **{s: {k: finite(v) for k, v in table.get(s, {}).items()} for s in sections},
    }


@dataclass(frozen=True)
class PeerRegion:
    """A material region as the peer takes it: its cells' label in the mesh file, the material
    file's values, the unit vector of its poling."""

    label: int
    material: dict[str, Any]
    poling: tuple[float, ...]


def run_peer(spec: dict[str, Any], work: Path, timeout_s: float) -> PeerRun:
    """Write problem.json into `work`, run the peer, read output.json."""
    work.mkdir(parents=True, exist_ok=True)
    (work / "problem.json").write_text(json.dumps(spec, indent=1) + "\n")
    output = work / "output.json"
    output.unlink(missing_ok=True)
    command = [SYSTEM_PYTHON, str(RUNNER), str(work / "problem.json"), str(output)]
    clock = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s,
                              env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    except subprocess.TimeoutExpired:
        raise RunError(f"GetFEM peer timed out after {timeout_s:g} s ({work})") from None
    wall = time.perf_counter() - clock
    (work / "stderr.txt").write_text(done.stderr)
    if done.returncode == 4:
        raise PeerMissing(f"GetFEM is not installed for {SYSTEM_PYTHON}: apt-get install {PACKAGE}")
    if not output.exists():
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise RunError(f"GetFEM peer failed (exit {done.returncode}): {last} ({work})")
    record = json.loads(output.read_text())
    if not record["converged"]:
        raise RunError(f"GetFEM peer did not converge: {record['reason']} after {record['newton_iterations']} "
                       f"Newton iterations ({work})")
    return PeerRun(record, wall, float(record["peak_rss_mb"]))


def pressed_depth(table: dict[str, dict[str, Any]]) -> float:
    """2 max(eps_e, eps_c) of the case, the depth of the pressed start (docs/model.md section 6)."""
    def value(section: str, key: str) -> float:
        # A case without the effect has no value: the start then uses the 1e-6 m that
        # freefem/parameters.idp takes, so both codes start from the same state.
        return float(table.get(section, {}).get(key, 1e-6))

    return 2.0 * max(value("electric_contact", "eps_e"), value("thermal_contact", "eps_c"))
