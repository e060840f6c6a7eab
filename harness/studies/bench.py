"""A benchmark, not a test: each measurement several times, medians and spread.

    python -m harness bench cases/paper.toml [--repeats 5] [--levels 2,...,64]
        [--max-load 1.2] [--wait-s 1200] [--results results/bench]

Measurements, each repeated:
  finest   the finest level alone, warm-started from the cached chain below it, as the
           sweep runs it (FreeFEM wall time seen by the harness, and run.json's parts);
  sweep    the whole convergence study (`make convergence`'s run_study: meshes, the chain
           of runs, the error table), every level rerun, in a fresh results directory;
  cli      `python -m harness convergence CASE --force` as a process: the sweep plus
           Python's start-up, the report and the plot;
  solvers  the finest level as `finest` measures it, once with each sparse direct solver
           FreeFEM offers here (run.linear_solver): the measurement behind the default;
  cold     the finest level alone from a zero initial guess, no chain below it: what a
           user pays who solves only that level;
  startup  FreeFEM running an empty script;
  process  `python -m harness solve CASE --n FINEST --force` as a whole process from nothing
           (imports, the chain below, the report), beside its own FreeFEM run of the finest
           level: the harness's own start-up overhead;
  mesh     the finest level's mesh made and written (build_mesh: the generator, the checks,
           the MSH 2.2 file) in this process, into a fresh folder each time.
Ratios per repetition: sweep / finest level within that sweep, and newton_over_linear of
the finest level (run.json: Newton wall time over one bulk assembly plus one
factorisation, same run). The GetFEM implementation of the same scheme took 11.6 s for
the h = 1/64 level on this kind of machine.

Before starting, the benchmark waits (up to --wait-s) for the 1-minute load average to
fall below --max-load, and records the load before and after: on a shared machine a
number measured under load is a different number.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import pandas as pd

from harness.core import freefem
from harness.arguments import add_case, add_levels, add_memory_override, add_results, name_list, positive_int
from harness.study.engine import freefem_startup_s, quiet, run_levels, runs_of, timed_meshes
from harness.core.errors import HarnessError
from harness.core.layout import REPO, Layout
from harness.run.record import read_run_json
from harness.run.run import WarmStart, run_level
from harness.scene.scene import Scene, load_scene
from harness.scene.linear_solvers import SOLVERS
from harness.study.study import run_study
from harness.study.pipeline import Guarded, Plan, run_pipeline
from harness.core.writers import markdown_table, write_csv, write_json, write_text
from harness.mesh.mesh import build_mesh

GETFEM_FINEST_S = 11.6  # issue 5: GetFEM + SuperLU, 5 Newton iterations, h = 1/64
SOLVER_KEYS = ("wall_s", "first_factorisation_s", "solve_s", "newton_s", "gmres_iterations", "peak_rss_mb")
FINEST_KEYS = ("wall_s", "total_s", "newton_s", "bulk_assembly_s", "first_factorisation_s", "factorisation_s",
               "solve_s", "output_s", "newton_over_linear", "newton_iterations", "gmres_iterations", "peak_rss_mb")


def wait_for_quiet(max_load: float, wait_s: float, say: Callable[[str], None]) -> float:
    """Sleep until the 1-minute load average is below max_load (or wait_s has passed)."""
    deadline = time.monotonic() + wait_s
    load = os.getloadavg()[0]
    while load >= max_load and time.monotonic() < deadline:
        say(f"1-min load {load:.2f} >= {max_load}: waiting")
        time.sleep(30)
        load = os.getloadavg()[0]
    return load


def spread(values: Sequence[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "repeats": len(values)}


def bench_finest(case: Path, overrides: Sequence[str], levels: Sequence[int], layout: Layout, repeats: int,
                 say: Callable[[str], None]) -> list[dict[str, Any]]:
    scene = load_scene(case, [*overrides, "scene.name=bench-finest"])
    meshes, _ = timed_meshes(scene, levels, layout)
    finest = max(levels)
    below = {n: p for n, p in meshes.items() if n < finest}
    runs = runs_of(run_levels(scene, below, layout, progress=quiet)) if below else {}
    warm = runs[max(below)].warm_start(meshes[max(below)]) if below else None
    return repeat_level(scene, meshes[finest], finest, layout, warm, repeats, "finest", say)


def repeat_level(scene: Scene, mesh: Path, n: int, layout: Layout, warm: WarmStart | None, repeats: int,
                 label: str, say: Callable[[str], None]) -> list[dict[str, Any]]:
    """One level run `repeats` times, each rerun (force), alone: FINEST_KEYS of each run."""
    out = []
    for i in range(repeats):
        run = run_level(scene, mesh, n, layout, force=True, warm=warm)
        out.append({k: getattr(run.record, k) for k in FINEST_KEYS})
        say(f"{label} n={n} #{i + 1}: {run.record.wall_s:.2f} s, {run.record.newton_iterations} Newton its, "
            f"newton_over_linear {run.record.value('newton_over_linear'):.2f}")
    return out


def bench_solvers(case: Path, overrides: Sequence[str], levels: Sequence[int], layout: Layout, repeats: int,
                  say: Callable[[str], None]) -> dict[str, list[dict[str, Any]]]:
    out = {}
    for solver in SOLVERS:
        samples = bench_finest(case, [*overrides, f'run.linear_solver="{solver}"'], levels, layout, repeats, say)
        out[f"solver {solver}"] = [{k: s[k] for k in SOLVER_KEYS} for s in samples]
    return out


def bench_cold(case: Path, overrides: Sequence[str], levels: Sequence[int], layout: Layout, repeats: int,
               say: Callable[[str], None]) -> list[dict[str, Any]]:
    scene = load_scene(case, [*overrides, "scene.name=bench-cold", 'scene.initial_guess="zero"'])
    finest = max(levels)
    mesh, _ = timed_meshes(scene, [finest], layout)
    return repeat_level(scene, mesh[finest], finest, layout, None, repeats, "cold", say)


def bench_sweep(case: Path, overrides: Sequence[str], levels: Sequence[int], repeats: int,
                say: Callable[[str], None]) -> list[dict[str, Any]]:
    out = []
    scene = load_scene(case, [*overrides, "scene.name=bench-sweep"])
    for i in range(repeats):
        with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp:
            layout = Layout(results=Path(tmp))
            study = run_study(scene, tuple(levels), layout, jobs=os.cpu_count() or 1, force=True,
                              progress=lambda s: None)
            finest = study.runs[max(levels)].record
            out.append({"sweep_s": study.wall_s, "finest_in_sweep_s": finest.wall_s,
                        "sweep_over_finest": study.wall_s / finest.wall_s,
                        "runs_s": sum(r.record.wall_s for r in study.runs.values())})
        say(f"sweep #{i + 1}: {out[-1]['sweep_s']:.2f} s, finest in it {out[-1]['finest_in_sweep_s']:.2f} s")
    return out


def bench_cli(case: Path, overrides: Sequence[str], levels: Sequence[int], repeats: int,
              say: Callable[[str], None]) -> list[dict[str, Any]]:
    out = []
    for i in range(repeats):
        with tempfile.TemporaryDirectory(prefix="bench-cli-") as tmp:
            argv = [sys.executable, "-m", "harness", "convergence", str(case), "--force", "--results", tmp,
                    "--levels", ",".join(map(str, levels))]
            for item in overrides:
                argv += ["--set", item]
            start = time.perf_counter()
            done = subprocess.run(argv, cwd=REPO, capture_output=True, text=True)
            wall = time.perf_counter() - start
        if done.returncode not in (0, 1):  # 1: out of the slope band, still a finished sweep
            raise HarnessError(f"harness convergence failed: {done.stderr.strip()[-300:]}")
        out.append({"cli_s": wall})
        say(f"cli #{i + 1}: {wall:.2f} s")
    return out


# issue 23's goal for the whole process over its own FreeFEM run of the finest level.
PROCESS_GOAL = 1.25


def bench_process(case: Path, overrides: Sequence[str], levels: Sequence[int], repeats: int,
                  say: Callable[[str], None]) -> list[dict[str, Any]]:
    """`python -m harness solve CASE --n FINEST --force` as a whole process from nothing (the
    chain below the finest level included, as a user pays it), against that process's own
    FreeFEM run of the finest level (run.json's wall_s: its setup overlaps the chain below it):
    issue 13's start-up overhead, issue 23's goal PROCESS_GOAL. Beside it, in the same
    repetition, the parts of the difference that can be timed apart: Python's start-up with
    the solve path's imports (`imports_s`, a process of its own), the finest level's mesh made
    in this process (`finest_mesh_s`: gmsh and the checks, on the critical path before the
    finest FreeFEM starts), and the 1-minute load."""
    out = []
    finest = max(levels)
    scene = load_scene(case, overrides)
    for i in range(repeats):
        load = os.getloadavg()[0]
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import harness.cli, harness.studies.solve"], cwd=REPO, check=True)
        imports = time.perf_counter() - start
        with tempfile.TemporaryDirectory(prefix="bench-process-") as tmp:
            mesh = timed_meshes(scene, [finest], Layout(results=Path(tmp)))[1][finest]
        with tempfile.TemporaryDirectory(prefix="bench-process-") as tmp:
            argv = [sys.executable, "-m", "harness", "solve", str(case), "--n", str(finest), "--force",
                    "--results", tmp]
            for item in overrides:
                argv += ["--set", item]
            start = time.perf_counter()
            done = subprocess.run(argv, cwd=REPO, capture_output=True, text=True)
            wall = time.perf_counter() - start
            if done.returncode not in (0, 1):  # 1: a failed check, still a finished run
                raise HarnessError(f"harness solve failed: {done.stderr.strip()[-300:]}")
            record = read_run_json(Layout(results=Path(tmp)).level_dir(scene.name, finest))
        if record is None or record.wall_s is None:
            raise HarnessError(f"harness solve left no run.json of n={finest}")
        out.append({"process_s": wall, "finest_freefem_s": record.wall_s, "process_over_finest": wall / record.wall_s,
                    "imports_s": imports, "finest_mesh_s": mesh, "finest_waited_s": record.waited_s or 0.0,
                    "load_1min": load})
        say(f"process #{i + 1}: {wall:.2f} s, its FreeFEM run of n={finest} {record.wall_s:.2f} s "
            f"(imports {imports:.2f} s, its mesh {mesh:.2f} s, waited {record.waited_s or 0.0:.2f} s, load {load:.2f})")
    return out


def bench_mesh(case: Path, overrides: Sequence[str], levels: Sequence[int], repeats: int,
               say: Callable[[str], None]) -> list[dict[str, Any]]:
    scene = load_scene(case, overrides)
    finest = max(levels)
    samples = []
    with tempfile.TemporaryDirectory(prefix="bench-mesh-") as tmp:
        for k in range(repeats):
            start = time.perf_counter()
            summary = build_mesh(scene.geometry, finest, Path(tmp) / str(k), warn=False)
            seconds = time.perf_counter() - start
            samples.append({"mesh_s": seconds, "cells": summary.triangles, "file_mb": summary.path.stat().st_size / 1e6,
                            "load_1min": os.getloadavg()[0]})
            say(f"mesh {k + 1}/{repeats}: n={finest}, {summary.triangles} cells, {seconds:.3f} s")
    return samples


def summarise(raw: dict[str, list[dict[str, Any]]]) -> pd.DataFrame:
    rows = []
    for measurement, samples in raw.items():
        for key in samples[0]:
            values = [float(s[key]) for s in samples if s.get(key) is not None]
            if values:
                rows.append({"measurement": measurement, "quantity": key, **spread(values)})
    table = pd.DataFrame(rows)
    finest = table[(table["measurement"] == "finest") & (table["quantity"] == "wall_s")]
    if not finest.empty:
        f = finest.iloc[0]
        # The GetFEM time over ours: how many times faster (min-max from our max-min).
        rows.append({"measurement": "finest", "quantity": "speedup_vs_getfem_11.6s",
                     "median": GETFEM_FINEST_S / f["median"], "min": GETFEM_FINEST_S / f["max"],
                     "max": GETFEM_FINEST_S / f["min"], "repeats": f["repeats"]})
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame, meta: dict[str, Any]) -> str:
    lines = [
        "# Benchmark (python -m harness bench)",
        "",
        f"{meta['repeats']} repetitions each; 1-min load {meta['load_before']:.2f} before, "
        f"{meta['load_after']:.2f} after; {meta['cpus']} CPUs ({meta['cpu']}); levels {meta['levels']}.",
        "",
    ]
    rows = ([r["measurement"], r["quantity"], f"{r['median']:.4g}", f"{r['min']:.4g}", f"{r['max']:.4g}"]
            for _, r in table.iterrows())
    text = "\n".join(lines) + "\n" + markdown_table(("measurement", "quantity", "median", "min", "max"), rows)
    if (table["measurement"] == "process").any():
        text += PROCESS_NOTE.format(goal=PROCESS_GOAL)
    return text


PROCESS_NOTE = """
`process`: `python -m harness solve CASE --n FINEST --force` as a whole process, from nothing
(a fresh results folder: every mesh, the chain of levels below, the report and checks), over
its own FreeFEM run of the finest level (`finest_freefem_s`: run.json's wall_s, from its
launch to its exit less the time it sat ready, waiting for the state of the level below,
`finest_waited_s`). The goal: `process_over_finest` at most {goal}. The difference
`process_s - finest_freefem_s` is, on the critical path: Python's start-up and imports
(`imports_s`, timed as a process of its own), the meshes and launches before the finest
level's FreeFEM starts (its own mesh: `finest_mesh_s`), `finest_waited_s` (the chain below
it outlasting its setup: on two cores both compete for the same CPUs), and after its exit the
checks, the summary and the interpreter's exit. `load_1min` is the load at each repetition:
on a shared machine every number here grows with it, the ratio too.
"""


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


MEASUREMENTS = ("startup", "finest", "solvers", "cold", "sweep", "cli", "process", "mesh")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_case(parser)
    add_levels(parser, what="the case's: the sweep's levels")
    parser.add_argument("--repeats", type=positive_int, default=5,
                        help="how many times each measurement is repeated (default: 5)")
    parser.add_argument("--only", type=name_list, default=list(MEASUREMENTS),
                        help=f"comma-separated measurements ({', '.join(MEASUREMENTS)})")
    parser.add_argument("--max-load", type=float, default=1.2,
                        help="before starting, wait until the 1-minute load average is below this (default: 1.2)")
    parser.add_argument("--wait-s", type=float, default=1200,
                        help="wait at most this many seconds for that load (default: 1200)")
    add_results(parser, under="bench")
    add_memory_override(parser)


def run(args: argparse.Namespace) -> int:
    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    scene = load_scene(args.case, args.overrides)
    levels = tuple(args.levels or scene.levels)
    plan = Plan(args.results, (Guarded(scene, levels),), outputs=(args.results,),
                locked=(Layout(results=args.results / "runs").case_dir(scene.name),), ignore_memory=args.ignore_memory)
    run_pipeline(plan, lambda: measure(args, levels, say), lambda done: report(args, levels, *done))
    return 0


def measure(args: argparse.Namespace, levels: tuple[int, ...],
            say: Callable[[str], None]) -> tuple[dict[str, list[dict[str, Any]]], float]:
    """Every measurement asked for (--only), after the load has fallen; the raw samples and
    the load before."""
    freefem.freefem_version()
    layout = Layout(results=args.results / "runs")
    wanted = args.only
    load_before = wait_for_quiet(args.max_load, args.wait_s, say)
    say(f"1-min load {load_before:.2f}: starting")
    raw: dict[str, list[dict[str, Any]]] = {}
    if "startup" in wanted:
        raw["startup"] = [{"freefem_empty_script_s": freefem_startup_s(1)} for _ in range(args.repeats)]
    if "finest" in wanted:
        raw["finest"] = bench_finest(args.case, args.overrides, levels, layout, args.repeats, say)
    if "solvers" in wanted:
        raw.update(bench_solvers(args.case, args.overrides, levels, layout, args.repeats, say))
    if "cold" in wanted:
        raw["cold"] = bench_cold(args.case, args.overrides, levels, layout, args.repeats, say)
    if "sweep" in wanted:
        raw["sweep"] = bench_sweep(args.case, args.overrides, levels, args.repeats, say)
    if "cli" in wanted:
        raw["cli"] = bench_cli(args.case, args.overrides, levels, args.repeats, say)
    if "process" in wanted:
        raw["process"] = bench_process(args.case, args.overrides, levels, args.repeats, say)
    if "mesh" in wanted:
        raw["mesh"] = bench_mesh(args.case, args.overrides, levels, args.repeats, say)
    shutil.rmtree(layout.case_dir("bench-sweep"), ignore_errors=True)
    return raw, load_before


def report(args: argparse.Namespace, levels: tuple[int, ...], raw: dict[str, list[dict[str, Any]]],
           load_before: float) -> None:
    load_after = os.getloadavg()[0]
    table = summarise(raw)
    for alone in ("finest", "cold"):
        if "sweep" in raw and alone in raw:
            finest = statistics.median(s["wall_s"] for s in raw[alone])
            sweeps = [s["sweep_s"] / finest for s in raw["sweep"]]
            table = pd.concat([table, pd.DataFrame([{"measurement": "sweep", "quantity": f"sweep_over_{alone}_alone",
                                                     **spread(sweeps)}])], ignore_index=True)
    meta = {"repeats": args.repeats, "load_before": load_before, "load_after": load_after,
            "cpus": os.cpu_count(), "cpu": cpu_name(), "levels": list(levels),
            "freefem_version": freefem.freefem_version(), "getfem_finest_s": GETFEM_FINEST_S,
            "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    write_csv(table, args.results / "bench.csv")
    write_text(markdown(table, meta), args.results / "bench.md")
    write_json({"meta": meta, "raw": raw}, args.results / "bench.json")
    print(markdown(table, meta))
