"""Power-law fits ``y = a x^b`` by least squares in log-log space, with standard errors; a
sample's mean with its standard error."""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validate import float_array
from ..errors import InputError


@dataclass(frozen=True)
class PowerLaw:
    """``y = prefactor x^exponent``; ``stderr`` is the exponent's standard error (the
    least-squares covariance scaled by the residual variance), ``points`` the number fitted and
    ``x_min``, ``x_max`` the range of ``x`` they span."""

    exponent: float
    stderr: float
    prefactor: float
    points: int
    x_min: float
    x_max: float

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
    if int(keep.sum()) < 3 or np.unique(xs[keep]).size < 2:
        raise InputError(
            f"fit_power_law: need at least 3 points with x in [{lower:g}, {upper:g}] and "
            f"x, y > 0, at 2 or more distinct x; got {int(keep.sum())}"
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
        x_min=float(xs[keep].min()),
        x_max=float(xs[keep].max()),
    )


def fit_jamming_point(phi: ArrayLike, pressure: ArrayLike) -> tuple[float, PowerLaw]:
    """Fit ``p = a (phi - phi_0)^b`` with the jamming point ``phi_0`` free.

    Least squares in ``log p`` over ``(log a, b, log(min(phi) - phi_0))``, started from the
    two-parameter fit with ``phi_0`` just below the smallest ``phi``. Returns ``phi_0`` and the
    power law in ``phi - phi_0`` (``stderr`` of ``b`` from the Jacobian at the optimum).
    Needs at least 4 points with ``p > 0``.
    """
    from scipy.optimize import least_squares

    x = float_array(phi, "phi", (None,))
    y = float_array(pressure, "pressure", (x.size,))
    keep = y > 0.0
    x, y = x[keep], y[keep]
    if x.size < 4:
        raise InputError(f"fit_jamming_point: need at least 4 points with p > 0, got {x.size}")
    lowest = float(x.min())
    spread = float(x.max()) - lowest
    if spread <= 0.0:
        raise InputError("fit_jamming_point: the packing fractions must not all be equal")
    start_gap = 1e-3 * spread
    first = fit_power_law(x - lowest + start_gap, y)
    ly = np.log(y)

    def residual(q: np.ndarray) -> np.ndarray:
        return np.asarray(q[0] + q[1] * np.log(x - lowest + np.exp(q[2])) - ly)

    q0 = np.array([np.log(first.prefactor), first.exponent, np.log(start_gap)])
    sol = least_squares(residual, q0, method="lm")
    dof = x.size - 3
    variance = float(sol.fun @ sol.fun) / dof if dof > 0 else 0.0
    try:
        cov = variance * np.linalg.inv(sol.jac.T @ sol.jac)
        stderr = float(np.sqrt(max(cov[1, 1], 0.0)))
    except np.linalg.LinAlgError:
        stderr = float("inf")
    phi_0 = lowest - float(np.exp(sol.x[2]))
    law = PowerLaw(
        exponent=float(sol.x[1]),
        stderr=stderr,
        prefactor=float(np.exp(sol.x[0])),
        points=x.size,
        x_min=lowest - phi_0,
        x_max=float(x.max()) - phi_0,
    )
    return phi_0, law


def sample_stats(values: list[float]) -> dict[str, float]:
    """Mean, standard deviation (``sd``, n - 1; 0 for one value), standard error of the mean
    and count ``n`` of ``values`` (NaN mean and error when there are none)."""
    n = len(values)
    mean = statistics.fmean(values) if n else float("nan")
    sd = statistics.stdev(values) if n > 1 else 0.0
    return {"mean": mean, "sd": sd, "stderr": sd / np.sqrt(n) if n else float("nan"), "n": n}
