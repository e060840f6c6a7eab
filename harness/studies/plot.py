"""`python -m harness plot RESULTS_DIR [--out PNG]`: a picture of one run's fields, from its
solution.vtu. RESULTS_DIR is a level's directory (results/strip_actuator/n16) or a scene's
(results/strip_actuator: its finest level). The picture goes to fields.png beside the
levels unless --out says where.

Two views. `device` (the default): a 2D body's phi, theta and displacement on the deformed
mesh, thickness exaggerated (a device is thin); a 3D body's phi and theta on the face where
it meets its pad and on the section y = 0 (harness/report/device_plot.py). `section`, 3D
only: phi and theta on the mid-plane with its displacement exaggerated, and on the contact
face, Gamma_3 of --case when given (harness/report/plot3d.py). `contact`: the contact pressure
along Gamma_3 from the level's contact.csv, with the tangential traction and the gap in 2D
(harness/report/contact_plot.py), into contact.png unless --out says where."""

from __future__ import annotations

import argparse
from pathlib import Path

from harness.core.errors import HarnessError

VIEWS = ("device", "section", "contact")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", type=Path, metavar="RESULTS_DIR",
                        help="a level's results directory (holding solution.vtu), or a scene's, whose finest level is drawn")
    parser.add_argument("--out", type=Path, default=None, metavar="PNG",
                        help="where to write the picture (default: fields.png, or contact.png for --view contact, in the "
                             "scene's results directory)")
    parser.add_argument("--view", choices=VIEWS, default="device",
                        help="device: the body and its deformation (2D or 3D); section: a 3D run's mid-plane and contact face; "
                             "contact: the contact pressure along Gamma_3 (contact.csv)")
    parser.add_argument("--case", type=Path, default=None,
                        help="with --view section, the case file whose contact part (Gamma_3) is drawn as the face")


def run(args: argparse.Namespace) -> int:
    level = level_dir(args.results)
    out = args.out or level.parent / ("contact.png" if args.view == "contact" else "fields.png")
    draw(level, out, args.view, args.case)
    print(f"wrote {out}")
    return 0


def level_dir(results: Path) -> Path:
    """The level directory to draw: `results` itself, or the finest level (largest n) under it."""
    if (results / "solution.vtu").is_file():
        return results
    if not results.is_dir():
        raise HarnessError(f"{results}: no such results directory")
    levels = [p for p in results.glob("n*") if p.name[1:].isdigit() and (p / "solution.vtu").is_file()]
    if not levels:
        raise HarnessError(f"{results}: neither a level's results (no solution.vtu) nor a scene's (no n<N>/solution.vtu)")
    return max(levels, key=lambda p: int(p.name[1:]))


def draw(level: Path, out: Path, view: str, case: Path | None) -> None:
    # matplotlib is imported here: `python -m harness --help` does not pay for it.
    from harness.measure.fields import read_fields

    if view == "contact":
        if case is not None:
            raise HarnessError("--case names the contact face of --view section; the contact view needs none")
        from harness.report.contact_plot import render as render_contact

        render_contact(level, out)
        return
    if view == "device":
        if case is not None:
            raise HarnessError("--case names the contact face of --view section; the device view needs none")
        from harness.report.device_plot import render

        render(level, out)
        return
    if read_fields(level / "solution.vtu").tetrahedra is None:
        raise HarnessError(f"{level}: --view section draws a 3D run; this one is 2D (use --view device)")
    if case is not None and not case.is_file():
        raise HarnessError(f"--case {case}: no such case file")
    from harness.report.plot3d import render as render_section

    render_section(level, out, case)
