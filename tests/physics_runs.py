"""Run the harness's `solve` in-process into a temporary results tree and load what it wrote."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from harness.cli import main
from harness.measure.fields import Fields, read_fields
from harness.run.record import RunRecord, read_run_json

DATA = Path(__file__).parent / "data"
CASES = Path(__file__).parents[1] / "cases"


@dataclass(frozen=True)
class Solved:
    record: RunRecord
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
    record = read_run_json(directory)
    assert record is not None
    return Solved(record, read_fields(directory / "solution.vtu"))
