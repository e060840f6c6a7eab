"""Arguments the studies share: one parser of level lists, one of each common option."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from harness.contract import ExitCode
from harness.layout import REPO, Layout

if TYPE_CHECKING:
    from harness.scene import Scene


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        # One line, like every other expected failure, instead of argparse's usage dump.
        self.exit(int(ExitCode.INPUT), f"error: {message} (see --help)\n")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be positive")
    return value


def level_list(text: str) -> tuple[int, ...]:
    """`2,4,8` -> (2, 4, 8): positive, in the order given (empty parts skipped)."""
    return tuple(positive_int(part.strip()) for part in text.split(",") if part.strip())


def name_list(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def add_case(parser: argparse.ArgumentParser, optional: bool = False) -> None:
    if optional:
        parser.add_argument("case", type=Path, nargs="?", default=REPO / "cases" / "paper.toml",
                            help="case file (default: cases/paper.toml)")
    else:
        parser.add_argument("case", type=Path, help="case file, e.g. cases/paper.toml")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a case-file value, e.g. contact.S=0 (repeatable)")


def add_levels(parser: argparse.ArgumentParser, default: tuple[int, ...] | None = None,
               what: str = "the case's") -> None:
    parser.add_argument("--levels", type=level_list, default=default,
                        help=f"comma-separated n = 1/h (default: {what})")


def add_jobs(parser: argparse.ArgumentParser, default: int | None = None) -> None:
    parser.add_argument("--jobs", type=positive_int, default=default or os.cpu_count() or 1, help="parallel runs")


def add_common(parser: argparse.ArgumentParser, results: Path | None = None) -> None:
    """--force, --results and --freefem."""
    parser.add_argument("--force", action="store_true", help="rerun even if inputs are unchanged")
    parser.add_argument("--results", type=Path, default=results or Layout().results, help="results root")
    parser.add_argument("--freefem", type=Path, default=Layout().freefem, help="solver scripts")


def layout_of(args: argparse.Namespace) -> Layout:
    return Layout(results=args.results, freefem=args.freefem)


def add_scene_options(parser: argparse.ArgumentParser) -> None:
    """What `solve` and `convergence` take besides the case: effects, memory override, common."""
    from harness.guards import OVERRIDE_FLAG

    parser.add_argument("--effects", help="comma-separated effects, replacing the case's "
                        "(e.g. piezoelectric,contact,friction,electric_contact)")
    add_common(parser)
    parser.add_argument(OVERRIDE_FLAG, dest="ignore_memory", action="store_true",
                        help="run a level even when its estimated memory exceeds what is available")


def prepared_scene(args: argparse.Namespace, levels: tuple[int, ...] | None = None,
                   nested: bool = False) -> tuple[Scene, tuple[int, ...]]:
    """The case with its overrides and --effects, its warnings printed, the results root and
    the levels checked (nested when `nested`, memory unless overridden)."""
    from harness.faults import check_results_root
    from harness.guards import check_memory, check_nested, geometry_depth
    from harness.scene import load_scene

    overrides = list(args.overrides)
    if args.effects is not None:
        overrides.append("scene.effects=" + repr(name_list(args.effects)).replace("'", '"'))
    scene = load_scene(args.case, overrides)
    for warning in scene.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    check_results_root(args.results)
    levels = levels or scene.levels
    if nested:
        check_nested(levels)
    if not args.ignore_memory:
        check_memory(scene.geometry.width, scene.geometry.height, levels, scene.effects, scene.element,
                     depth=geometry_depth(scene.geometry), factorises=scene.factorises,
                     multigrid=scene.multigrid_levels > 0)
    return scene, levels
