"""Material regions: `[scene.materials]` maps each named physical group of a gmsh scene's body
(surfaces in 2D, volumes in 3D) to a material; `scene.material` stays the one-region shorthand.

The regions are perfectly bonded: u, phi and theta are one continuous P1 field over the whole
body, and only the constants of the law change from cell to cell. Each region's constants are
asked of FreeFEM (harness/scene/material_constants.py: the file checked and, for a rotated poling,
rotated by freefem/material.idp) and handed to the run as piecewise-constant (P0) fields,
one per constant, keyed by the cells' region labels (harness/mesh/gmsh_mesh.py writes label i + 1
on the cells of the i-th region). freefem/regions.idp defines them; the law reads them
through material.idp's `mat(...)`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from harness.core.errors import SceneError
from harness.scene.gmsh_geometry import GmshGeometry
from harness.core.layout import Layout
from harness.scene.material_constants import CONSTANTS, CONSTANTS_3D, ROTATED, material_constants
from harness.scene.poling import Poling, parse_poling
from harness.scene.schema import safe_name

ENTRY_KEYS = ("material", "poling_axis")


@dataclass(frozen=True)
class Region:
    name: str       # the physical group of the .geo file
    material: str
    poling: Poling  # its own poling_axis, or the scene's


def regions_of(materials: dict[str, Any], names: tuple[str, ...], scene_poling: Any, dimension: int) -> tuple[Region, ...]:
    """Each region's entry: a material name, or a table {material = ..., poling_axis = ...}."""
    out = []
    for name in names:
        entry = materials[name]
        material = entry if isinstance(entry, str) else entry["material"]
        axis = entry.get("poling_axis", scene_poling) if isinstance(entry, dict) else scene_poling
        out.append(Region(name, material, parse_poling(axis, dimension)))
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
        raise SceneError("[scene.materials] needs a gmsh scene (geometry.kind = \"gmsh\") whose body has named "
                         "physical groups; the rectangle and the box have one region")
    kind = "surface" if geometry.dimension == 2 else "volume"
    bodies = dict(geometry.bodies)
    for name, value in materials.items():
        if isinstance(value, dict):
            unknown = [k for k in value if k not in ENTRY_KEYS]
            if unknown or "material" not in value:
                raise SceneError(f"scene.materials.{name} = {value!r}: a region's table has a material and may have "
                                 f"a poling_axis ({'unknown key ' + repr(unknown[0]) if unknown else 'no material'})")
            try:
                parse_poling(value.get("poling_axis", ""), geometry.dimension)
            except SceneError as exc:
                raise SceneError(f"scene.materials.{name}: {exc}") from None
            value = value["material"]
        if not isinstance(value, str) or safe_name(value):
            raise SceneError(f"scene.materials.{name} = {value!r} must be a material name (letters, digits, - _ .)")
        if name not in bodies:
            raise SceneError(f"scene.materials.{name}: {geometry.file.name} has no physical {kind} named {name!r} "
                             f"(its named {kind}s: {', '.join(bodies) or 'none'})")
    for name in bodies:
        if name not in materials:
            raise SceneError(f"{geometry.file.name}: physical {kind} {name!r} has no material in [scene.materials]")
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


def any_rotated(regions: tuple[Region, ...]) -> bool:
    return any(not r.poling.is_default for r in regions)


def region_definitions(regions: tuple[Region, ...], layout: Layout, dimension: int) -> list[str]:
    """FreeFEM lines for main.edp: the switch REGIONS and, expanded by freefem/regions.idp once
    the mesh is read, each constant as a P0 field of the cells' region labels. When a region
    is rotated, every region's set carries the rotated entries (zero on the default axis)."""
    rotated = any_rotated(regions)
    names = CONSTANTS + CONSTANTS_3D + ROTATED * rotated
    values = [material_constants(r.material, layout, tuple(r.poling.macros(always=rotated).items()), dimension)
              for r in regions]
    fields = []
    for name in names:
        # One term per region; a cell's own term is its value, the others 0 * value = 0.
        terms = " + ".join(f"(region == {i + 1}) * {value[name]!r}" for i, value in enumerate(values))
        fields.append(f"RegionSpace rg{name} = {terms};")
    return ["macro REGIONS 1 //", f"macro regionConstants {' '.join(fields)} //"]
