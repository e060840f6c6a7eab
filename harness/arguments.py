"""Arguments the studies share: one parser of level lists, one of each common option."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any, Callable, NoReturn

from harness.core.contract import ExitCode
from harness.core.errors import SceneError
from harness.core.layout import REPO, Layout, results_root


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
    """`2,4,8` -> (2, 4, 8): positive, in the order given; '' -> () (an option's "none")."""
    if not text.strip():
        return ()
    parts = [part.strip() for part in text.split(",")]
    if "" in parts:
        raise argparse.ArgumentTypeError(f"{text!r} has an empty level between its commas")
    return tuple(positive_int(part) for part in parts)


def study_levels(text: str) -> tuple[int, ...]:
    """A study's --levels: as level_list, but never empty (leaving the option out means the
    case's own levels; an empty value is a mistake, not that)."""
    levels = level_list(text)
    if not levels:
        raise argparse.ArgumentTypeError("no levels given (leave --levels out for the case's own)")
    return levels


def name_list(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def add_case(parser: argparse.ArgumentParser, optional: bool = False) -> None:
    if optional:
        parser.add_argument("case", type=Path, nargs="?", default=REPO / "cases" / "paper.toml",
                            help="case file (default: cases/paper.toml)")
    else:
        parser.add_argument("case", type=Path, help="case file, e.g. cases/paper.toml")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="change one value of the case file for this run, e.g. --set contact.S=0 (repeatable)")


def add_levels(parser: argparse.ArgumentParser, default: tuple[int, ...] | None = None,
               what: str = "the case's") -> None:
    parser.add_argument("--levels", type=study_levels, default=default,
                        help=f"the levels to run, comma-separated, e.g. 2,4,8: level n has cells of about 1/n in the "
                        f"model's units (default: {what})")


def add_jobs(parser: argparse.ArgumentParser, default: int | None = None) -> None:
    parser.add_argument("--jobs", type=positive_int, default=default or os.cpu_count() or 1,
                        help="how many levels may run at the same time (default: the number of cores)")


def add_common(parser: argparse.ArgumentParser, under: str = "") -> None:
    """--force, --results, --freefem and the memory guard's override. `under`: the study's
    own folder inside ./results (its default)."""
    parser.add_argument("--force", action="store_true",
                        help="run every level again, even those whose inputs are unchanged since the last run")
    add_results(parser, under)
    parser.add_argument("--freefem", type=Path, default=Layout().freefem, metavar="DIR",
                        help="the folder of FreeFEM scripts to solve with (default: the harness's own freefem/)")
    add_memory_override(parser)


def add_results(parser: argparse.ArgumentParser, under: str = "") -> None:
    default = results_root() / under if under else results_root()
    parser.add_argument("--results", type=Path, default=default, metavar="DIR",
                        help=f"the folder results are written into (default: {default.relative_to(Path.cwd())} "
                        "under the working directory)")


def add_memory_override(parser: argparse.ArgumentParser) -> None:
    from harness.core.guards import OVERRIDE_FLAG

    parser.add_argument(OVERRIDE_FLAG, dest="ignore_memory", action="store_true",
                        help="run a level even when its estimated memory exceeds what is available")


def add_cluster(parser: argparse.ArgumentParser) -> None:
    """--scheduler / --cluster, for a study whose independent pieces can run on a cluster
    (harness/study/executor.py's `cluster`), each checked as the command line is read."""
    from harness.study.executor import parse_cluster, scheduler_address

    parser.add_argument("--scheduler", metavar="tcp://HOST:PORT", type=checked_by(scheduler_address),
                        help="run the study's chains on this Dask scheduler (workers share the results path)")
    parser.add_argument("--cluster", metavar="local:N", type=checked_by(lambda text: parse_cluster(text) and text),
                        help="run them on a local Dask cluster of N worker processes")


def checked_by(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a parser that raises SceneError: its one line becomes the error."""
    def check(text: str) -> Any:
        try:
            return parse(text)
        except SceneError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return check


def layout_of(args: argparse.Namespace) -> Layout:
    return Layout(results=args.results, freefem=args.freefem)


def add_goals(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--goal", dest="goals", action="append", default=[], metavar="NAME",
                        help="estimate this quantity's discretisation error by dual-weighted residuals (repeatable; "
                        "in place of the case's quantities.goals), e.g. --goal heat_through_contact (docs/goals.md)")


def goal_overrides(args: argparse.Namespace) -> list[str]:
    """--goal NAME ... as the one --set that names the case's goals (none given: the case's own)."""
    goals = getattr(args, "goals", [])
    return [f"quantities.goals={json.dumps(goals)}"] if goals else []


def add_effects(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--effects", type=name_list, help="the physics to switch on, comma-separated, in place of "
                        "the case's scene.effects (e.g. piezoelectric,contact,friction,electric_contact)")
