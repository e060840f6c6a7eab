"""The one set of writers for what studies leave behind: CSV tables, Markdown, JSON, all
written atomically (harness/core/atomic.py), and the one rule for turning values into JSON.

Infinity: strict JSON has no NaN or infinity. NaN means "no value" (the reference level's
error, a quantity a run did not report) and is written as null; an infinity is a value
(an unbounded slip bound S, a power law that never reaches a tolerance) and is written as
the string "inf" or "-inf", so it is not mistaken for a missing one.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np
import pandas as pd

from harness.core.atomic import sibling_temp, write_atomic
from harness.core.faults import naming

CSV_FORMAT = "%.6g"  # summary tables: what a reader compares by eye
PRECISE_CSV_FORMAT = "%.10g"  # convergence tables: errors whose slopes are fitted again


def jsonable(value: Any) -> Any:
    """Strict JSON: NaN becomes null, an infinity "inf" / "-inf", numpy scalars Python's."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "item"):  # numpy scalars
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def json_text(value: Any) -> str:
    return json.dumps(jsonable(value), indent=2) + "\n"


def csv_text(table: pd.DataFrame, float_format: str = CSV_FORMAT) -> str:
    return table.to_csv(index=False, float_format=float_format)


def write_csv(table: pd.DataFrame, path: Path, float_format: str = CSV_FORMAT) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, csv_text(table, float_format))
    return path


def write_json(value: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, json_text(value))
    return path


def write_text(text: str, path: Path) -> Path:
    """Markdown (or any text) file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, text)
    return path


def write_with(render: Callable[[Path], None], path: Path) -> bool:
    """A file a renderer writes itself (a plot): rendered to a temp name, then moved over
    `path`; False (and nothing written) when the renderer wrote nothing."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = sibling_temp(path)
    try:
        with naming(path):
            render(tmp)
        if not tmp.exists():
            return False
        tmp.replace(path)
        return True
    finally:
        tmp.unlink(missing_ok=True)


def cell(value: Any) -> str:
    """A number as a Markdown table cell: 3 significant digits, blank for NaN."""
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, (float, np.floating)):
        return "" if math.isnan(value) else f"{value:.3g}"
    return str(value)


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """The one Markdown table writer: a header, its rule, a line per row of cells (str()).
    An empty cell is one space; a row shorter than the header is closed with bare pipes
    (a failed row that says why once, across the columns it has no values for)."""
    lines = [row_line(header), "|" + "---|" * len(header)]
    for row in rows:
        cells = [str(c) for c in row]
        lines.append(row_line(cells) + "|" * (len(header) - len(cells)))
    return "\n".join(lines) + "\n"


def row_line(cells: Sequence[str]) -> str:
    return "|" + "|".join(f" {c} " if c else " " for c in cells) + "|"
