"""The FreeFEM main script of one run: compile-time switches, then the material, then the scheme.

The scheme is specialised at compile time (FreeFEM's IFMACRO): an effect a scene leaves
off is a macro left undefined, so its unknowns, blocks and terms do not exist at all.
Extra macros (a manufactured solution's data, for instance) come in the same way.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from harness.contract import contract_path
from harness.layout import Layout
from harness.schema import LINEAR_SOLVERS
from harness.unknowns import Unknowns


def effect_macro(effect: str) -> str:
    """`electric_contact` -> `effElectricContact` (FreeFEM identifiers have no underscore)."""
    return "eff" + "".join(part.capitalize() for part in effect.split("_"))


def main_script(
    material: str,
    effects: tuple[str, ...],
    layout: Layout,
    element: str = "P1",
    macros: Mapping[str, str] | None = None,
    linear_solver: str = "mumps",
) -> str:
    lines = ["// Written by the harness (harness/script.py); edit the scene, not this file."]
    plugin, name = LINEAR_SOLVERS[linear_solver]
    if plugin:
        # Loading the plugin makes it FreeFEM's `sparsesolver`.
        lines += [f'load "{plugin}"', "macro LINEARSOLVER sparsesolver //", f'string linearSolverName = "{name}";']
    lines += [f"macro {effect_macro(e)} 1 //" for e in effects]
    lines.append(f"macro ELEMENT {element} //")
    lines += Unknowns(tuple(effects)).macros()
    for name, body in (macros or {}).items():
        # "NAME (body)" would read as a macro with parameters; "NAME() (body)" is used bare.
        lines.append(f"macro {name}() ({body}) //")
    # FreeFEM's include takes a literal file name; nested includes resolve next to the includer.
    includes: list[Path] = [contract_path(), layout.material_file(material)]
    if layout.material_reduction_file().is_file():
        includes.append(layout.material_reduction_file())
    includes.append(layout.scheme_file())
    lines += [f'include "{p.resolve()}"' for p in includes]
    return "\n".join(lines) + "\n"
