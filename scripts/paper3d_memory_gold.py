"""tests/gold/paper3d_memory.csv from `make paper3d`'s study: each level's unknowns and the peak
memory its run recorded (VmHWM, MiB), both branches, as the memory guard's test compares with
(tests/test_reliability.py). `make gold` runs it after `make paper3d`; the `source` column
names the summary each row was read from."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BRANCHES = ("paper3d", "paper3d_pressed")  # cases/paper3d.toml from zero, and from the pressed start
GOLD = ROOT / "tests" / "gold" / "paper3d_memory.csv"


def rows(results: Path) -> list[dict[str, object]]:
    table = []
    for branch in BRANCHES:
        summary = results / branch / "summary.json"
        runs = json.loads(summary.read_text())["runs"]
        for n in sorted(runs, key=int):
            table.append({"branch": branch, "n": int(n), "dofs": runs[n]["dofs"],
                          "peak_rss_mb": repr(float(runs[n]["peak_rss_mb"])),
                          "source": str(summary.relative_to(ROOT) if summary.is_relative_to(ROOT) else summary)})
    return table


def main(argv: list[str]) -> int:
    results = Path(argv[0]) if argv else ROOT / "results"
    table = rows(results.resolve())
    with GOLD.open("w", newline="") as out:
        writer = csv.DictWriter(out, fieldnames=list(table[0]))
        writer.writeheader()
        writer.writerows(table)
    print(f"{GOLD.relative_to(ROOT)}: {len(table)} levels")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
