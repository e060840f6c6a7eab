"""How far two solutions of one scene are (the branch-stability study, harness/study/stability.py):
each field's relative difference in its norm of E^h (docs/model.md section 7), on the same
nodes or on nodes moved by a jitter (harness/mesh/jitter.py), and the relative difference of
each contact resultant of run.json, each against a floor of what round-off can make of it.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Mapping

import numpy as np

from harness.measure.checks import EPS, QUANTA, ROUNDINGS
from harness.measure.fields import Fields
from harness.measure.norm_table import FIELD_NAMES, measure_of
from harness.measure.norms import P1_INTEGRANDS, error_norms, simplex_seminorm
from harness.mesh.msh import read_msh
from harness.run.record import RunRecord

# Two solutions agree when every field and resultant differs by at most this, relative: 1e4
# times the perturbations (1e-12 of the loads moves a solution by about 1e-12, 1e-9 h of the
# nodes by about 1e-9 h |grad|: measured at most 1e-9, docs/hard-cases.md), far below any
# distance between two branches (the paper's two differ by O(1)).
TOLERANCE = 1e-8
# A difference is relative to the larger of the two values and a floor, the size of what it
# is measured against: a field's norm against 1e-14 of its scale over the body (run.json's
# scales, freefem/scaling.idp; lift_off's theta is 1e-118 K, zero up to round-off); a contact
# resultant against what round-off can make of it, as the physical checks take it
# (harness/measure/checks.py floors: ROUNDINGS eps of the terms its balance sums, QUANTA eps of
# what a contact flow is formed from) over the tolerance, and a force also against the load it
# balances: the bimorph's 3.83 N/m of contact force moves by 4.5e-8 N/m under 1e-12 of its
# load, where its force balance is known to 1000 eps of 3.8e10 N/m, 8.4e-3 N/m; the barely
# touching branch's 3.7e-6 N/m, by 2e-10 under 1e-12 of the 200 N/m it balances.
SCALE_OF = {"u": "U", "phi": "Phi", "theta": "Theta"}
FIELD_FLOOR = 1e-14
RESULTANTS = {"contact_force": "force", "friction_force": "force", "heat_in_contact": "heat",
              "charge_in_contact": "charge"}


def relative(a: float, b: float, floor: float) -> float:
    """|a - b| over the larger of |a|, |b| and `floor` (0 when both are 0 and so is the floor)."""
    size = max(abs(a), abs(b), floor)
    return abs(a - b) / size if size > 0 else 0.0


def norm_of(fields: Fields, values: np.ndarray, name: str) -> float:
    """A field's norm of E^h (V for u, W for phi, Q for theta) on the mesh of `fields`."""
    stem = measure_of(name).stem
    if fields.tetrahedra is not None:
        return simplex_seminorm(fields.points, fields.cells, values, stem)
    return float(np.sqrt(P1_INTEGRANDS[stem](fields.points, fields.triangles, values)))


def body_measure(fields: Fields) -> tuple[float, float]:
    """The body's area (volume in 3D) and its size (the longest side of its bounding box)."""
    d = fields.cells.shape[1] - 1
    corners = fields.points[fields.cells][:, :, :d]
    measure = float(np.abs(np.linalg.det(corners[:, 1:] - corners[:, :1])).sum()) / math.factorial(d)
    return measure, float(np.ptp(fields.points, axis=0).max())


def exact_points(fields: Fields, mesh: Path | None) -> Fields:
    """`fields` on its mesh file's coordinates (double precision), where solution.vtu has them
    in single precision: FreeFEM keeps the file's nodes in their order (checked here, else the
    VTU's are kept). A jittered node moves by 1e-9 h, far below single precision."""
    if mesh is None or not mesh.is_file():
        return fields
    points = read_msh(mesh).points
    size = float(np.ptp(fields.points, axis=0).max())
    if points.shape != fields.points.shape or not np.allclose(points, fields.points, rtol=0, atol=1e-6 * size):
        return fields
    return replace(fields, points=np.asarray(points, dtype=float))


def field_differences(base: Fields, other: Fields, scales: Mapping[str, float]) -> dict[str, float]:
    """Each field's relative difference in its norm: ||f' - f|| / max(||f||, ||f'||, floor),
    the floor FIELD_FLOOR of the field's scale varying over the body's size. On the same
    nodes, node by node; on moved ones (a jittered mesh), f' against f's P1 interpolant at
    them, as the convergence study transfers a level (harness/measure/norms.py error_norms): the
    same function at the same point, where the same node index would compare u at two points
    1e-9 h apart (a slender bender's rotation, 40 times its strain, then shows as 4e-8)."""
    measure, size = body_measure(base)
    same = base.points.shape == other.points.shape and bool((base.points == other.points).all())
    names = [name for name in FIELD_NAMES if name in base.values and name in other.values]
    apart = ({name: norm_of(base, other.field(name) - base.field(name), name) for name in names} if same
             else error_norms(base, other, names))
    out = {}
    for name in names:
        floor = FIELD_FLOOR * scales.get(SCALE_OF[name], 0.0) * math.sqrt(measure) / size
        size_of = max(norm_of(base, base.field(name), name), norm_of(other, other.field(name), name), floor)
        out[name] = apart[name] / size_of if size_of > 0 else 0.0
    return out


def resultant_floor(record: RunRecord, balance: str) -> float:
    """The size below which a resultant of `balance` (force, heat, charge) is round-off, over
    the tolerance: a difference within TOLERANCE of it is what round-off may make."""
    c = record.checks or {}
    if balance == "force":
        load = float(np.linalg.norm(np.asarray(c.get("applied_load") or [0.0], dtype=float)))
        return max(load, ROUNDINGS * EPS * c.get("force_reading", 0.0) / TOLERANCE)
    return max(ROUNDINGS * EPS * c.get(f"{balance}_reading", 0.0),
               QUANTA * EPS * c.get(f"{balance}_contact_reading", 0.0)) / TOLERANCE


def resultant_differences(base: RunRecord, other: RunRecord) -> dict[str, float]:
    out = {}
    for key, balance in RESULTANTS.items():
        a, b = getattr(base, key), getattr(other, key)
        if a is None or b is None:
            continue
        out[key] = relative(float(a), float(b), max(resultant_floor(base, balance), resultant_floor(other, balance)))
    return out
