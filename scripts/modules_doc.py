"""docs/modules.md from the code: each layer's folder with its `__init__` docstring, each module
with the first sentence of its own. `python scripts/modules_doc.py` rewrites the page;
`--check` exits 1 when the page is stale (tests/test_layers.py runs it)."""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

from harness import LAYERS

ROOT = Path(__file__).resolve().parents[1]
HARNESS = ROOT / "harness"
PAGE = ROOT / "docs" / "modules.md"
ENTRY_POINTS = ("__main__.py", "cli.py", "arguments.py")

HEAD = """# The harness, one line per module

[← README](../README.md)

Generated from the code by `python scripts/modules_doc.py` (`make modules-doc`); a test fails
when it is stale. The package's folders are its layers, in the order the data flows:
scene → mesh → FreeFEM run → parsed fields → norms → study → report. A module imports only
from its own layer and the layers before it, and the import graph has no cycle
(tests/test_layers.py draws it from the code).

    core → scene → mesh → run → measure → study → report → studies, cli
"""

TAIL = """## Layout of the repository (data flows one way)

```
cases/*.toml        scenes: geometry, boundary parts, material, effects, loads, contact data,
                    study; cases/hard/ the stress suite, cases/mms/ manufactured solutions
harness/            the Python package, in the layer folders above
freefem/            solve.edp and scheme.idp, the one umbrella for one rank and N MPI ranks,
                    which includes the pieces in order, each with an include guard: the options
                    (parameters, every one), the integers shared with Python (contract), the
                    backend (one_rank, or on ranks ranks and parallel_newton: the mesh, the
                    solve, the reductions, the gather), the only place 2D or 3D enters
                    (dimension), the laws (constitutive, contact, friction, forms: one varf per
                    block), the Newton loop and its pieces, the checks, the estimator, the output;
                    freefem/materials/ one file per material, checked by material.idp
peer_getfem/        the GetFEM peer, run by Debian's Python (python3-getfem)
results/            study outputs (the study targets rewrite them; no test reads them)
tests/              pytest; tests/gold/ the references they compare with (make baseline, make gold)
```
"""


def docstring(path: Path) -> str:
    return ast.get_docstring(ast.parse(path.read_text())) or ""


def first_sentence(text: str) -> str:
    paragraph = " ".join(text.split("\n\n")[0].split())
    match = re.search(r"(?<!e\.g)(?<!i\.e)(?<!\bvs)\.(\s|$)", paragraph)
    return paragraph[: match.start() + 1] if match else paragraph


def table(paths: list[Path], folder: str) -> list[str]:
    rows = ["| module | what it does |", "|---|---|"]
    for path in paths:
        text = first_sentence(docstring(path)).replace("|", "\\|") or "(no docstring)"
        rows.append(f"| `{folder}{path.name}` | {text} |")
    return rows


def page() -> str:
    out = [HEAD]
    out += ["## Entry points", ""]
    out += table([HARNESS / name for name in ENTRY_POINTS], "") + [""]
    for layer in LAYERS:
        folder = HARNESS / layer
        intro = " ".join(docstring(folder / "__init__.py").split())
        out += [f"## `{layer}/`", "", intro, ""]
        out += table(sorted(p for p in folder.glob("*.py") if p.name != "__init__.py"), f"{layer}/") + [""]
    out.append(TAIL)
    return "\n".join(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/modules.md is not what the code says")
    args = parser.parse_args()
    text = page()
    if args.check:
        if PAGE.read_text() != text:
            print(f"{PAGE} is stale: run python scripts/modules_doc.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
