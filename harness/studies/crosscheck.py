"""`python -m harness crosscheck CASE [CASE ...] --levels 2,4,8 --branches zero,pressed`:
every level solved by FreeFEM (the harness's chain) and by the GetFEM peer (peer_getfem/peer.py,
from the branch's start) on the same mesh; the relative difference of each field in its norm
(V, W, Q) and at the nodes, the contact integrals, Newton iterations, whole-process time and
memory of both, into results/crosscheck/ (crosscheck.csv, crosscheck.md, crosscheck.png).
Exit 6 (DISAGREE) when a field differs by more than 1e-8 relative, naming field and level;
5 (NO_PEER) when GetFEM is not installed (docs/crosscheck.md)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import pandas as pd

from harness.arguments import add_common, name_list, positive_int, study_levels
from harness.measure.crosscheck import TOLERANCE, differences, integral_differences
from harness.study.adapt import DEFAULT_BULK, adapt, adaptive_overrides
from harness.study.engine import InlineMeshes, quiet, run_levels, runs_of
from harness.core.errors import Disagreement, FieldsError, RunError, SceneError
from harness.measure.fields import Fields, read_fields
from harness.core.layout import Layout
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.measure.norm_table import MEASURE
from harness.scene.materials import values as material_values
from harness.run.peer import PeerRegion, pressed_depth, problem, require_getfem, run_peer
from harness.run.record import RunRecord
from harness.scene.scene import Scene, load_scene

# The coarse levels a cross-check takes by default: enough to see round-off, seconds each.
COARSE = {2: (2, 4, 8), 3: (2, 4)}
NORM_OF = {term.field: term.norm for term in MEASURE}  # V, W, Q: the columns rel_u_V, ...


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("cases", type=Path, nargs="+", help="case files, e.g. cases/paper.toml")
    parser.add_argument("--levels", type=study_levels, help="levels n = 1/h (default: the case's up to 8 in 2D, 4 in 3D)")
    parser.add_argument("--branches", type=name_list, help="starts to compare: zero, pressed (default: the case's own)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a case value, e.g. --set contact.S=4 (repeatable)")
    parser.add_argument("--out", type=Path, help="output folder (default: RESULTS/crosscheck)")
    parser.add_argument("--repeat", type=positive_int, default=1,
                        help="also time the finest level N more times per code, FreeFEM and GetFEM alternating, "
                        "medians into timing.csv and timing.md")
    parser.add_argument("--adapted", type=positive_int, metavar="STEPS",
                        help="also compare on the mesh of the adaptive loop's step STEPS (from the case's coarsest "
                        "level, as `adapt` makes it): non-uniform and bisected, unlike the levels")
    parser.add_argument("--figures", type=Path, help="also draw the paper's figures from both codes at the "
                        "finest level into this folder (docs/crosscheck.md)")
    add_common(parser)


@dataclass(frozen=True)
class Compared:
    """What the runs of a cross-check gave: the table's rows, each failed scene's line, the timings."""

    rows: list[dict]
    failures: list[str]
    timed: list[dict]


def run(args: argparse.Namespace) -> int:
    # Both codes' runs in RESULTS/crosscheck/runs/<scene>/ (not committed): FreeFEM's every
    # level from the branch's start, not the warm-started runs of a study.
    layout = Layout(results=args.results / "crosscheck" / "runs", freefem=args.freefem)
    plans = [plan for case in args.cases for plan in plans_of(case, args.overrides, args.branches, args.levels)]
    if args.figures and any(scene.regions or not scene.poling.is_default for scene, _, _ in plans):
        # peer_figures.render computes the stress with one material in its own axes
        raise SceneError("--figures draws scenes of one material on its own poling axis only")
    require_getfem()
    out = args.out or args.results / "crosscheck"
    # The one study pipeline (harness/study/pipeline.py): its runs, table and figures all new or
    # all the earlier ones, and no other study writing them meanwhile.
    plan = Plan(args.results, tuple(Guarded(scene, levels) for scene, _, levels in plans),
                scene_dirs=tuple(dict.fromkeys(layout.case_dir(scene.name) for scene, _, _ in plans)),
                outputs=(out, *([args.figures] if args.figures else [])), ignore_memory=args.ignore_memory)

    def runs() -> Compared:
        done = Compared([], [], [])
        for scene, start, levels in plans:
            try:
                done.rows.extend(compare(scene, start, levels, layout, args.force, args.figures))
                if args.adapted:
                    done.rows.extend(compare_adapted(scene, start, args.adapted, args.overrides, layout, args.force))
                if args.repeat > 1:
                    done.timed.append(timing(scene, start, max(levels), layout, args.repeat))
            except (RunError, FieldsError) as exc:  # recorded; the other scenes still run
                done.failures.append(f"{scene.name} ({start}): {exc}")
                done.rows.append({"scene": scene.name, "case": scene.source.stem, "branch": start,
                                  "dimension": scene.dimension, "status": f"failed: {exc}"})
                print(f"{scene.name} ({start}): failed: {exc}", flush=True)
        return done

    def report(done: Compared) -> None:
        table = pd.DataFrame(done.rows)
        write(table, out)
        if done.timed:
            write_timing(pd.DataFrame(done.timed), out)
        print(summary_markdown(table))
        print(f"wrote {out}/crosscheck.csv, crosscheck.md, crosscheck.png")

    def verdict(done: Compared) -> None:
        """A disagreement (exit 6) before a failed scene (exit 3), the report written."""
        worst = worst_row(pd.DataFrame(done.rows))
        if worst is not None:
            raise Disagreement(f"{worst['scene']} ({worst['branch']}) n={int(worst['n'])}: {worst['field']} differs "
                               f"by {worst['value']:.3g} relative (tolerance {TOLERANCE:g})")
        if done.failures:
            raise RunError(done.failures[0] + (f" (+{len(done.failures) - 1} more)" if len(done.failures) > 1 else ""))

    run_pipeline(plan, runs, report, verdict)
    return 0


def plans_of(case: Path, overrides: list[str], branches: list[str] | None,
             levels: tuple[int, ...] | None) -> list[tuple[Scene, str, tuple[int, ...]]]:
    base = load_scene(case, overrides)
    if base.element != "P1" or base.manufactured:
        raise SceneError(f"{case}: the GetFEM peer solves P1 scenes without manufactured sources")
    tied = [r for r in base.regions if r.conductor]
    if tied:  # unsupported, not a disagreement: the peer would solve the region as a dielectric
        raise SceneError(f"{case}: the GetFEM peer has no conductor regions (scene.materials.{tied[0].name}.conductor "
                         f"= {tied[0].conductor!r})")
    own = base.sections.scene.coarsest_guess if base.initial_guess == "coarser" else base.initial_guess
    out = []
    for start in branches or [own]:
        if start not in ("zero", "pressed"):
            raise SceneError(f"--branches: {start!r} is not a start (zero, pressed)")
        name = base.name if start == own else f"{base.name}_{start}"  # a branch of its own
        # Every level from the same start in both codes (not FreeFEM's warm-started chain),
        # so that their Newton iterations compare too.
        scene = load_scene(case, [*overrides, f"scene.name={name}", f"scene.initial_guess={start}"])
        chosen = levels or tuple(n for n in scene.levels if n <= max(COARSE[scene.dimension])) or scene.levels[:1]
        out.append((scene, start, tuple(sorted(chosen))))
    return out


def compare_adapted(scene: Scene, start: str, steps: int, overrides: list[str], layout: Layout,
                    force: bool) -> list[dict]:
    """Both codes on the mesh of the adaptive loop's step `steps` (harness/study/adapt.py: the
    loop warm-starts, so it runs as a scene of its own), each from the branch's start. Its row
    names the mesh; its n is the step."""
    looping = load_scene(scene.source, [*overrides, *adaptive_overrides(scene), f"scene.name={scene.name}_adapting",
                                        "scene.initial_guess=coarser"])
    adaptation = adapt(looping, None, layout, steps, DEFAULT_BULK, None, force, quiet, lambda line: None)
    last = adaptation.steps[-1]
    compared = load_scene(scene.source, [*overrides, f"scene.name={scene.name}_adapted", f"scene.initial_guess={start}"])
    rows = compare(compared, start, (last.index,), layout, force, meshes={last.index: last.mesh})
    return [dict(row, mesh=f"adaptive step {last.index}, {last.cells} cells") for row in rows]


def compare(scene: Scene, start: str, levels: tuple[int, ...], layout: Layout, force: bool,
            figures: Path | None = None, meshes: Mapping[int, Path] | None = None) -> list[dict]:
    """Both codes on each level, or on the given meshes (one per label in `levels`)."""
    meshes = meshes or InlineMeshes(scene, list(levels), layout)
    runs = runs_of(run_levels(scene, meshes, layout, force=force, progress=quiet))
    material = material_values(layout.material_file(scene.material))
    # Each region's label is 1 + its index (harness/gmsh_mesh.py region_labels).
    regions = tuple(PeerRegion(i + 1, material_values(layout.material_file(r.material)), r.poling.axis)
                    for i, r in enumerate(scene.regions))
    poling = None if scene.poling.is_default else scene.poling.axis
    rows = []
    for n in levels:
        ours = runs[n]
        spec = problem(scene.solver_parameters(), scene.effects, scene.dimension, material, meshes[n], start,
                       pressed_depth(scene.table), poling, regions, scene.plane)
        peer = run_peer(spec, layout.case_dir(scene.name) / f"getfem_n{n}", 10 * scene.timeout_s)
        fields = read_fields(ours.directory / "solution.vtu")
        diffs, _ = differences(fields, peer.record, scene.fields, ours.record.scales or {})
        if figures is not None and n == max(levels):
            from harness.report.peer_figures import render

            render(fields, peer.record, material, scene.fields, f"{scene.name}, {start} start, h = 1/{n}: "
                   "FreeFEM, GetFEM and their difference", figures / f"{scene.name}_n{n}.png")
        row = {"scene": scene.name, "case": scene.source.stem, "branch": start, "dimension": scene.dimension, "n": n,
               "dofs": ours.record.dofs, "peer_dofs": peer.record["dofs"]}
        for name, d in diffs.items():
            row[f"rel_{name}_{NORM_OF[name]}"] = d.relative
            row[f"rel_{name}_nodal"] = d.relative_nodal
            row[f"diff_{name}_{NORM_OF[name]}"] = d.norm
            row[f"max_{name}_nodal"] = d.max_nodal
        for key, (a, b, rel) in integral_differences(ours.record, peer.record).items():
            row[f"{key}_freefem"], row[f"{key}_getfem"], row[f"rel_{key}"] = a, b, rel
        row.update({
            "newton_freefem": ours.record.newton_iterations, "newton_getfem": peer.record["newton_iterations"],
            "restarted_freefem": ours.record.restarted_at, "restarted_getfem": peer.record["restarted_at"],
            "wall_s_freefem": ours.record.wall_s, "wall_s_getfem": peer.wall_s,
            "rss_mb_freefem": ours.record.peak_rss_mb, "rss_mb_getfem": peer.peak_rss_mb,
            "reused_freefem": ours.reused,
        })
        row["status"] = "agree" if all(d.relative <= TOLERANCE for d in diffs.values()) else \
            branch_or_disagree(fields, scene, spec, layout.case_dir(scene.name) / f"getfem_n{n}_from_freefem", ours.record)
        rows.append(row)
        worst = max(v for k, v in row.items() if k.startswith("rel_") and k.split("_")[1] in NORM_OF)
        print(f"{scene.name} n={n} ({start}): worst field difference {worst:.2e}; Newton {row['newton_freefem']} "
              f"(FreeFEM) / {row['newton_getfem']} (GetFEM)", flush=True)
    return rows


# Phases both codes time (FreeFEM: CPU seconds from run.json, one thread; the peer: wall
# seconds of its own clock, one thread): name -> (FreeFEM's keys, summed; the peer's key).
PHASES = {"assembly": (("bulk_assembly_s", "assembly_s"), "assembly_s"),
          "factorisation": (("factorisation_s",), "factorisation_s"),
          "newton": (("newton_s",), "newton_s")}


def timing(scene: Scene, start: str, n: int, layout: Layout, repeat: int) -> dict:
    """Level n run `repeat` times by each code as whole processes, FreeFEM and GetFEM
    alternating (so that a change of the machine's load hits both): medians and ranges."""
    import statistics

    meshes = InlineMeshes(scene, [n], layout)
    spec = problem(scene.solver_parameters(), scene.effects, scene.dimension,
                   material_values(layout.material_file(scene.material)), meshes[n], start, pressed_depth(scene.table),
                   plane=scene.plane)
    samples: dict[str, list[float]] = {}
    for _ in range(repeat):
        ours = runs_of(run_levels(scene, meshes, layout, force=True, progress=quiet, pipelined=False))[n].record
        theirs = run_peer(spec, layout.case_dir(scene.name) / f"getfem_n{n}_timing", 10 * scene.timeout_s)
        add = lambda key, value: samples.setdefault(key, []).append(float(value))  # noqa: E731
        add("wall_s_freefem", ours.wall_s)
        add("wall_s_getfem", theirs.wall_s)
        add("rss_mb_freefem", ours.peak_rss_mb)
        add("rss_mb_getfem", theirs.peak_rss_mb)
        for phase, (keys, key) in PHASES.items():
            add(f"{phase}_s_freefem", sum(float(ours.value(k)) for k in keys))
            add(f"{phase}_s_getfem", theirs.record[key])
    row = {"scene": scene.name, "branch": start, "dimension": scene.dimension, "n": n, "dofs": ours.dofs,
           "repeats": repeat}
    for key, values in samples.items():
        row[key] = statistics.median(values)
        row[f"{key}_min"], row[f"{key}_max"] = min(values), max(values)
    for what in ("wall_s", "rss_mb", *(f"{p}_s" for p in PHASES)):
        row[f"ratio_{what}"] = row[f"{what}_freefem"] / max(row[f"{what}_getfem"], 1e-300)
    return row


def write_timing(table: pd.DataFrame, out: Path) -> None:
    table.to_csv(out / "timing.csv", index=False, float_format="%.6g")
    lines = ["| scene | branch | n | dofs | runs | whole process s FreeFEM / GetFEM (ratio) | peak MB FreeFEM / GetFEM (ratio) | "
             "assembly ratio | factorisation ratio | Newton ratio |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in table.itertuples(index=False):
        lines.append(f"| {r.scene} | {r.branch} | {r.n} | {r.dofs:,} | {r.repeats} | {r.wall_s_freefem:.2f} / "
                     f"{r.wall_s_getfem:.2f} ({r.ratio_wall_s:.2f}) | {r.rss_mb_freefem:.0f} / {r.rss_mb_getfem:.0f} "
                     f"({r.ratio_rss_mb:.2f}) | {r.ratio_assembly_s:.2f} | {r.ratio_factorisation_s:.2f} | "
                     f"{r.ratio_newton_s:.2f} |")
    (out / "timing.md").write_text("Medians; ratio FreeFEM / GetFEM (below 1: FreeFEM faster or smaller).\n\n"
                                   + "\n".join(lines) + "\n")


def branch_or_disagree(fields: Fields, scene: Scene, spec: dict, work: Path, record: RunRecord) -> str:
    """Two solutions of the same discrete problem (docs/model.md section 6), or a mistake?
    The peer starts from FreeFEM's solution: if its Newton stays there (no step larger than
    the tolerance, the result equal to FreeFEM's), FreeFEM's solution solves the peer's
    equations too, and the two codes' Newton paths went to different branches."""
    given = {"points": fields.points.tolist(), **{n: fields.field(n).tolist() for n in scene.fields}}
    try:
        check = run_peer({**spec, "start": "given", "given": given}, work, 10 * scene.timeout_s).record
    except RunError:
        return "DISAGREE"
    diffs, _ = differences(fields, check, scene.fields, record.scales or {})
    first = max(v[0] for v in check["increments"].values())
    if all(d.relative <= TOLERANCE for d in diffs.values()) and first <= TOLERANCE:
        return (f"branch: FreeFEM's solution solves GetFEM's equations (first step {first:.0e}); "
                f"the codes' Newton paths reached different solutions")
    return "DISAGREE"


def field_columns(table: pd.DataFrame) -> list[str]:
    return [c for c in table.columns if c.startswith("rel_") and c.split("_")[1] in NORM_OF]


def worst_row(table: pd.DataFrame) -> dict | None:
    """The largest field difference above TOLERANCE (None: every field agrees)."""
    if table.empty or not field_columns(table):
        return None
    rows = table[table["status"] == "DISAGREE"]  # a row on another branch is explained, not a failure
    long = rows.melt(id_vars=["scene", "branch", "n"], value_vars=field_columns(table), var_name="field")
    long = long[long["value"] > TOLERANCE]
    if long.empty:
        return None
    row = long.loc[long["value"].idxmax()].to_dict()
    row["field"] = row["field"].removeprefix("rel_").replace("_", " ", 1)
    return row


def table_markdown(table: pd.DataFrame) -> str:
    cols = ["scene", "branch", "n", "dofs", "status", *field_columns(table), "newton_freefem", "newton_getfem",
            "wall_s_freefem", "wall_s_getfem", "rss_mb_freefem", "rss_mb_getfem"]
    shown = table[[c for c in cols if c in table.columns]]
    head = "| " + " | ".join(shown.columns) + " |\n|" + "---|" * len(shown.columns) + "\n"
    cell = lambda v: "–" if pd.isna(v) else f"{v:.2e}" if isinstance(v, float) else str(v)[:120]  # noqa: E731
    return head + "\n".join("| " + " | ".join(cell(v) for v in row) + " |" for row in shown.itertuples(index=False))


def summary_markdown(table: pd.DataFrame) -> str:
    """One row per scene and branch: its levels, the worst field difference (which field,
    which level), the worst contact integral, Newton iterations of both codes, the verdict."""
    lines = ["| scene | branch | d | levels | worst field difference | worst contact integral | Newton its FreeFEM | GetFEM | status |",
             "|---|---|---|---|---|---|---|---|---|"]
    fields = field_columns(table)
    integrals = [c for c in table.columns if c.startswith("rel_") and c not in fields]
    for (scene, branch), g in table.groupby(["scene", "branch"], sort=False):
        if g["status"].iloc[0].startswith("failed"):
            lines.append(f"| {scene} | {branch} | {g['dimension'].iloc[0]} | – | – | – | – | – | {g['status'].iloc[0][:100]} |")
            continue
        worst = g[fields].stack().astype(float)
        (row, col), value = worst.idxmax(), worst.max()
        where = f"{value:.1e} ({col[4:].replace('_', ' ')}, n = {int(g.loc[row, 'n'])})"
        # A scene without contact has no integrals: its columns are empty beside those of the others.
        ints = g[integrals].stack().astype(float).dropna() if integrals else pd.Series(dtype=float)
        integral = f"{ints.max():.1e} ({ints.idxmax()[1][4:].replace('_', ' ')})" if len(ints) else "–"
        its = lambda code: " ".join(str(int(v)) for v in g[f"newton_{code}"])  # noqa: E731
        status = "DISAGREE" if (g["status"] == "DISAGREE").any() else \
            "agree" if (g["status"] == "agree").all() else "; ".join(
                f"n = {int(n)}: {st}" for n, st in zip(g["n"], g["status"]) if st != "agree")
        lines.append(f"| {scene} | {branch} | {g['dimension'].iloc[0]} | {' '.join(str(int(n)) for n in g['n'])} | "
                     f"{where} | {integral} | {its('freefem')} | {its('getfem')} | {status} |")
    return "\n".join(lines)


def write(table: pd.DataFrame, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "crosscheck.csv", index=False, float_format="%.6g")
    (out / "crosscheck.md").write_text("## Per scene and branch\n\n" + summary_markdown(table)
                                       + "\n\n## Per level\n\n" + table_markdown(table) + "\n")
    fig, ax = plt.subplots(figsize=(7, 4.5))
    done = table.dropna(subset=["n"]) if "n" in table else table.iloc[0:0]
    if "mesh" in done:  # an adapted mesh has no h
        done = done[done["mesh"].isna()]
    for (scene, branch), group in done.groupby(["scene", "branch"]):
        for col in field_columns(group):
            if group[col].notna().any() and "nodal" not in col:
                ax.loglog(1.0 / group["n"], group[col].clip(lower=1e-17, upper=1.0), "o-", lw=0.8, ms=3,
                          label=f"{scene} {col[4:]}" if len(done.groupby(["scene", "branch"])) <= 6 else None)
    ax.axhline(TOLERANCE, color="k", ls="--", lw=1, label="tolerance 1e-8")
    ax.set_xlabel("h")
    ax.set_ylabel("|FreeFEM - GetFEM| / |FreeFEM| (field norm)")
    ax.legend(fontsize=6, ncol=2)  # many scenes: only the tolerance is labelled
    fig.tight_layout()
    fig.savefig(out / "crosscheck.png", dpi=110)
    plt.close(fig)
