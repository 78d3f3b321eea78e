"""Line search for the strong Wolfe conditions that keeps working below energy round-off.

Nocedal & Wright's bracketing and zoom (Algorithms 3.5 and 3.6, cubic interpolation) on
``phi(a) = E(x + a p)``. Near a minimum, energy differences ``E(x + a p) - E(x)`` fall below the
round-off of ``E`` long before the gradient reaches ``1e-9`` of the contact forces, and an
energy-based search stalls (as scipy's L-BFGS-B and ASE's PreconLBFGS do). So when
``|phi(a) - phi(0)|`` is below the round-off (``eps |phi(0)|``, or an absolute ``noise`` given by
the caller) energy comparisons are not trusted: sufficient decrease is
judged by Hager & Zhang's approximate Wolfe condition ``phi'(a) <= (1 - 2 c1) |phi'(0)|``
(exact for a quadratic) and interpolation falls back to the secant of ``phi'``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Phi = Callable[[float], tuple[float, float]]


@dataclass(frozen=True)
class LineSearchResult:
    """Accepted step ``a`` with ``phi(a)``, ``phi'(a)``; ``ok`` False when none was found."""

    step: float
    value: float
    slope: float
    evaluations: int
    ok: bool


@dataclass
class _Search:
    phi: Phi
    f0: float
    g0: float
    c1: float
    c2: float
    eps: float
    noise: float
    evaluations: int = 0

    def __call__(self, a: float) -> tuple[float, float]:
        self.evaluations += 1
        return self.phi(a)

    def resolved(self, f: float, f_ref: float) -> bool:
        """True when ``f`` and ``f_ref`` differ by more than the energy round-off."""
        return abs(f - f_ref) > max(self.eps * abs(self.f0), self.noise)

    def decrease(self, a: float, f: float, df: float) -> bool:
        if self.resolved(f, self.f0):
            return f <= self.f0 + self.c1 * a * self.g0
        return df <= (1.0 - 2.0 * self.c1) * abs(self.g0)

    def curvature(self, df: float) -> bool:
        return abs(df) <= self.c2 * abs(self.g0)

    def result(self, a: float, f: float, df: float, ok: bool) -> LineSearchResult:
        return LineSearchResult(a, f, df, self.evaluations, ok)


def strong_wolfe(
    phi: Phi,
    f0: float,
    g0: float,
    step: float,
    *,
    c1: float = 1e-4,
    c2: float = 0.9,
    step_max: float = np.inf,
    eps: float = 1e-12,
    noise: float = 0.0,
    max_evaluations: int = 40,
) -> LineSearchResult:
    """Find ``a > 0`` with sufficient decrease and ``|phi'(a)| <= c2 |phi'(0)|``.

    Parameters
    ----------
    phi : ``a -> (phi(a), phi'(a))``.
    f0, g0 : ``phi(0)`` and ``phi'(0) < 0``.
    step : first trial step (clipped to ``step_max``).
    c1, c2 : Wolfe constants, ``0 < c1 < c2 < 1``.
    eps, noise : relative and absolute energy round-off; energy differences below the larger
        of ``eps |phi(0)|`` and ``noise`` are not trusted.
    max_evaluations : budget of ``phi`` calls.

    A zero energy at the trial point (an unjammed packing) is accepted at once: it cannot be
    improved. When ``step_max`` stops the search while ``phi`` still decreases, the capped step
    is returned as accepted (sufficient decrease holds, the curvature condition may not).
    """
    if not g0 < 0.0:
        raise ValueError(f"phi'(0) = {g0} is not a descent direction")
    s = _Search(phi, f0, g0, c1, c2, eps, noise)
    a_prev, f_prev, df_prev = 0.0, f0, g0
    a = min(step, step_max)
    while s.evaluations < max_evaluations:
        f, df = s(a)
        if f == 0.0 and df == 0.0:
            return s.result(a, f, df, True)
        if not s.decrease(a, f, df) or (s.resolved(f, f_prev) and f >= f_prev and a_prev > 0):
            return _zoom(s, a_prev, f_prev, df_prev, a, f, df, max_evaluations)
        if s.curvature(df):
            return s.result(a, f, df, True)
        if df >= 0.0:
            return _zoom(s, a, f, df, a_prev, f_prev, df_prev, max_evaluations)
        if a >= step_max:  # capped with sufficient decrease, still descending: take it
            return s.result(a, f, df, True)
        a_prev, f_prev, df_prev = a, f, df
        a = min(4.0 * a, step_max)
    return s.result(a_prev, f_prev, df_prev, False)


def _zoom(
    s: _Search,
    lo: float,
    f_lo: float,
    df_lo: float,
    hi: float,
    f_hi: float,
    df_hi: float,
    max_evaluations: int,
) -> LineSearchResult:
    """Shrink ``[lo, hi]`` (``lo`` has sufficient decrease, the minimum lies between them)."""
    while s.evaluations < max_evaluations:
        a = _interpolate(s, lo, f_lo, df_lo, hi, f_hi, df_hi)
        f, df = s(a)
        if f == 0.0 and df == 0.0:
            return s.result(a, f, df, True)
        if not s.decrease(a, f, df) or (s.resolved(f, f_lo) and f >= f_lo):
            hi, f_hi, df_hi = a, f, df
            continue
        if s.curvature(df):
            return s.result(a, f, df, True)
        if df * (hi - lo) >= 0.0:
            hi, f_hi, df_hi = lo, f_lo, df_lo
        lo, f_lo, df_lo = a, f, df
    return s.result(lo, f_lo, df_lo, False)


def _interpolate(
    s: _Search, lo: float, f_lo: float, df_lo: float, hi: float, f_hi: float, df_hi: float
) -> float:
    """Cubic minimizer of the two end points (secant of ``phi'`` below round-off), kept inside
    the middle 80 % of the interval."""
    width = hi - lo
    trial = np.nan
    if s.resolved(f_hi, f_lo):
        d1 = df_lo + df_hi - 3.0 * (f_lo - f_hi) / (lo - hi)
        disc = d1 * d1 - df_lo * df_hi
        if disc >= 0.0:
            d2 = np.sign(hi - lo) * np.sqrt(disc)
            denom = df_hi - df_lo + 2.0 * d2
            if denom != 0.0:
                trial = hi - width * (df_hi + d2 - d1) / denom
    if not np.isfinite(trial) and df_hi != df_lo:
        trial = lo - df_lo * width / (df_hi - df_lo)
    low, high = sorted((lo + 0.1 * width, hi - 0.1 * width))
    if not np.isfinite(trial):
        return lo + 0.5 * width
    return float(min(max(trial, low), high))
