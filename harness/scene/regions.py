"""Material regions: `[scene.materials]` maps each named physical group of a gmsh scene's body
(surfaces in 2D, volumes in 3D), or each named block of the rectangle or the box
(harness/scene/blocks.py), to a material; `scene.material` stays the one-region shorthand.

The regions are perfectly bonded: u, phi and theta are one continuous P1 field over the whole
body, and only the constants of the law change from cell to cell. Each region's constants are
asked of FreeFEM (harness/scene/material_constants.py: the file checked and, for a rotated poling,
rotated by freefem/material.idp) and handed to the run as piecewise-constant (P0) fields,
one per constant, keyed by the cells' region labels (harness/mesh/gmsh_mesh.py, mesh.py and
box_mesh.py write label i + 1 on the cells of the i-th region). freefem/regions.idp defines
them; the law reads them through material.idp's `mat(...)`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from harness.core.contract import FLOATING_ROLES
from harness.core.errors import SceneError
from harness.scene.floating import check_own_potential
from harness.scene.gmsh_geometry import GmshGeometry
from harness.core.layout import Layout, case_path, is_material_path
from harness.scene.material_constants import CONSTANTS, CONSTANTS_3D, ROTATED, material_constants
from harness.scene.poling import Poling, parse_poling
from harness.scene.schema import material_reference

ENTRY_KEYS = ("material", "poling_axis", "conductor")
# A conductor region is an equipotential at the potential of a role's parts: phi = 0 with the
# ground (and the clamped parts), phi = loads.electrode_potential with the electrode; with a
# floating role, the unknown uniform potential of that floating electrode (freefem/floating.idp),
# whose given charge is then the conductor's and its boundary part's together.
CONDUCTOR_ROLES = ("ground", "electrode", *FLOATING_ROLES)


@dataclass(frozen=True)
class Region:
    name: str       # the physical group of the .geo file, or the block
    material: str
    poling: Poling  # its own poling_axis, or the scene's
    conductor: str = ""  # a role of CONDUCTOR_ROLES: the region is an equipotential at its potential


def regions_of(materials: dict[str, Any], names: tuple[str, ...], scene_poling: Any, dimension: int) -> tuple[Region, ...]:
    """Each region's entry: a material name, or a table {material = ..., poling_axis = ...}."""
    out = []
    for name in names:
        entry = materials[name]
        material = entry if isinstance(entry, str) else entry["material"]
        axis = entry.get("poling_axis", scene_poling) if isinstance(entry, dict) else scene_poling
        conductor = entry.get("conductor", "") if isinstance(entry, dict) else ""
        out.append(Region(name, material, parse_poling(axis, dimension), conductor))
    return tuple(out)


def check_regions(materials: Any, material: str, geometry: Any) -> tuple[str, ...]:
    """The region names in label order; a SceneError naming the culprit otherwise."""
    if not materials:
        if not material:
            raise SceneError("missing key scene.material (or a [scene.materials] table of region = material)")
        return ()
    if not isinstance(materials, dict):
        raise SceneError("scene.materials must be a table of region name = material")
    if material:
        raise SceneError(f"scene.material = {material!r} and [scene.materials] both given: the first is the "
                         "shorthand for one region; name every region's material in [scene.materials] instead")
    if not isinstance(geometry, GmshGeometry):
        return check_block_regions(materials, geometry)
    kind = "surface" if geometry.dimension == 2 else "volume"
    bodies = dict(geometry.bodies)
    match_names(materials, tuple(bodies), geometry.dimension,
                lambda name: f"scene.materials.{name}: {geometry.file.name} has no physical {kind} named {name!r} "
                             f"(its named {kind}s: {', '.join(bodies) or 'none'})",
                lambda name: f"{geometry.file.name}: physical {kind} {name!r} has no material in [scene.materials]")
    owner: dict[int, str] = {}
    for name, entities in geometry.bodies:
        for entity in entities:
            if entity in owner:
                raise SceneError(f"{geometry.file.name}: physical {kind}s {owner[entity]!r} and {name!r} overlap "
                                 f"({kind} {entity} is in both): a region has one material")
            owner[entity] = name
    if geometry.unnamed_bodies:
        raise SceneError(f"{geometry.file.name}: {kind} {geometry.unnamed_bodies[0]} is in no physical {kind}, so "
                         "it has no material: add it to a named region")
    return tuple(materials)


def check_block_regions(materials: dict[str, Any], geometry: Any) -> tuple[str, ...]:
    """The rectangle's or box's regions, its [geometry.blocks] (harness/scene/blocks.py has
    checked that they tile the body without overlapping)."""
    blocks = [block.name for block in getattr(geometry, "blocks", ())]
    if not blocks:
        raise SceneError("[scene.materials] needs a gmsh scene (geometry.kind = \"gmsh\") whose body has named "
                         "physical groups, or [geometry.blocks] naming the rectangle's or box's sub-blocks")
    match_names(materials, tuple(blocks), geometry.dimension,
                lambda name: f"scene.materials.{name}: geometry.blocks has no block named {name!r} "
                             f"(its blocks: {', '.join(blocks)})",
                lambda name: f"geometry.blocks.{name} has no material in [scene.materials]")
    return tuple(materials)


def match_names(materials: dict[str, Any], names: tuple[str, ...], dimension: int,
                no_part: Callable[[str], str], no_material: Callable[[str], str]) -> None:
    """Every entry valid and naming a part of the body, every part named: else the first
    culprit, in the words `no_part(name)` or `no_material(name)` give."""
    for name in materials:
        check_entry(name, materials[name], dimension)
        if name not in names:
            raise SceneError(no_part(name))
    for name in names:
        if name not in materials:
            raise SceneError(no_material(name))


def check_entry(name: str, value: Any, dimension: int) -> None:
    """One entry of [scene.materials]: a material name, or a table with a material and a poling_axis."""
    if isinstance(value, dict):
        unknown = [k for k in value if k not in ENTRY_KEYS]
        if unknown or "material" not in value:
            raise SceneError(f"scene.materials.{name} = {value!r}: a region's table has a material and may have "
                             f"a poling_axis and a conductor "
                             f"({'unknown key ' + repr(unknown[0]) if unknown else 'no material'})")
        if value.get("conductor", "") not in CONDUCTOR_ROLES + ("",):
            raise SceneError(f"scene.materials.{name}.conductor = {value['conductor']!r}: a conductor region is tied "
                             f"to the potential of one of the roles {', '.join(CONDUCTOR_ROLES)}")
        try:
            parse_poling(value.get("poling_axis", ""), dimension)
        except SceneError as exc:
            raise SceneError(f"scene.materials.{name}: {exc}") from None
        value = value["material"]
    complaint = material_reference(value) if isinstance(value, str) and value else "must be a material name"
    if complaint:
        raise SceneError(f"scene.materials.{name} = {value!r} {complaint}")


def with_paths_resolved(materials: dict[str, Any], case_dir: Path) -> dict[str, Any]:
    """[scene.materials] with each material given as a path made absolute, relative to the case
    file's folder (as scene.material and a .geo are), so that no run looks it up in the folder
    it happens to run from; library names and the rest of each entry as they were."""
    def resolved(name: str, material: str) -> str:
        return str(case_path(case_dir, material, f"scene.materials.{name}")) if is_material_path(material) else material

    return {name: resolved(name, entry) if isinstance(entry, str)
            else {**entry, "material": resolved(name, entry["material"])} for name, entry in materials.items()}


def check_conductors(table: dict[str, dict[str, Any]], regions: tuple[Region, ...]) -> None:
    """A conductor region needs the potential, fixes it by Dirichlet values on one rank's
    direct solve, and has no manufactured data of its own."""
    tied = [r for r in regions if r.conductor]
    if not tied:
        return
    check_own_potential(table, f"scene.materials.{tied[0].name}.conductor = {tied[0].conductor!r}",
                        "its phi is given everywhere", "a conductor region")


def conductor_definitions(regions: tuple[Region, ...]) -> list[str]:
    """The switch CONDUCTORS and the P0 fields of the cells tied to each role's potential
    (freefem/regions.idp makes them Dirichlet nodes of phi); none without conductor regions."""
    if not any(r.conductor for r in regions):
        return []
    fields = []
    for role in ("ground", "electrode"):
        terms = " + ".join(f"(region == {i + 1})" for i, r in enumerate(regions) if r.conductor == role) or "0."
        fields.append(f"RegionSpace rgTied{role.capitalize()} = {terms};")
    # A floating conductor's cells carry 1 + the index of its electrode (its slot in floating.idp).
    terms = " + ".join(f"(region == {i + 1}) * {FLOATING_ROLES.index(r.conductor) + 1}."
                       for i, r in enumerate(regions) if r.conductor in FLOATING_ROLES) or "0."
    fields.append(f"RegionSpace rgTiedFloating = {terms};")
    return ["macro CONDUCTORS 1 //", f"macro conductorFields {' '.join(fields)} //"]


def any_rotated(regions: tuple[Region, ...]) -> bool:
    return any(not r.poling.is_default for r in regions)


def region_definitions(regions: tuple[Region, ...], layout: Layout, dimension: int, plane: str = "strain") -> list[str]:
    """FreeFEM lines for main.edp: the switch REGIONS and, expanded by freefem/regions.idp once
    the mesh is read, each constant as a P0 field of the cells' region labels. When a region
    is rotated, every region's set carries the rotated entries (zero on the default axis)."""
    rotated = any_rotated(regions)
    names = CONSTANTS + CONSTANTS_3D + ROTATED * rotated
    values = [material_constants(r.material, layout, tuple(r.poling.macros(always=rotated).items()), dimension, plane)
              for r in regions]
    fields = []
    for name in names:
        # One term per region; a cell's own term is its value, the others 0 * value = 0.
        terms = " + ".join(f"(region == {i + 1}) * {value[name]!r}" for i, value in enumerate(values))
        fields.append(f"RegionSpace rg{name} = {terms};")
    groups = recovery_groups(regions, [tuple(value[name] for name in names) for value in values])
    terms = " + ".join(f"(region == {i + 1}) * {g + 1}." for i, g in enumerate(groups))
    fields.append(f"RegionSpace rgRecovery = {terms};")
    return ["macro REGIONS 1 //", f"macro recoveryGroups {max(groups) + 1} //",
            f"macro regionConstants {' '.join(fields)} //", *conductor_definitions(regions)]


def recovery_groups(regions: tuple[Region, ...], constants: list[tuple[float, ...]]) -> list[int]:
    """Each region's group for the error estimate's gradient recovery (freefem/estimator.idp),
    0, 1, ... in order of first appearance: regions of the same constants (material and poling)
    and the same conductor tie share one, since the gradient jumps only where the law does; so
    a body split into regions of one material is estimated as the one-region body."""
    keys = [(values, region.conductor) for region, values in zip(regions, constants)]
    first = {key: index for index, key in enumerate(dict.fromkeys(keys))}
    return [first[key] for key in keys]
