"""The case-file schema in one table: section -> key -> type, default and physical range.

Every check returns a complaint (a phrase) or None, so the loader can name the key
generically; nothing here knows about files or overrides.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

from harness.core.contract import FLOATING_CHARGES, ROLE_LABELS
from harness.core.layout import is_material_path
from harness.scene.linear_solvers import SOLVERS

# Sections passed verbatim to FreeFEM as `-<section>.<key> <value>`.
SOLVER_SECTIONS = ("loads", "contact", "electric_contact", "thermal_contact", "newton")

REQUIRED = object()

Check = Callable[[Any], "str | None"]


@dataclass(frozen=True)
class Key:
    kind: type
    default: Any = REQUIRED
    check: Check | None = None
    # What an infinite value means, for the few keys where it is data ("none"); blank: a
    # number must be finite (inf is refused like nan, never passed on as a huge number).
    unbounded: str = ""

    @property
    def required(self) -> bool:
        return self.default is REQUIRED


def positive(v: float) -> str | None:
    return None if v > 0 else "must be > 0"


def nonnegative(v: float) -> str | None:
    return None if v >= 0 else "must be >= 0"


def one_of(*choices: str | int) -> Check:
    def check(v: str | int) -> str | None:
        return None if v in choices else f"must be one of {', '.join(map(str, choices))}"

    return check


def petsc_option_words(v: str) -> str | None:
    """PETSc's options string: it must start with an option ("-name"); PETSc itself judges
    names and values (an unknown or unused one ends the run with exit code INPUT)."""
    words = v.split()
    if words and not (words[0].startswith("-") and words[0][1:2].isalpha()):
        return f"must be PETSc options like '-ksp_type gmres -pc_type gamg', not starting with {words[0]!r}"
    if any(not w.isprintable() or '"' in w for w in words):
        return "must be PETSc options (printable words without quotes)"
    return None


def positive_ints(v: list) -> str | None:
    ok = v and all(type(x) is int and x > 0 for x in v)
    return None if ok else "must be a non-empty list of positive integers"


def increasing_pair(v: list) -> str | None:
    ok = (
        len(v) == 2
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        and all(math.isfinite(x) for x in v)
        and v[0] < v[1]
    )
    return None if ok else "must be [low, high] with low < high"


def safe_name(v: str) -> str | None:
    ok = v and v not in (".", "..") and all(c.isalnum() or c in "-_." for c in v)
    return None if ok else "must be a plain file name (letters, digits, - _ .)"


def material_reference(v: str) -> str | None:
    if is_material_path(v):
        return None if v.endswith(".idp") else "must be a material name or a path to a .idp file"
    return None if safe_name(v) is None else "must be a material name (letters, digits, - _ .) or a path to a .idp file"


_ROLE = one_of(*ROLE_LABELS)

# geometry.plane: how a 2D scene reads its third direction (freefem/material.idp's reduction).
PLANES = ("strain", "stress")
# Effects a scene can switch on (elasticity is always on), each with its prerequisites.
EFFECTS: dict[str, tuple[str, ...]] = {
    "piezoelectric": (),
    "thermal": (),
    "pyroelectric": ("piezoelectric", "thermal"),
    "contact": (),
    "friction": ("contact",),
    "electric_contact": ("piezoelectric", "contact"),
    "thermal_contact": ("thermal", "contact"),
}

# Case-file data that only matter when an effect is on: a whole section, or one key.
DATA_EFFECT: dict[tuple[str, str | None], str] = {
    ("contact", None): "contact",
    ("contact", "S"): "friction",
    ("contact", "friction_law"): "friction",
    ("contact", "mu"): "friction",
    ("electric_contact", None): "electric_contact",
    ("thermal_contact", None): "thermal_contact",
    ("loads", "surface_charge"): "piezoelectric",
    ("loads", "charge_density"): "piezoelectric",
    ("loads", "electrode_potential"): "piezoelectric",
    **{("loads", key): "piezoelectric" for key in FLOATING_CHARGES.values()},
    ("loads", "heat_source"): "thermal",
}


# The friction laws (freefem/friction.idp, docs/laws.md), each with the key whose positive
# value makes it grip (a pressed contact then holds the body tangentially: well_posed.py).
FRICTION_LAWS: dict[str, str] = {
    "tresca": "S",
    "coulomb": "mu",
}

# Case-file data that only one friction law reads (freefem/friction.idp): key -> (the key
# naming the law, the law that reads it). Under another law the key may be left out.
LAW_DATA: dict[tuple[str, str], tuple[str, str]] = {
    ("contact", "S"): ("friction_law", "tresca"),
}


def unread_by_law(section: str, key: str, given: dict[str, Any], keys: dict[str, "Key"]) -> bool:
    """Whether the law a section names (or its default) never reads this key."""
    law = LAW_DATA.get((section, key))
    if law is None:
        return False
    law_key, reader = law
    return given.get(law_key, keys[law_key].default) != reader


def effect_of(section: str, key: str) -> str | None:
    """The effect a case-file value belongs to (None: always used)."""
    return DATA_EFFECT.get((section, key)) or DATA_EFFECT.get((section, None))


def effect_list(v: list) -> str | None:
    valid = ", ".join(EFFECTS)
    if not all(isinstance(e, str) for e in v):
        return f"must be a list of effect names ({valid})"
    unknown = [e for e in v if e not in EFFECTS]
    if unknown:
        return f"has unknown effect {unknown[0]!r}; valid effects: {valid}"
    if len(set(v)) != len(v):
        return "names an effect twice"
    for effect in v:
        missing = [p for p in EFFECTS[effect] if p not in v]
        if missing:
            return f"turns on {effect!r}, which needs {' and '.join(repr(m) for m in missing)} on too"
    return None

SCHEMA: dict[str, dict[str, Key]] = {
    "scene": {
        "name": Key(str, check=safe_name),
        "description": Key(str, ""),
        # One material for the whole body, or blank with [scene.materials] (harness/scene/regions.py).
        "material": Key(str, "", check=lambda v: material_reference(v) if v else None),
        # [scene.materials]: a gmsh scene's named body groups (surfaces in 2D, volumes in 3D),
        # or the rectangle's or box's [geometry.blocks], = material, one entry per group; the
        # scene.material shorthand left blank.
        "materials": Key(object, {}),
        "effects": Key(list, list(EFFECTS), effect_list),
        # zero | pressed: Newton's start on every level; coarser: each level starts from
        # the solution of the next coarser level (the coarsest from `coarsest_guess`),
        # which keeps a study on one solution branch; file: from initial_mesh/initial_state.
        "initial_guess": Key(str, "coarser", one_of("zero", "pressed", "coarser", "file")),
        "coarsest_guess": Key(str, "zero", one_of("zero", "pressed")),
        "initial_mesh": Key(str, ""),
        "initial_state": Key(str, ""),
        # The material's axis 3 (poling): blank for the default (y in 2D, z in 3D), a named
        # axis with a sign ("x", "-z") or a vector, in-plane in 2D (harness/scene/poling.py).
        "poling_axis": Key(object, ""),
    },
    "geometry": {
        "kind": Key(str, check=one_of("rectangle", "box", "gmsh")),
        "width": Key(float, check=positive),
        "height": Key(float, check=positive),
        "bottom": Key(list),
        "top": Key(list),
        "left": Key(str, check=_ROLE),
        "right": Key(str, check=_ROLE),
        # "unstructured": gmsh's Frontal-Delaunay triangles of size h with the interior
        # nodes shifted at random by up to 0.3 h (a distorted, non-nested mesh; harness/mesh/rectangle_mesh.py).
        "diagonals": Key(str, "SW-NE", one_of("SW-NE", "NW-SE", "unstructured")),
        # [geometry.blocks]: named sub-blocks name = [x0, x1, y0, y1] that tile the body, the
        # regions [scene.materials] maps to materials (harness/scene/blocks.py).
        "blocks": Key(object, {}),
        # A 2D body's third direction (docs/model.md section 8): strain, the long prism (eps_zz = 0,
        # the paper's); stress, the thin plate or beam free across its width (sigma_zz = 0).
        "plane": Key(str, "strain", one_of(*PLANES)),
    },
    "loads": {
        name: Key(float, 0.0)
        for name in (
            "traction_x", "traction_y", "traction_z", "surface_charge", "body_force_x",
            "body_force_y", "body_force_z", "charge_density", "heat_source",
            # phi on the parts whose role is `electrode` [V] (the `ground` parts hold 0)
            "electrode_potential",
            # the net free charge on the parts whose role is `floating` [C/m in 2D, C in 3D]:
            # one open conductor at a uniform, unknown potential (docs/model.md); _2, _3:
            # those of the roles floating_2, floating_3, two more conductors
            *FLOATING_CHARGES.values(),
        )
    },
    "contact": {
        "c_nu": Key(float, check=positive),
        "gap": Key(float),
        # Tresca's slip bound [N/m^2]: a friction stress the contact holds whatever its
        # pressure, so it grips the body even where the contact is open (docs/model.md).
        # Required by Tresca only (LAW_DATA).
        "S": Key(float, check=nonnegative),
        # The slip bound (freefem/friction.idp, docs/laws.md): tresca, R = S; coulomb,
        # R = mu c_nu (u_nu - g)_+, mu times the normal pressure (S is then not used).
        "friction_law": Key(str, "tresca", one_of(*FRICTION_LAWS)),
        "mu": Key(float, 0.0, nonnegative),
    },
    "electric_contact": {
        "k_e": Key(float, check=nonnegative),
        "eps_e": Key(float, check=positive),
        "phi_f": Key(float),
        "L": Key(float, check=positive, unbounded="no truncation: phi_L is the identity"),
    },
    "thermal_contact": {
        "k_c": Key(float, check=nonnegative),
        "eps_c": Key(float, check=positive),
        "theta_f": Key(float),
    },
    "newton": {
        "max_iterations": Key(int, check=positive),
        "rtol": Key(float, check=positive),
    },
    "run": {
        "timeout_s": Key(float, 600.0, positive),
        # The linear solver (harness/scene/linear_solvers.py; freefem/effects.idp, LINEARSOLVER). MUMPS_seq is the
        # fastest here at every level (results/bench/) and, unlike the built-in UMFPACK
        # (32-bit indices), reaches h = 1/256.
        "linear_solver": Key(str, "mumps", one_of(*SOLVERS)),
        # With linear_solver = "petsc": PETSc's options for the Newton system ("-ksp_type gmres
        # -pc_type fieldsplit ..."); blank: the measured default of the scene's dimension
        # (harness/scene/petsc_options.py default_options, docs/solvers.md).
        "petsc_options": Key(str, "", petsc_option_words),
        # With a PETSc geometric multigrid (-pc_type mg in run.petsc_options): how many coarser
        # meshes of the scene's nested family, each halving n, become its levels, the coarsest
        # no coarser than n = multigrid_coarsest (a level with none is solved by the coarse
        # solver alone). Below n = 8 a coarse mesh misses where Gamma_3 opens: the paper's
        # scene at n = 4 over n = 2 took 88-131 Krylov iterations a Newton step, against 5-13
        # from n = 16 to 128 (docs/solvers.md). The harness meshes them (harness/mesh/mesh.py).
        "multigrid_levels": Key(int, 4, nonnegative),
        "multigrid_coarsest": Key(int, 8, positive),
        # MPI ranks of one solve (freefem/ranks.idp, harness/run/launcher.py); 1: the sequential scheme.
        "ranks": Key(int, 1, positive),
        # How ranks are started; {ranks} is replaced. On a SLURM cluster: "srun -n {ranks} FreeFem++-mpi".
        "launcher": Key(str, "ff-mpirun -np {ranks}"),
        # With run.ranks > 1: the Schwarz preconditioner's second level (freefem/coarse_space.idp).
        # "nested" (the default): a coarse-grid correction on the mesh coarse_levels halvings
        # of n below the level (the coarsest is n = 2), whose Krylov iterations stay bounded as
        # the ranks grow; on 2 ranks it took 3-5x fewer iterations than one level and was as
        # fast or faster at every size of results/scale/ but 3D n = 8 (+3 %). "none": one-level
        # RAS, whose iterations grow with the ranks (docs/scale-out.md).
        "coarse_space": Key(str, "nested", one_of("none", "nested")),
        # 0: a coarse mesh with about 1/64 of the unknowns, 3 halvings in 2D and 2 in 3D
        # (measured against 2 and 3, 4, docs/scale-out.md).
        "coarse_levels": Key(int, 0, nonnegative),
        # With run.ranks > 1: GMRES's tolerance on the true residual relative to the right-hand
        # side (the sequential solver's 1e-11). Below the residual's round-off floor (about
        # 2.6e-11 at 2D h = 1/256) it stops at the floor and accepts within 1e3 times this.
        "krylov_rtol": Key(float, 1e-11, positive),
    },
    "study": {
        "levels": Key(list, check=positive_ints),
        "slope_band": Key(list, check=increasing_pair),
        # An adaptive study's band (python -m harness adapt): each field's slope of its error
        # estimate against N^(-1/d), 1 being optimal; [] judges nothing.
        "adaptive_band": Key(list, [], check=lambda v: None if v == [] else increasing_pair(v)),
    },
}

# A manufactured solution (harness/scene/mms.py): exact u1, u2 (u3 in 3D) [m], phi [V], theta [K]
# as sympy expressions in x, y (and z). All blank (the default): an ordinary run with the case's [loads].
# williams: the amplitude [m] of Williams' mode-I displacement of the corner at the origin whose
# traction-free faces are the polar angles 0 and williams_opening [rad] (harness/scene/corner.py),
# added to u1, u2; 2D, an isotropic material.
SCHEMA["manufactured"] = {name: Key(str, "") for name in ("u1", "u2", "u3", "phi", "theta",
                                                          "williams", "williams_opening")}

# The finite element of every field (freefem/scheme.idp's ELEMENT macro), and a reference
# run to measure errors against inside FreeFEM (freefem/reference_error.idp, issue 5): its
# mesh and state.txt (paths) and its element, passed to FreeFEM as -reference.<key> when
# a state is set (Scene.solver_parameters). A blank state: no reference errors.
SCHEMA["scene"]["element"] = Key(str, "P1", one_of("P1", "P2"))
SCHEMA["reference"] = {
    "mesh": Key(str, ""),
    "state": Key(str, ""),
    "element": Key(str, "P1", one_of("P1", "P2")),
    # The error is integrated on the reference mesh with each triangle split split^2
    # times: 1 is exact for a run on a mesh the reference mesh refines; a non-nested run
    # (a graded mesh) has kinks inside reference triangles, which splitting resolves.
    "split": Key(int, 1, positive),
}

# A case's own quantities (harness/scene/quantities.py, docs/quantities.md), beside the built-in
# ones every run reports: probes = [{ name, field, at = [x, y(, z)] }] and
# averages = [{ name, field, on = "<role>" }], checked there; tolerances = { <quantity> = <relative
# error> }, the accuracy a convergence study's verdict asks of its finest level (docs/quantities.md);
# goals = ["heat_through_contact", ...]: the quantities whose error a run estimates by dual-weighted
# residuals (freefem/goals.idp, docs/goals.md).
SCHEMA["quantities"] = {"probes": Key(object, []), "averages": Key(object, []), "tolerances": Key(object, {}),
                        "goals": Key(object, [])}

# The [geometry] of kind = "box" (harness/scene/box.py): side lengths and each face's role or
# patches; the face values are checked there.
BOX_GEOMETRY: dict[str, Key] = {
    "kind": Key(str, check=one_of("box")),
    **{name: Key(float, check=positive) for name in ("lx", "ly", "lz")},
    **{name: Key(object) for name in ("x0", "x1", "y0", "y1", "z0", "z1")},
    # kuhn: nested structured tetrahedra (harness/mesh/box_mesh.py); unstructured: gmsh's, not nested.
    "diagonals": Key(str, "kuhn", one_of("kuhn", "unstructured")),
    # [geometry.blocks]: named sub-blocks name = [x0, x1, y0, y1, z0, z1] (harness/scene/blocks.py).
    "blocks": Key(object, {}),
}


# The [geometry] of kind = "gmsh" (harness/scene/gmsh_geometry.py): a .geo file whose named
# physical groups (curves in 2D, surfaces in 3D) the [geometry.roles] table maps to roles.
GMSH_GEOMETRY: dict[str, Key] = {
    "kind": Key(str, check=one_of("gmsh")),
    "file": Key(str),  # relative to the case file
    "dimension": Key(int, check=one_of(2, 3)),
    "roles": Key(object),  # physical-group name -> role, checked against the file
    # split: uniform refinements of the coarsest mesh (nested on straight-sided bodies);
    # remesh: an independent mesh per level (point-located transfer).
    "levels": Key(str, "split", one_of("split", "remesh")),
    # The level whose mesh (h = 1/coarsest) split refines and remesh scales the file's sizes
    # from; 0: the smallest of study.levels.
    "coarsest": Key(int, 0, nonnegative),
    # A 2D body's third direction (docs/model.md section 8): strain, the long prism (eps_zz = 0,
    # the paper's); stress, the thin plate or beam free across its width (sigma_zz = 0).
    "plane": Key(str, "strain", one_of(*PLANES)),
}


def unbounded_keys() -> list[str]:
    """The keys an infinite value is documented for ("section.key")."""
    return [f"{section}.{key}" for section, keys in SCHEMA.items() for key, spec in keys.items() if spec.unbounded]


def geometry_keys(given: dict[str, Any]) -> dict[str, Key]:
    """The [geometry] schema of the kind a case file names."""
    return {"box": BOX_GEOMETRY, "gmsh": GMSH_GEOMETRY}.get(given.get("kind"), SCHEMA["geometry"])


# What a case promises (the stress suite, cases/hard/; harness/studies/stress.py), the way a
# MOOSE test spec carries a `requirement`: the outcome expected from the solver as it is
# (converged, or a known failure with its classified reason and why), one sentence of what
# the case must show, and the tolerances its test applies, each with why. A case whose
# known failure gets fixed is noticed (the suite fails until the expectation is flipped).
EXPECTED_STATUSES = ("converged", "known_failure")
FAILURE_STATUSES = ("diverged", "max_iterations", "nan", "freefem_error", "timeout")
SCHEMA["expect"] = {
    "hard_because": Key(str, ""),
    "requirement": Key(str, ""),
    "status": Key(str, "converged", one_of(*EXPECTED_STATUSES)),
    "failure": Key(str, "", one_of("", *FAILURE_STATUSES)),  # a known failure's classified reason
    "why": Key(str, ""),  # why it fails, for a known failure
    # The most Newton iterations any level of the case may take (coarse levels, n <= 8).
    "max_newton_iterations": Key(int, 40, positive),
    "max_newton_iterations_why": Key(str, ""),
}
