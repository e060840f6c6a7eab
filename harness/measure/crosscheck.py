"""FreeFEM against the GetFEM peer on one level: the per-field relative differences in the
norms of docs/model.md section 7 (V for u, W for phi, Q for theta) and at the nodes, and the
contact integrals of both codes. See docs/crosscheck.md."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from harness.core.errors import FieldsError
from harness.measure.fields import Fields
from harness.measure.norm_table import measure_of
from harness.measure.norms import simplex_seminorm
from harness.run.record import RunRecord
from harness.scene.unknowns import FIELDS

# Above this relative difference the two codes disagree (issue 21): both solve the same
# discrete equations to Newton's tolerance 1e-9 per field, so what remains is round-off.
TOLERANCE = 1e-8
# Contact integrals compared: run.json key -> the peer's key (the same names).
INTEGRALS = ("contact_force", "heat_in_contact", "charge_in_contact")


@dataclass(frozen=True)
class FieldDifference:
    norm: float  # ||FreeFEM - GetFEM|| in the field's norm
    relative: float  # ... over ||FreeFEM||
    max_nodal: float  # max |FreeFEM - GetFEM| at the nodes
    relative_nodal: float  # ... over max |FreeFEM|


def matched(reference: np.ndarray, points: np.ndarray) -> np.ndarray:
    """For each reference point, the index of the same point in `points` (the same mesh,
    numbered differently). FreeFEM's VTU stores points in single precision, so points match
    to 1e-6 of the mesh's extent."""
    extent = max(float(np.ptp(reference, axis=0).max()), 1e-300)
    d = reference.shape[1]
    key = lambda p: np.lexsort(np.round(p[:, :d] / extent * 1e6).T[::-1])  # noqa: E731
    a, b = key(reference), key(points[:, :d])
    order = np.empty(len(reference), dtype=int)
    order[a] = b
    if len(points) != len(reference) or np.abs(points[order, :d] - reference).max() > 1e-5 * extent:
        raise FieldsError("the GetFEM peer's nodes are not FreeFEM's: not the same mesh")
    return order


# A field both codes leave at zero (theta with the contact open and no source) is compared
# against this fraction of its scale (run.json "scales": U, Phi, Theta) instead of its own
# size, which is round-off (1e-300) and would turn equal noise into a huge ratio.
ZERO_FIELD = 1e-14
# run.json "scales" key of each field (U, Phi, Theta).
SCALE_OF = {f.name: f.scale for f in FIELDS}


def differences(fields: Fields, peer: dict[str, Any], names: tuple[str, ...],
                scales: dict[str, float]) -> tuple[dict[str, FieldDifference], np.ndarray]:
    """Per field, FreeFEM's solution minus the peer's, on FreeFEM's cells with the peer's
    (double precision) coordinates; relative to the field's size, or to ZERO_FIELD times its
    scale (per unit measure of the body) when that is larger."""
    d = fields.cells.shape[1] - 1
    scalar_nodes = np.array(peer["points"], float)
    order = matched(fields.points[:, :d], scalar_nodes)
    points = scalar_nodes[order]
    edges = points[fields.cells][:, 1:, :d] - points[fields.cells][:, :1, :d]
    measure = float(np.abs(np.linalg.det(edges)).sum()) / math.factorial(d)
    out = {}
    for name in names:
        if name == "u":
            theirs = np.array(peer["u"], float)[matched(fields.points[:, :d], np.array(peer["u_points"], float))]
            ours = fields.field("u")[:, :d]
        else:
            theirs, ours = np.array(peer[name], float)[order], fields.field(name)
        floor = ZERO_FIELD * float(scales.get(SCALE_OF[name], 1.0))
        stem = measure_of(name).stem  # the field's norm of E^h
        size = max(simplex_seminorm(points, fields.cells, ours, stem), floor * math.sqrt(measure), 1e-300)
        diff = simplex_seminorm(points, fields.cells, ours - theirs, stem)
        nodal = float(np.abs(ours - theirs).max())
        out[name] = FieldDifference(diff, diff / size, nodal, nodal / max(float(np.abs(ours).max()), floor, 1e-300))
    return out, points


def integral_differences(record: RunRecord, peer: dict[str, Any]) -> dict[str, tuple[float, float, float]]:
    """(FreeFEM, GetFEM, relative difference) of each contact integral both codes report;
    the friction force compared as its magnitude (run.json's friction_force)."""
    out = {}
    for key in INTEGRALS:
        ours, theirs = getattr(record, key), peer.get(key)
        if ours is not None and theirs is not None:
            out[key] = (float(ours), float(theirs), relative(float(ours), float(theirs)))
    if record.friction_force is not None and "friction_force_vector" in peer:
        # A friction force that cancels (a symmetric scene: 4e-16 against 0 N/m) is measured
        # against the most the contact can carry, max |sigma_tau| times the closed measure.
        theirs = float(np.linalg.norm(peer["friction_force_vector"]))
        capacity = float((record.checks or {}).get("max_abs_sigma_tau", 0.0)) * float(record.active_measure or 0.0)
        out["friction_force"] = (float(record.friction_force), theirs, relative(float(record.friction_force), theirs, capacity))
    return out



def relative(a: float, b: float, floor: float = 0.0) -> float:
    """|a - b| over the larger of |a|, |b| and `floor` (0 when all are 0)."""
    scale = max(abs(a), abs(b), floor)
    return 0.0 if scale == 0.0 else abs(a - b) / scale if math.isfinite(scale) else math.inf
