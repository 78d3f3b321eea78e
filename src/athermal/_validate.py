"""One place where arrays entering the public API are checked and converted."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError


def float_array(value: ArrayLike, name: str, shape: tuple[int | None, ...]) -> NDArray[np.float64]:
    """Return ``value`` as a new read-only float64 array of the given shape, all finite.

    ``None`` in ``shape`` accepts any length along that axis.
    """
    try:
        arr = np.array(value, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be converted to float64 numbers ({exc})") from None
    if arr.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(arr.shape, shape, strict=True)
    ):
        want_txt = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"{name}: expected shape {want_txt}, got {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{name}: contains NaN or infinite values (first at index {first})")
    arr.setflags(write=False)
    return arr


def positive_scalar(value: float, name: str) -> float:
    """Return ``value`` as a finite float > 0."""
    out = float(value)
    if not np.isfinite(out) or out <= 0.0:
        raise InputError(f"{name}: must be a finite number > 0, got {value!r}")
    return out


def choice(value: str, name: str, valid: tuple[str, ...]) -> str:
    """Return ``value`` if it is one of ``valid``; otherwise an error listing the choices."""
    if value not in valid:
        raise InputError(f"{name}: {value!r} is not one of {', '.join(map(repr, valid))}")
    return value
