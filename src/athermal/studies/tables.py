"""Per-step tables of the protocols as CSV files, written atomically."""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Sequence
from pathlib import Path

from .._records import Row
from ..atomic import write_text
from ..errors import FileFormatError, InputError


def write_table(path: str | os.PathLike[str], rows: Sequence[Row]) -> None:
    """Write ``rows`` (same keys in each) as CSV with a header, replacing ``path`` atomically.

    Floats are written with ``repr`` (round-trip exact). On any error a file already at ``path``
    is left untouched.
    """
    if not rows:
        raise InputError("rows: a table needs at least one row")
    columns = list(rows[0])
    if any(list(row) != columns for row in rows):
        raise InputError("rows: every row must have the same columns in the same order")
    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(columns)
    for row in rows:
        writer.writerow([repr(float(v)) if isinstance(v, float) else v for v in row.values()])
    write_text(path, buffer.getvalue())


def _value(text: str) -> float | str:
    try:
        return float(text)
    except ValueError:
        return text


def read_table(path: str | os.PathLike[str]) -> list[dict[str, float | str]]:
    """Read a table written by :func:`write_table`: numbers as floats, other cells as text."""
    source = Path(path)
    try:
        with open(source, newline="", encoding="utf-8") as handle:
            rows = [{k: _value(v) for k, v in row.items()} for row in csv.DictReader(handle)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise FileFormatError(f"{source}: not a readable athermal table ({exc})") from exc
    return rows
