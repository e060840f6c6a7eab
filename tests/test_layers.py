"""The package's folders are its layers (harness/__init__.py): the import graph, drawn from the
code itself, has no cycle and no module imports from a layer above its own. Imports inside
functions and under TYPE_CHECKING count as well: a lazy import is still a dependency."""

from __future__ import annotations

import ast
import graphlib
import subprocess
import sys
from pathlib import Path

import pytest

from harness import LAYERS

HARNESS = Path(__file__).parents[1] / "harness"
# Modules beside the folders: the arguments the studies share sit with the studies.
BESIDE = {"harness.arguments": "studies", "harness.cli": None, "harness.__main__": None, "harness": None}


def module_name(path: Path) -> str:
    parts = path.relative_to(HARNESS.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """Every harness module `path` imports, at any depth of its code."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("harness")}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("harness"):
            # `from harness.core import errors` names a module; `from harness.core.errors import X` a name in one.
            found |= {f"{node.module}.{a.name}" for a in node.names} | {node.module}
    return found


def graph() -> dict[str, set[str]]:
    modules = {module_name(p): p for p in HARNESS.rglob("*.py")}
    return {name: {m for m in imports(path) if m in modules and m != name} for name, path in modules.items()}


def layer(module: str) -> int:
    folder = BESIDE[module] if module in BESIDE else module.split(".")[1]
    return len(LAYERS) if folder is None else LAYERS.index(folder)


def test_every_module_lives_in_a_layer_folder_or_is_an_entry_point():
    for module in graph():
        assert module in BESIDE or module.split(".")[1] in LAYERS, f"{module} is in no layer folder"


def test_no_module_imports_from_a_layer_above_its_own():
    upward = [f"{a} imports {b}" for a, deps in graph().items() for b in sorted(deps)
              if not b.startswith(a + ".") and layer(b) > layer(a)]
    assert not upward, "\n".join(upward)


def test_the_import_graph_has_no_cycle():
    # A package's own __init__ is not an import of its modules (Python runs it first either way).
    edges = {a: {b for b in deps if not a.startswith(b + ".") and not b.startswith(a + ".")}
             for a, deps in graph().items()}
    graphlib.TopologicalSorter(edges).prepare()  # raises CycleError naming the cycle


def test_the_checks_find_what_they_look_for(tmp_path, monkeypatch):
    """Both checks fail on a package built to break them: an upward import and a cycle."""
    fake = tmp_path / "harness"
    for folder in ("core", "scene"):
        (fake / folder).mkdir(parents=True)
        (fake / folder / "__init__.py").write_text("")
    (fake / "__init__.py").write_text("")
    (fake / "core" / "low.py").write_text("from harness.scene.high import x\n")
    (fake / "scene" / "high.py").write_text("def f():\n    from harness.core import low\n")
    monkeypatch.setattr(__import__(__name__), "HARNESS", fake)
    with pytest.raises(AssertionError, match="harness.core.low imports harness.scene.high"):
        test_no_module_imports_from_a_layer_above_its_own()
    with pytest.raises(graphlib.CycleError):
        test_the_import_graph_has_no_cycle()


def test_the_module_map_is_what_the_code_says():
    """docs/modules.md is generated from the folders and the docstrings; a moved, added or
    re-described module without `make modules-doc` fails here."""
    done = subprocess.run([sys.executable, str(HARNESS.parent / "scripts" / "modules_doc.py"), "--check"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
