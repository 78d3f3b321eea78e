"""Power-law fits ``y = a x^b`` by least squares in log-log space, with standard errors."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ._validate import float_array
from .errors import InputError


@dataclass(frozen=True)
class PowerLaw:
    """``y = prefactor x^exponent``; ``stderr`` is the exponent's standard error (the
    least-squares covariance scaled by the residual variance), ``points`` the number fitted."""

    exponent: float
    stderr: float
    prefactor: float
    points: int

    def __call__(self, x: ArrayLike) -> np.ndarray:
        """The fitted ``y`` at ``x``."""
        return self.prefactor * np.asarray(x, dtype=np.float64) ** self.exponent


def fit_power_law(
    x: ArrayLike, y: ArrayLike, *, lower: float = 0.0, upper: float = np.inf
) -> PowerLaw:
    """Fit ``y = a x^b`` to the points with ``lower <= x <= upper`` and ``x, y > 0``.

    Examples
    --------
    >>> fit = fit_power_law([1e-4, 1e-3, 1e-2], [2e-2, 2e-1, 2.0])
    >>> round(fit.exponent, 12), round(fit.prefactor, 9)
    (1.0, 200.0)
    """
    xs = float_array(x, "x", (None,))
    ys = float_array(y, "y", (xs.size,))
    keep = (xs >= lower) & (xs <= upper) & (xs > 0.0) & (ys > 0.0)
    if int(keep.sum()) < 3:
        raise InputError(
            f"fit_power_law: need at least 3 points with x in [{lower:g}, {upper:g}] and "
            f"x, y > 0; got {int(keep.sum())}"
        )
    lx, ly = np.log(xs[keep]), np.log(ys[keep])
    design = np.column_stack([lx, np.ones_like(lx)])
    coef, *_ = np.linalg.lstsq(design, ly, rcond=None)
    residual = ly - design @ coef
    dof = lx.size - 2
    variance = float(residual @ residual) / dof if dof > 0 else 0.0
    cov = variance * np.linalg.inv(design.T @ design)
    return PowerLaw(
        exponent=float(coef[0]),
        stderr=float(np.sqrt(cov[0, 0])),
        prefactor=float(np.exp(coef[1])),
        points=int(lx.size),
    )
