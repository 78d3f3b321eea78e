"""The one printer of the ``athermal`` command: a JSON object (``--json``), or aligned
``name  value`` lines with rounded numbers, nested objects indented and lists of equal
objects as small tables."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

DIGITS = 6
"""Significant digits of a printed number (``--json`` keeps every digit)."""
PHI_DIGITS = 10
"""Significant digits of a packing fraction (``phi``, ``phi_c``, ``linear_phi_c``, ...): known
to 1e-6 or better."""
LONGEST = 12
"""A list of more numbers than this prints as its length, range and mean (``--json`` has them
all): a histogram's 100 bins are not for reading on a terminal."""


def _digits(key: str) -> int:
    return PHI_DIGITS if "phi" in key.split("_") else DIGITS


def plain(value: Any) -> Any:
    """``value`` with numpy scalars and arrays as Python numbers and lists, tuples as lists,
    non-finite floats as None (JSON has no NaN)."""
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        return plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    return value


def number(value: Any, digits: int = DIGITS) -> str:
    """A number rounded to ``digits`` significant digits (integers and text as they are)."""
    if isinstance(value, bool) or value is None:
        return {True: "yes", False: "no", None: "-"}[value]
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _cell(value: Any) -> str:
    if isinstance(value, list) and all(isinstance(v, int | float | None) for v in value):
        numbers = [v for v in value if v is not None]
        if len(value) > LONGEST and numbers:
            return (
                f"{len(value)} values, {number(min(numbers), 4)} ... {number(max(numbers), 4)}, "
                f"mean {number(float(np.mean(numbers)), 4)} (--json: all)"
            )
        return ", ".join(number(v, 4) for v in value)
    return number(value)


def _is_table(value: Any) -> bool:
    """A non-empty list of objects with the same keys and scalar values."""
    return (
        isinstance(value, list)
        and bool(value)
        and all(isinstance(v, dict) for v in value)
        and all(v.keys() == value[0].keys() for v in value)
        and all(not isinstance(x, dict | list) for v in value for x in v.values())
    )


def _table(rows: Sequence[dict[str, Any]], indent: str) -> list[str]:
    keys = list(rows[0])
    cells = [[number(r[k]) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    lines = [indent + "  ".join(k.rjust(w) for k, w in zip(keys, widths, strict=True))]
    lines += [
        indent + "  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in cells
    ]
    return lines


def lines(summary: Mapping[str, Any], indent: str = "") -> list[str]:
    """The plain-text lines of ``summary`` (already :func:`plain`)."""
    width = max((len(k) for k in summary), default=0)
    out: list[str] = []
    for key, value in summary.items():
        if (
            isinstance(value, dict)
            and value
            and all(not isinstance(v, dict | list) for v in value.values())
            and len(value) <= 6
        ):
            text = "  ".join(f"{k} {number(v, _digits(k))}" for k, v in value.items())
            out.append(f"{indent}{key:<{width}}  {text}")
        elif isinstance(value, dict) and value:
            out.append(f"{indent}{key}")
            out += lines(value, indent + "  ")
        elif _is_table(value):
            out.append(f"{indent}{key}")
            out += _table(value, indent + "  ")
        elif isinstance(value, dict | list) and not value:
            out.append(f"{indent}{key:<{width}}  none")
        else:
            text = number(value, _digits(key)) if isinstance(value, float) else _cell(value)
            out.append(f"{indent}{key:<{width}}  {text}")
    return out


def emit(summary: Mapping[str, Any], as_json: bool) -> None:
    """Print ``summary``: one JSON object on stdout, or aligned, rounded lines."""
    data = plain(summary)
    if as_json:
        print(json.dumps(data))
    else:
        print("\n".join(lines(data)))
