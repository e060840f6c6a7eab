"""The constants the law uses, asked of FreeFEM itself: a material file included as a run
includes it, with freefem/material.idp's checks, reduction and (for a rotated poling) its
rotation, printed to 17 digits. Manufactured data (harness/scene/mms.py) and material regions
(harness/scene/regions.py) take their values from here, so nothing in Python repeats a material.
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path

from harness.core import freefem
from harness.core.contract import Failure
from harness.core.errors import RunError, SceneError
from harness.core.layout import Layout

# How long FreeFEM may take to read a material file and print its constants (measured: well under
# a second, FreeFEM's start-up included): a file that takes longer loops.
READ_TIMEOUT_S = 60.0
# The 2D constants material.idp derives (its section 6; plane strain or plane stress, section 4c).
CONSTANTS = ("f11", "f13", "f33", "f44", "e31", "e33", "e15", "b11", "b33",
             "m11", "m33", "p1", "p3", "k11", "k33")
# The out-of-plane constants of the 3D law (freefem/constitutive.idp, material.idp).
CONSTANTS_3D = ("fC12", "fC22", "fC23", "f2323", "f1212", "e24", "e32", "b22", "m22", "p2", "k22")
# The other entries of a set rotated to a scene's poling axis (freefem/material.idp, "Poling"):
# C_IJ and e_kI as above, beta_kl and k_kl (k < l), m_I; present only for a rotated poling.
ROTATED_ELASTIC = {(1, 4): "gC14", (1, 5): "gC15", (1, 6): "gC16", (2, 4): "gC24", (2, 5): "gC25", (2, 6): "gC26",
                   (3, 4): "gC34", (3, 5): "gC35", (3, 6): "gC36", (4, 5): "gC45", (4, 6): "gC46", (5, 6): "gC56"}
ROTATED_PIEZO = {(1, 1): "ge11", (1, 2): "ge12", (1, 3): "ge13", (1, 4): "ge14", (1, 6): "ge16",
                 (2, 1): "ge21", (2, 2): "ge22", (2, 3): "ge23", (2, 5): "ge25", (2, 6): "ge26",
                 (3, 4): "ge34", (3, 5): "ge35", (3, 6): "ge36"}
ROTATED_PERMITTIVITY = {(1, 2): "gb12", (1, 3): "gb13", (2, 3): "gb23"}
ROTATED_CONDUCTIVITY = {(1, 2): "gk12", (1, 3): "gk13", (2, 3): "gk23"}
ROTATED_STRESS_TEMPERATURE = {4: "gm4", 5: "gm5", 6: "gm6"}
ROTATED = (tuple(ROTATED_ELASTIC.values()) + tuple(ROTATED_PIEZO.values()) + tuple(ROTATED_PERMITTIVITY.values())
           + tuple(ROTATED_CONDUCTIVITY.values()) + tuple(ROTATED_STRESS_TEMPERATURE.values()))


def material_constants(material: str, layout: Layout, poling: tuple[tuple[str, str], ...] = (),
                       dimension: int = 2, plane: str = "strain") -> dict[str, float]:
    """`poling`: the scene's poling macros (harness/scene/poling.py), empty for the default axis;
    `plane`: a 2D scene's geometry.plane ("stress": the plane-stress reduction of material.idp)."""
    return dict(_constants(str(layout.material_file(material).resolve()),
                           str(layout.material_reduction_file().resolve()), poling, dimension, plane))


@functools.cache
def _constants(material_file: str, reduction_file: str, poling: tuple[tuple[str, str], ...] = (),
               dimension: int = 2, plane: str = "strain") -> tuple[tuple[str, float], ...]:
    """Include the material as a run does, print the constants of the 2D law (plane strain or
    plane stress) and the 3D one to 17 digits (and, for a rotated poling, the rotated set's
    other entries)."""
    includes = [material_file] + [reduction_file] * Path(reduction_file).is_file()
    names = CONSTANTS + CONSTANTS_3D + ROTATED * bool(poling)
    stress = plane == "stress"
    lines = [f"macro DIMENSION {dimension} //"] * (bool(poling) or stress) + [f"macro {k}() ({v}) //" for k, v in poling]
    lines += ["macro PLANESTRESS() (1) //"] * stress
    lines += [f'include "{p}"' for p in includes] + ["cout.precision(17);"]
    lines += [f'cout << "{k} " << {k} << endl;' for k in names]
    with tempfile.TemporaryDirectory(prefix="ff-material-") as tmp:
        script = Path(tmp) / "constants.edp"
        script.write_text("\n".join(lines) + "\n")
        outcome = freefem.invoke(freefem.command(script, []), Path(tmp), timeout_s=READ_TIMEOUT_S)
        text = (Path(tmp) / "stdout.txt").read_text(errors="replace")
    values = dict(line.split() for line in text.splitlines() if len(line.split()) == 2)
    code = outcome.returncode
    if code == 0 and not set(names) - set(values):
        return tuple((k, float(values[k])) for k in names)
    # The script is the material file and material.idp, the harness's own: what stops it is the
    # material's doing (bad input, exit 2), but a signal from outside (an OOM kill, say).
    if code is not None and (code < 0 or freefem.shell_signal(code)):
        raise RunError(f"FreeFEM could not print the constants of {material_file}: "
                       f"{freefem.failure_reason(outcome, READ_TIMEOUT_S, '')}", freefem.failure_of(outcome))
    if code is None:
        why = (f"FreeFEM did not finish reading it: timed out after {READ_TIMEOUT_S:g} s (a file of constants "
               "reads in well under a second; does it loop?)")
    elif code == Failure.INVALID_MATERIAL.code:  # material.idp's one line
        said = next((line for line in text.splitlines() if line.startswith("error: material ")), "")
        why = said.removeprefix("error: ") or "refused"
    elif code == 0:
        why = "FreeFEM ended before it printed the constants, with exit code 0 (does the file call exit?)"
    else:
        reason = freefem.EXIT_REASONS.get(code, f"FreeFEM exited with code {code}")
        why = f"{reason}: {freefem.error_detail(text) or 'no detail'}"
    raise SceneError(f"invalid material file {material_file}: {why}")
