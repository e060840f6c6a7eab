"""Each section of a case file as a frozen dataclass, derived from the schema
(harness/scene/schema.py) so that the two cannot drift apart: `scene.sections.contact.gap`
instead of indexing the raw table. A key of an effect that is off is None (FreeFEM never
reads it); a section the schema lists and the file leaves out holds its defaults."""

from __future__ import annotations

import dataclasses
from typing import Any

from harness.scene.schema import BOX_GEOMETRY, GMSH_GEOMETRY, SCHEMA


def section_class(section: str, keys: dict | None = None, name: str | None = None) -> type:
    keys = SCHEMA[section] if keys is None else keys
    fields = [(key, spec.kind | None, dataclasses.field(default=None)) for key, spec in keys.items()]
    name = name or "".join(part.capitalize() for part in section.split("_")) + "Section"
    return dataclasses.make_dataclass(name, fields, frozen=True)


# section -> its dataclass; `Sections` holds one instance of each.
SECTION_CLASSES: dict[str, type] = {section: section_class(section) for section in SCHEMA}
# The [geometry] of a box (harness/scene/box.py) or gmsh scene (harness/scene/gmsh_geometry.py) has keys
# of its own, by kind as schema.geometry_keys.
GEOMETRY_SECTIONS: dict[str, type] = {"box": section_class("geometry", BOX_GEOMETRY, "BoxGeometrySection"),
                                      "gmsh": section_class("geometry", GMSH_GEOMETRY, "GmshGeometrySection")}
Sections = dataclasses.make_dataclass(
    "Sections", [(section, cls) for section, cls in SECTION_CLASSES.items()], frozen=True)


def sections_of(table: dict[str, dict[str, Any]]) -> Any:
    """A resolved table (scene.resolve) as a Sections instance."""
    classes = dict(SECTION_CLASSES)
    classes["geometry"] = GEOMETRY_SECTIONS.get(table.get("geometry", {}).get("kind"), classes["geometry"])
    return Sections(**{s: cls(**table.get(s, {})) for s, cls in classes.items()})
