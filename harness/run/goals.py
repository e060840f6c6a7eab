"""A run's goals (the case's `[quantities] goals`, `--goal NAME`): main.edp's macros for
freefem/goals.idp, which estimates each goal's discretisation error by dual-weighted residuals
on the P2 space of the same mesh (docs/goals.md): the goals' list, and the P2 bulk and contact
blocks of the scene's Newton fields, named as the P1 ones of harness/scene/unknowns.py are."""

from __future__ import annotations

from harness.scene.quantities import GOAL_KINDS
from harness.scene.scene import Scene
from harness.scene.unknowns import BULK_BLOCKS, FIELDS, Unknowns

# A Newton field's P1 space -> its P2 space in freefem/goals.idp.
GOAL_SPACES = {"Uh": "goalUh", "Ph": "goalPh", "Qh": "goalQh"}


def block_matrix(name: str, rows: list[str], blocks: set[tuple[str, str]]) -> str:
    """FreeFEM's block matrix of `name.format(r=, c=)` over the Newton fields (0 where absent)."""
    cells = [", ".join(name.format(r=r, c=c) if (r, c) in blocks else "0" for c in rows) for r in rows]
    return cells[0] if len(rows) == 1 else "[" + ", ".join(f"[{row}]" for row in cells) + "]"


def vtk_name(goal: str) -> str:
    return "goal_indicator_" + goal.replace(".", "_")


def goal_definitions(scene: Scene) -> list[str]:
    """main.edp's goal macros; none for a scene without goals, so its run is what it was."""
    goals = scene.goals
    if not goals:
        return []
    unknowns = Unknowns(tuple(scene.effects), scene.dimension)
    newton = [f.low for f in unknowns.newton]
    space = {f.low: GOAL_SPACES[f.space] for f in FIELDS}
    present = {f.low for f in unknowns.fields}
    bulk = {(r, c) for r, c, effect in BULK_BLOCKS if (effect is None or effect in scene.effects)
            and r in present and c in present}
    bulk_blocks = " ".join(f"matrix gK{r}{c} = gvK{r}{c}({space[c]}, {space[r]});" for r, c in sorted(bulk))
    on = {f.low: f.contact in scene.effects for f in FIELDS}
    tangent, contact = [], set()
    for k in newton:
        form = f"vT{k}{k}" if on[k] else f"vZ{k}{k}"
        tangent.append(f"matrix gT{k}{k} = {form}({space[k]}, {space[k]});")
        contact.add((k, k))
        if k != "u" and on[k]:
            tangent.append(f"matrix gT{k}u = vT{k}u(goalUh, {space[k]});")
            contact.add((k, "u"))
    keys = {f.low: f.key for f in FIELDS}
    lines = [
        "macro GOALS 1 //",
        "macro goalList(DO) " + " ".join(f'DO({j}, {GOAL_KINDS[g]}, "{g}")' for j, g in enumerate(goals)) + " //",
        f"macro goalTotal {len(goals)} //",
        f"macro goalBulkBlocks() {bulk_blocks} //",
        f"macro goalBulkMatrix() {block_matrix('gK{r}{c}', newton, bulk)} //",
        f"macro goalContactBlocks() {' '.join(tangent)} //",
        f"macro goalContactMatrix() {block_matrix('gT{r}{c}', newton, contact)} //",
        f"macro goalUpMatrix() {block_matrix('goalUp' + '{r}', [keys[k] for k in newton], {(keys[k], keys[k]) for k in newton})} //",
        f"macro goalDownMatrix() {block_matrix('goalDown' + '{r}', [keys[k] for k in newton], {(keys[k], keys[k]) for k in newton})} //",
        "macro goalVtk() " + " ".join(f", goalEta{j}" for j in range(len(goals))) + " //",
        'macro goalVtkNames() "' + "".join(f" {vtk_name(g)}" for g in goals) + '" //',
    ]
    for f in unknowns.newton:
        body = f"r = vR{f.low}(0, {space[f.low]});" if on[f.low] else "r = 0;"
        lines.append(f"macro contactR{f.low}Goal(r) {body} //")
    return lines
