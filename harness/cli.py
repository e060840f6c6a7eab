"""`python -m harness <study> ...`: one command line, one subcommand per study.

Each study is a plug-in module `harness/studies/<name>.py` with `add_arguments(parser)` and
`run(args) -> int` (the way meshio's `_cli` wires its subcommands). Only the chosen study's
module is imported: `--help` and a `solve` do not pay for the imports of `cost` or `bench`.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from harness.core import freefem
from harness.arguments import Parser
from harness.core.contract import ExitCode
from harness.core.faults import guarded, report

# Subcommand -> its one-line help (the module's own docstring says the rest), grouped by the
# task each serves (the top-level help lists them so).
TASKS: dict[str, tuple[str, ...]] = {
    "your own part (a case file of yours)": ("solve", "convergence", "adapt", "plot"),
    "checking the scheme": ("verify", "goals", "scenes", "stress", "stability", "branches", "crosscheck"),
    "what it costs and how far it scales": ("cost", "budget", "bench", "solvers", "profile", "scale"),
}
STUDIES: dict[str, str] = {
    "convergence": "solve every level of a case; the error of each against the finest, and its slope",
    "solve": "solve one level of a case and print its results and physical checks",
    "scenes": "a convergence study of every scene in cases/ and one summary table",
    "stress": "the stress suite: every case of cases/hard/, classified, with physical checks",
    "stability": "branch stability: every hard case and scene again with its loads and mesh perturbed by round-off",
    "branches": "the solution branches of the paper's scene from four starts",
    "verify": "true errors against exact (manufactured) solutions, and the Grid Convergence Index",
    "goals": "goal estimates by dual-weighted residuals: their effectivity against exact and Richardson values",
    "adapt": "adaptive refinement from the error estimate (2D and 3D): error against unknowns, beside uniform",
    "plot": "a picture of one run's fields, 2D or 3D: a device on its deformed mesh, or a 3D section",
    "cost": "what accuracy costs: the cost-accuracy frontier of a scene",
    "budget": "each quantity's error in three parts (mesh, penalty, Newton), beside what each costs",
    "bench": "repeated timings (finest level, sweep, whole process), medians and spread",
    "solvers": "the solver table: every linear solver on the same levels, medians",
    "profile": "where a solve's time and memory go, piece by piece, medians and shares",
    "crosscheck": "FreeFEM against the GetFEM peer, level by level, field by field",
    "scale": "past one machine: a solve on 1 and 2 MPI ranks, a study on a Dask cluster",
}


def overview() -> str:
    """The top-level help: the subcommands by the task they serve."""
    lines = ["Thermo-electro-elastic contact, solved with FreeFEM and checked.", ""]
    for task, names in TASKS.items():
        lines.append(f"{task}:")
        lines += [f"  {name:<12} {STUDIES[name]}" for name in names]
    lines += ["", "Start with: python -m harness convergence my_part.toml  (docs/geometry.md: your own part)",
              "Each command's own help: python -m harness COMMAND --help"]
    return "\n".join(lines)


def parser(chosen: str | None) -> Parser:
    """The command line; only `chosen`'s plug-in adds its arguments (None: none, for --help)."""
    top = Parser(prog="python -m harness", usage="python -m harness COMMAND [options]", description=overview(),
                 formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = top.add_subparsers(dest="command", required=True, parser_class=Parser, metavar="COMMAND",
                                  help=argparse.SUPPRESS)
    for name, text in STUDIES.items():
        sub = commands.add_parser(name, prog=f"python -m harness {name}", help=text, description=text,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
        if name == chosen:
            module = plugin(name)
            sub.description = module.__doc__
            module.add_arguments(sub)
            sub.set_defaults(run=module.run)
    return top


def plugin(name: str):  # noqa: ANN201 (a module)
    return importlib.import_module(f"harness.studies.{name}")


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    freefem.version_query(freefem.BINARY)  # asked while the plug-in is imported
    try:  # the plug-in's imports are the rest of the start-up
        args = parser(chosen if chosen in STUDIES else None).parse_args(argv)
    except KeyboardInterrupt as exc:
        return report(f"interrupted by {exc.args[0] if exc.args else 'SIGINT'} during start-up", ExitCode.INTERRUPTED)
    return guarded(lambda: args.run(args))
