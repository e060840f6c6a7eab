"""A material file: where it is (a library name or a path), what it holds, whether it is valid.

A scene's `material` is a name of the library `freefem/materials/<Name>.idp` or a path to a
file of the same format (freefem/materials/TEMPLATE.idp.txt), relative to the case file. Its
check runs before anything is meshed or solved, and a bad file ends with exit 2 (INPUT) and
one line naming the file and the entry. The rules have one home each:

- the file's syntax (every tensor a macro of plain, finite numbers, as the GetFEM peer reads
  them; a `materialName` equal to the file's name) is read here;
- the physics (presence, shapes, symmetry, magnitudes, positive definiteness, the plane-strain
  reduction) is freefem/material.idp's, run by FreeFEM on the file alone
  (harness/scene/material_constants.py), as every solve runs it.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from harness.core.errors import SceneError
from harness.core.layout import Layout
from harness.scene.material_constants import material_constants

# The material tensors: macro name -> key of the peer's input and symbol of an entry
# (docs/model.md section 8).
MATERIAL_MACROS = {"materialC": "C", "materialE": "e", "materialBeta": "beta", "materialK": "k",
                   "materialM": "m", "materialP": "p", "materialAlpha": "alpha"}
MACRO = re.compile(r"^\s*macro\s+(material\w+)\s+(.*?)//", re.MULTILINE | re.DOTALL)
NAME = re.compile(r'^\s*string\s+materialName\s*=\s*"([^"]*)"', re.MULTILINE)
# An array literal's innermost [...] rows, the decimal numbers in an entry, and any word left.
ROW = re.compile(r"\[([^\[\]]*)\]")
NUMBER_IN = re.compile(r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
WORD = re.compile(r"[A-Za-z_]\w*")
# FreeFEM's include statement, and its comments (an include in a comment includes nothing).
INCLUDE = re.compile(r'^[ \t]*include[ \t]+"([^"]+)"', re.MULTILINE)
COMMENT = re.compile(r"/\*.*?\*/|//[^\n]*", re.DOTALL)


def check(path: Path, layout: Layout) -> None:
    """Every rule, before anything is meshed or run; one SceneError line naming the file.
    Without freefem/material.idp (a stand-in solver with no material rules) only the name is
    checked."""
    text = read(path)
    name = NAME.search(text)
    if name and name.group(1) != path.stem:
        raise SceneError(f"invalid material file {path}: materialName {name.group(1)!r} differs from the file's "
                         f"name {path.stem!r} (rename one of them)")
    if not layout.material_reduction_file().is_file():
        return
    if not name:
        raise SceneError(f"invalid material file {path}: no materialName "
                         f"(add: string materialName = \"{path.stem}\";)")
    for macro, body in MACRO.findall(text):  # what FreeFEM cannot name: nan, inf, 1e999, words
        if macro in MATERIAL_MACROS:
            check_entries(path, macro, body)
    material_constants(str(path.resolve()), layout)  # material.idp's rules, run by FreeFEM


def read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError as exc:
        raise SceneError(f"invalid material file {path}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise SceneError(f"invalid material file {path}: not a text file") from None


def values(path: Path) -> dict[str, Any]:
    """The 3D tensors of a material file: C, e, beta, k, p and m (or m = C alpha when the file
    gives the expansion alpha), each entry a plain finite number."""
    found: dict[str, Any] = {}
    for name, body in MACRO.findall(read(path)):
        if name in MATERIAL_MACROS:
            found[MATERIAL_MACROS[name]] = tensor(path, name, body)
    if "alpha" in found:
        found["m"] = (np.array(found.pop("alpha"), float) @ np.array(found["C"], float).T).tolist()
    missing = [macro for macro, key in MATERIAL_MACROS.items() if key not in found and key not in ("m", "alpha")]
    if "m" not in found:
        missing.append("materialM or materialAlpha")
    if missing:
        raise SceneError(f"invalid material file {path}: no macro {missing[0]}")
    return found


def tensor(path: Path, name: str, body: str) -> Any:
    """A macro's array literal as nested lists (plain numbers only: the GetFEM peer's reader)."""
    check_entries(path, name, body)
    try:
        return json.loads(body.strip())
    except ValueError:
        raise SceneError(f"invalid material file {path}: {name} is not an array of plain numbers "
                         "([...] or [[...], ...]; the GetFEM peer reads no arithmetic)") from None


def check_entries(path: Path, name: str, body: str) -> None:
    """Each entry of a macro's array literal is a finite number or arithmetic of such numbers
    (730 * 8.8541878e-12); a word (nan, inf) or an overflow (1e999) is named by its symbol
    and Voigt indices (C11, p3), as material.idp names entries."""
    rows = ROW.findall(body)
    nested = len(rows) > 1 or body.strip().startswith("[[")
    for i, row in enumerate(rows):
        for j, entry in enumerate(row.split(",")):
            words = WORD.findall(NUMBER_IN.sub(" ", entry))
            if words or not all(math.isfinite(float(x)) for x in NUMBER_IN.findall(entry)):
                where = f"{MATERIAL_MACROS[name]}{i + 1}{j + 1}" if nested else f"{MATERIAL_MACROS[name]}{j + 1}"
                raise SceneError(f"invalid material file {path}: {name} entry {where} = {entry.strip()} "
                                 "is not a finite number")


def included_files(path: Path) -> tuple[Path, ...]:
    """Every file a material file includes, and every file those include, recursively (each
    once, resolved; the file itself left out): what a run reads of a material besides the file,
    so that the cache's key covers it (harness/run/cache.py). A relative name is looked up next
    to the file that includes it. FreeFEM 4.9 looks there only one level down (a file included
    by a relative name has its own relative includes looked up in the run's folder, a temp dir,
    and in FreeFEM's own idp folder, which its version in the key stands for), so this may key
    a file FreeFEM does not read: that costs a rerun, never a stale result. A name found nowhere
    (FreeFEM's own idp files, or a missing file FreeFEM will name) is left out."""
    own = path.resolve()
    found: dict[Path, None] = {}
    todo = [own]
    while todo:
        current = todo.pop()
        try:
            text = COMMENT.sub("", current.read_text(errors="replace"))
        except OSError:
            continue
        for name in INCLUDE.findall(text):
            try:
                candidate = (current.parent / name).resolve()  # an absolute name stays itself
            except RuntimeError:  # a loop of symbolic links (Python < 3.13): FreeFEM cannot open it either
                continue
            if candidate != own and candidate not in found and candidate.is_file():
                found[candidate] = None
                todo.append(candidate)
    return tuple(found)
