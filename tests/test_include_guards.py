"""Every FreeFEM piece has an include guard: a scheme that includes each piece twice
compiles and gives the same run as the scheme that includes it once (issue 13, item 4)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

from harness.cli import main
from harness.core.layout import REPO

PIECES = sorted(p.relative_to(REPO / "freefem") for p in (REPO / "freefem").rglob("*.idp"))


def test_every_piece_has_a_guard():
    unguarded = [str(p) for p in PIECES
                 if not re.search(r"^IFMACRO\(!(\w+)\)\nmacro \1 1 //", (REPO / "freefem" / p).read_text(), re.M)]
    assert not unguarded, f"no include guard in {unguarded}"


def doubled_tree(tmp_path: Path) -> Path:
    """A copy of freefem/ whose scheme.idp includes every piece twice or more."""
    tree = tmp_path / "freefem"
    shutil.copytree(REPO / "freefem", tree)
    scheme = tree / "scheme.idp"
    text = re.sub(r'^(include "[^"]+"\n)', r"\1\1", scheme.read_text(), flags=re.M)
    # Each piece twice in a row where the scheme includes it; then, at the end, every piece
    # again, the ones main.edp includes before the scheme and the scheme itself among them.
    again = "".join(f'include "{p}"\n' for p in PIECES)
    body, guard_end = text.rsplit("ENDIFMACRO", 1)
    scheme.write_text(body + again + "ENDIFMACRO" + guard_end)
    assert text.count("include") >= 2 * 15
    return tree


def solve(results: Path, *argv: str) -> dict:
    assert main(["solve", str(REPO / "cases" / "paper.toml"), "--n", "2", "--results", str(results), *argv]) == 0
    return json.loads((results / "paper" / "n2" / "run.json").read_text())


def test_including_every_piece_twice_changes_nothing(tmp_path):
    once = solve(tmp_path / "once")
    twice = solve(tmp_path / "twice", "--freefem", str(doubled_tree(tmp_path)))
    for key in ("newton_iterations", "residuals", "max_abs_u", "max_phi", "max_theta", "contact_force", "checks"):
        assert twice[key] == once[key], key
