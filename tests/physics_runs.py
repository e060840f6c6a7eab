"""Run the harness's `solve` in-process into a temporary results tree and load what it wrote."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.cli import main
from harness.fields import Fields, read_fields

DATA = Path(__file__).parent / "data"
CASES = Path(__file__).parents[1] / "cases"


@dataclass(frozen=True)
class Solved:
    record: dict[str, Any]
    fields: Fields


def solve(case: Path, n: int, results: Path, *overrides: str) -> Solved:
    argv = ["solve", str(case), "--n", str(n), "--results", str(results)]
    for item in overrides:
        argv += ["--set", item]
    assert main(argv) == 0, f"solve {case.name} n={n} {overrides} failed"
    name = case.stem  # every case file here names its scene after itself
    for item in overrides:
        if item.startswith("scene.name="):
            name = item.split("=", 1)[1].strip('"')
    directory = results / name / f"n{n}"
    record = json.loads((directory / "run.json").read_text())
    return Solved(record, read_fields(directory / "solution.vtu"))
