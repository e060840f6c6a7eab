"""Load a case file (TOML) plus `--set section.key=value` overrides into a frozen Scene."""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from harness.scene.electrodes import check_electrodes
from harness.core.errors import SceneError
from harness.core.layout import case_path
from harness.scene.floating import check_floating
from harness.scene.linear_solvers import LinearSolver, Memory, solver
from harness.scene.petsc_options import RANKS_ONLY, default_options, one_rank_options
from harness.scene.box import Box, parse_box
from harness.scene.gmsh_geometry import GmshGeometry, parse_gmsh
from harness.scene.quantities import Average, Probe, Quantity, parse_goals, parse_quantities, parse_tolerances, quantity_table
from harness.scene.poling import Poling, default_axis, parse_poling
from harness.scene.regions import (Region, any_rotated, check_conductors, check_regions, regions_of,
                                   with_paths_resolved)
from harness.scene.schema import (EFFECTS, REQUIRED, SCHEMA, SOLVER_SECTIONS, Key, effect_of, geometry_keys,
                            is_material_path, unbounded_keys, unread_by_law)
from harness.scene.sections import sections_of
from harness.scene.segments import Geometry, parse_geometry
from harness.scene.unknowns import Unknowns
from harness.scene.well_posed import check_fixed


@dataclass(frozen=True)
class Scene:
    """A validated case. `sections` holds each section of the resolved case file (defaults
    filled, overrides applied) as a frozen dataclass (harness/scene/sections.py); `table` is the
    same as plain data, for writing into a summary and for the cache key, never indexed
    (the [expect] section is left out of it: it changes no result)."""

    source: Path
    table: dict[str, dict[str, Any]]
    geometry: Geometry | Box | GmshGeometry
    warnings: tuple[str, ...] = ()
    sections: Any = None

    @property
    def expect(self) -> Any:
        return self.sections.expect

    @property
    def name(self) -> str:
        return self.sections.scene.name

    @property
    def dimension(self) -> int:
        return getattr(self.geometry, "dimension", 2)

    @property
    def material(self) -> str:
        """The one material, or with regions the first region's (its constants set the
        scheme's scales, freefem/scaling.idp)."""
        return self.sections.scene.material or self.regions[0].material

    @property
    def regions(self) -> tuple[Region, ...]:
        """The material regions in the mesh's label order; empty for a one-material scene."""
        return regions_of(self.sections.scene.materials, getattr(self.geometry, "regions", ()),
                          self.sections.scene.poling_axis, self.dimension)

    def poling_macros(self) -> dict[str, str]:
        """The poling macros of main.edp: the scene's axis for one material; with regions the
        default axis written out when any region is rotated (the law then has the rotated
        terms, each region's values come from harness/scene/regions.py), else none."""
        if not self.regions:
            return self.poling.macros()
        return Poling(default_axis(self.dimension)).macros(always=True) if any_rotated(self.regions) else {}

    @property
    def plane(self) -> str:
        """geometry.plane of a 2D scene ("strain" or "stress"); a 3D scene's is "strain" (none applies)."""
        return getattr(self.sections.geometry, "plane", None) or "strain"  # the default is dropped on load

    def plane_macros(self) -> dict[str, str]:
        """PLANESTRESS switches on freefem/material.idp's plane-stress reduction."""
        return {"PLANESTRESS": "1"} if self.plane == "stress" else {}

    @property
    def poling(self) -> Poling:
        """The material's axis 3 in the scene's coordinates (checked when the scene loads)."""
        return parse_poling(self.sections.scene.poling_axis, self.dimension)

    @property
    def effects(self) -> tuple[str, ...]:
        """The scene's effects in the canonical order of schema.EFFECTS."""
        on = set(self.sections.scene.effects)
        return tuple(e for e in EFFECTS if e in on)

    @property
    def fields(self) -> tuple[str, ...]:
        """The fields the effects bring in (harness/scene/unknowns.py), in their order."""
        return tuple(f.name for f in Unknowns(self.effects).fields)

    @property
    def element(self) -> str:
        return self.sections.scene.element

    @property
    def initial_guess(self) -> str:
        return self.sections.scene.initial_guess

    @property
    def timeout_s(self) -> float:
        return self.sections.run.timeout_s

    @property
    def linear_solver(self) -> str:
        return self.sections.run.linear_solver

    @property
    def solver(self) -> LinearSolver:
        """run.linear_solver's entry (harness/scene/linear_solvers.py)."""
        return solver(self.linear_solver)

    @property
    def solver_options(self) -> str:
        """The linear solver's own options (for PETSc, petsc_options); "" for one that has none."""
        entry = self.solver
        if not entry.options_key:
            return ""
        given = str(getattr(self.sections.run, entry.options_key)).strip()
        fields = tuple(f.name for f in Unknowns(self.effects, self.dimension).newton)
        defaults = entry.default_options(self.dimension, fields, self.sections.run.ranks) if entry.default_options else ""
        return given or defaults

    @property
    def petsc_options(self) -> str:
        """run.petsc_options, or the measured default of the scene's dimension when blank."""
        fields = tuple(f.name for f in Unknowns(self.effects, self.dimension).newton)
        return self.sections.run.petsc_options.strip() or default_options(self.dimension, fields, self.sections.run.ranks)

    @property
    def multigrid_levels(self) -> int:
        """Coarser meshes a geometric multigrid gets (0: the options ask for none)."""
        return self.sections.run.multigrid_levels if self.solver.wants_coarser_meshes(self.solver_options) else 0

    @property
    def coarse_levels(self) -> int:
        """Halvings of n down to the coarse space's mesh on ranks (0: one-level Schwarz, one rank, or
        PETSc, whose preconditioner is run.petsc_options' business)."""
        run = self.sections.run
        if run.ranks == 1 or run.coarse_space != "nested" or self.solver.options_key:
            return 0
        return run.coarse_levels or (3 if self.dimension == 2 else 2)

    @property
    def factorises(self) -> bool:
        """Whether the linear solver factorises the Newton matrix (memory: a factor's fill)."""
        return self.solver.memory(self.solver_options) is Memory.FACTOR

    @property
    def levels(self) -> tuple[int, ...]:
        return tuple(self.sections.study.levels)

    @property
    def slope_band(self) -> tuple[float, float]:
        low, high = self.sections.study.slope_band
        return float(low), float(high)

    @property
    def manufactured(self) -> dict[str, str]:
        """The exact solution of a manufactured case (harness/scene/mms.py); empty for any other."""
        given = self.table.get("manufactured", {})
        return dict(given) if any(v.strip() for v in given.values()) else {}

    def solver_parameters(self) -> dict[str, dict[str, Any]]:
        """The values FreeFEM reads, one dict per section; data of effects that are off are
        left out (FreeFEM never assembles their terms)."""
        on = set(self.effects)
        return {
            **{s: {k: v for k, v in self.table[s].items() if effect_of(s, k) in (None, *on)}
               for s in SOLVER_SECTIONS},
            **({"reference": dict(self.table["reference"])} if self.reference_state else {}),
        }

    def run_inputs(self) -> dict[str, Any]:
        """Everything in the scene that can change a single solve (not the study settings),
        so that editing levels or the band does not invalidate cached runs."""
        return {
            "material": self.material,
            **({"materials": [[r.name, r.material, list(r.poling.axis)] for r in self.regions]} if self.regions else {}),
            # Only a rotated poling joins the key: the default one leaves earlier keys as they were.
            **({} if self.poling.is_default else {"poling_axis": list(self.poling.axis)}),
            "initial_guess": self.initial_guess,
            "element": self.element,
            "linear_solver": self.linear_solver,
            **self.solver.keyed(self.solver_options),
            **({"multigrid": [self.multigrid_levels, self.sections.run.multigrid_coarsest]}
               if self.multigrid_levels else {}),
            **({"coarse_levels": self.coarse_levels} if self.coarse_levels else {}),
            "effects": list(self.effects),
            "geometry": copy.deepcopy(self.table["geometry"]),
            **self.solver_parameters(),
            **({"manufactured": self.manufactured} if self.manufactured else {}),
            **({"reference_sha256": sha256_file(self.reference_state)} if self.reference_state else {}),
        }

    def on_ranks(self, count: int) -> Scene:
        """The same scene solved on `count` MPI ranks (run.ranks): a level of a chain too
        small for the scene's ranks runs on fewer (harness/run/launcher.py level_scene)."""
        if count == self.sections.run.ranks:
            return self
        run: dict[str, Any] = {"ranks": count}
        given = self.sections.run.petsc_options
        if count == 1 and set(given.split()) & set(RANKS_ONLY):
            # Blank options follow the ranks (default_options); given ones lose what one rank never reads.
            run["petsc_options"] = one_rank_options(given)
        table = {**self.table, "run": {**self.table["run"], **run}}
        sections = dataclasses.replace(self.sections, run=dataclasses.replace(self.sections.run, **run))
        return dataclasses.replace(self, table=table, sections=sections)

    @property
    def probes(self) -> tuple[Probe, ...]:
        return self.case_quantities[0]

    @property
    def averages(self) -> tuple[Average, ...]:
        return self.case_quantities[1]

    @property
    def case_quantities(self) -> tuple[tuple[Probe, ...], tuple[Average, ...]]:
        """The [quantities] section's probes and averages (checked when the scene loaded)."""
        return parse_quantities(self.sections.quantities.__dict__, self.fields, self.dimension,
                                self.geometry.used_roles(), extents(self.geometry))

    @property
    def tolerances(self) -> dict[str, float]:
        """[quantities] tolerances: each quantity's relative error a study asks of its finest level
        (checked when the scene loaded: a quantity of the scene, a positive number)."""
        return {name: float(v) for name, v in (self.sections.quantities.tolerances or {}).items()}

    @property
    def goals(self) -> tuple[str, ...]:
        """The quantities whose error a run estimates by dual-weighted residuals (checked when the
        scene loaded; freefem/goals.idp)."""
        return tuple(self.sections.quantities.goals)

    @property
    def quantities(self) -> tuple[Quantity, ...]:
        """Every quantity of the scene's effects, roles and [quantities] (harness/scene/quantities.py)."""
        return quantity_table(self.effects, self.geometry.used_roles(), self.probes, self.averages)

    @property
    def reference_state(self) -> str:
        return self.sections.reference.state

    def reference_macros(self) -> dict[str, str]:
        """REFERENCE switches on freefem/reference_error.idp when a reference state is set."""
        return {"REFERENCE": "1"} if self.reference_state else {}


def load_scene(path: Path, overrides: Iterable[str] = ()) -> Scene:
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SceneError(f"case file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"cannot read case file {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"malformed case file {path}: {exc}") from None
    try:
        for item in overrides:
            apply_override(raw, item)
        table, warnings = resolve(raw)
        if is_material_path(table["scene"]["material"]):  # relative to the case file, as a .geo
            table["scene"]["material"] = str(case_path(path.parent, table["scene"]["material"], "scene.material"))
        geometry = parse_any_geometry(table, path.parent)
        if "piezoelectric" in table["scene"]["effects"]:
            check_electrodes(geometry.parts(), max(geometry.width, geometry.height))
        parse_poling(table["scene"]["poling_axis"], getattr(geometry, "dimension", 2))
        regions = check_regions(table["scene"]["materials"], table["scene"]["material"], geometry)
        if regions:
            table["scene"]["materials"] = with_paths_resolved(table["scene"]["materials"], path.parent)
            geometry = dataclasses.replace(geometry, regions=regions)
            check_conductors(table, regions_of(table["scene"]["materials"], regions, table["scene"]["poling_axis"],
                                               getattr(geometry, "dimension", 2)))
        check_fixed(geometry, table["scene"]["effects"], table)
        check_floating(table, geometry)
        check_expect(table["expect"])
        dimension = getattr(geometry, "dimension", 2)
        effects = tuple(table["scene"]["effects"])
        probes, averages = parse_quantities(table["quantities"], tuple(f.name for f in Unknowns(effects, dimension).fields),
                                            dimension, geometry.used_roles(), extents(geometry))
        parse_tolerances(table["quantities"]["tolerances"],
                         quantity_table(effects, geometry.used_roles(), probes, averages))
        parse_goals(table["quantities"]["goals"], tuple(q.name for q in quantity_table(
            effects, geometry.used_roles(), probes, averages)), goals_unsupported(table, geometry))
    except SceneError as exc:
        raise SceneError(f"{path}: {exc}") from None  # every case-file error names the file
    sections = sections_of(table)
    # A tolerance judges a study's result and changes no run: it stays out of the table the runs'
    # inputs are taken from, so asking for one reuses the runs made without it.
    table["quantities"] = {k: v for k, v in table["quantities"].items() if k != "tolerances"}
    # (a case without [quantities] keeps the table, and so the summaries, it had before the section existed)
    table = {name: values for name, values in table.items()
             if name != "expect" and not (name == "quantities" and not any(values.values()))}
    return Scene(source=path, table=table, geometry=geometry, warnings=warnings, sections=sections)


def goals_unsupported(table: dict[str, dict[str, Any]], geometry: Geometry | Box | GmshGeometry) -> str:
    """What a run of this scene lacks for goal estimates (freefem/goals.idp); empty when nothing."""
    dimension = getattr(geometry, "dimension", 2)
    if table["run"]["ranks"] > 1:
        return f"one MPI rank (run.ranks = {table['run']['ranks']}): the dual solve is not distributed"
    if table["scene"]["element"] != "P1":
        return "P1 elements (the dual is solved on P2)"
    if solver(table["run"]["linear_solver"]).builds_plugin:
        return (f"a linear solver of FreeFEM's own (run.linear_solver = {table['run']['linear_solver']!r} "
                "holds K in its plugin)")
    if Unknowns(tuple(table["scene"]["effects"]), dimension).staggered:
        return "theta in the Newton system (thermal_contact on): a staggered theta has no Newton tangent"
    if any(role.startswith("floating") for role in geometry.used_roles()):
        return "no floating electrode"
    return ""


def extents(geometry: Geometry | Box | GmshGeometry) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The body's lowest and highest corners: the rectangle's and the box's own extent (the body
    itself), a gmsh body's bounding box."""
    if isinstance(geometry, Box):
        return (0.0, 0.0, 0.0), geometry.lengths
    if isinstance(geometry, GmshGeometry):
        d, b = geometry.dimension, geometry.bounds
        return tuple(b[:d]), tuple(b[3:3 + d])
    return (0.0, 0.0), (geometry.width, geometry.height)


def parse_any_geometry(table: dict[str, dict[str, Any]], case_dir: Path) -> Geometry | Box | GmshGeometry:
    given = table["geometry"]
    if given.get("plane") == "strain":
        # Plane strain, the default, resolves to the table it had before the key existed: its
        # summary.json and run cache keys stay what they were.
        del given["plane"]
    if given.get("blocks") == {}:
        # A body without named sub-blocks resolves to the table it had before blocks existed:
        # its summary.json and run cache keys stay what they were.
        del given["blocks"]
    if given["kind"] == "box":
        return parse_box(given)
    if given["kind"] == "gmsh":
        geometry = parse_gmsh(given, case_dir, table["study"]["levels"], table["scene"]["effects"])
        given["coarsest"] = geometry.coarsest  # resolved, so that the cache key names it
        if geometry.dimension == 3 and given.get("plane", "strain") != "strain":
            raise SceneError(f"geometry.plane = {given['plane']!r} is for 2D bodies; this drawing is 3D "
                             "(a 3D body has no plane reduction: remove the key)")
        return geometry
    return parse_geometry(given)


def parse_value(text: str) -> Any:
    """A TOML scalar or array; anything TOML rejects is taken as a bare string (`pressed`)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text.strip()


def apply_override(raw: dict, item: str) -> None:
    dotted, sep, text = item.partition("=")
    dotted = dotted.strip()
    section, _, key = dotted.partition(".")
    if not sep:
        raise SceneError(f"--set {item!r}: expected section.key=value")
    keys = geometry_keys(raw.get("geometry", {})) if section == "geometry" else SCHEMA.get(section, {})
    if key not in keys:
        raise SceneError(f"--set {item!r}: no such key {dotted!r} in the case-file schema")
    raw.setdefault(section, {})[key] = parse_value(text)


def resolve(raw: dict) -> tuple[dict[str, dict[str, Any]], tuple[str, ...]]:
    for section in raw:
        if section not in SCHEMA:
            raise SceneError(f"unknown section [{section}]")
        if not isinstance(raw[section], dict):
            raise SceneError(f"{section} must be a [section]")
    scene_keys = SCHEMA["scene"]
    effects = checked("scene.effects", scene_keys["effects"], raw.get("scene", {}).get("effects", scene_keys["effects"].default))
    table: dict[str, dict[str, Any]] = {}
    warnings: list[str] = []
    for section, keys in SCHEMA.items():
        given = raw.get(section, {})
        if section == "geometry":
            keys = geometry_keys(given)
        for key in given:
            if key not in keys:
                raise SceneError(f"unknown key {section}.{key}")
        table[section] = {}
        for key, spec in keys.items():
            effect = effect_of(section, key)
            if effect is not None and effect not in effects:
                # Data of an effect that is off: not required, and never used.
                if key in given:
                    warnings.append(f"{section}.{key} is ignored: effect {effect!r} is off")
                continue
            if spec.required and key not in given and unread_by_law(section, key, given, keys):
                continue  # the law in force never reads it (schema.LAW_DATA)
            table[section][key] = checked(f"{section}.{key}", spec, given.get(key, spec.default))
    return table, tuple(warnings)


def check_expect(expect: dict[str, Any]) -> None:
    """A known failure names its classified reason and why; a converging case names neither."""
    if expect["status"] == "known_failure" and not (expect["failure"] and expect["why"]):
        raise SceneError("expect.status = \"known_failure\" needs expect.failure and expect.why")
    if expect["status"] == "converged" and expect["failure"]:
        raise SceneError(f"expect.failure = {expect['failure']!r} needs expect.status = \"known_failure\"")


def checked(name: str, spec: Key, value: Any) -> Any:
    if value is REQUIRED:
        raise SceneError(f"missing key {name}")
    value = coerced(name, spec.kind, value)
    if isinstance(value, float) and math.isnan(value):
        raise SceneError(f"{name} = nan is not a number")
    if isinstance(value, float) and math.isinf(value) and not spec.unbounded:
        raise SceneError(f"{name} = {value} must be a finite number (only {', '.join(unbounded_keys())} may be inf)")
    complaint = spec.check(value) if spec.check else None
    if complaint:
        raise SceneError(f"{name} = {value!r} {complaint}")
    return value


def coerced(name: str, kind: type, value: Any) -> Any:
    # TOML keeps 1 and 1.0 apart; a float key accepts an integer, but bool is never a number.
    if kind is float and type(value) is int:
        return float(value)
    if kind is object:  # checked by its own parser (a box face: harness/scene/box.py)
        return value
    if type(value) is not kind:
        raise SceneError(f"{name} = {value!r} must be of type {kind.__name__}")
    return value


def sha256_file(path: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        raise SceneError(f"reference.state {path!r} is not a readable file") from None
