"""Statistics of avalanche sizes (the stress and energy drops of plastic events): log-binned
densities and the exponent of ``P(S) ~ S^-tau exp(-S / S_c)``, a power law with the cutoff a
finite system puts on its largest avalanches.

:func:`power_law_tail` fits ``tau`` and ``S_c`` by maximum likelihood to the sizes above
``S_min``; its standard errors come from the curvature of the log-likelihood (the observed
information). ``S_min`` is the one of the candidate starts (quantiles :data:`STARTS` of the
sizes) whose fit is closest to the sizes above it in the Kolmogorov-Smirnov distance (the
criterion of Clauset, Shalizi & Newman, SIAM Review 51, 661, 2009), so no range is chosen by
hand; the fits from every start are reported too, to show how far the estimate depends on it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import integrate, optimize

from .._validate import float_array

MIN_TAIL = 20
"""Fewest sizes above ``S_min`` that a fit uses."""
STARTS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
"""The candidate starts ``S_min`` of a fit, as quantiles of the sizes."""
SIGNS = ((1, 1), (1, -1), (-1, 1), (-1, -1))


@dataclass(frozen=True)
class PowerTail:
    """``P(S) ~ S^-exponent exp(-S / cutoff)`` above ``s_min``: the estimates and their standard
    errors, the sizes fitted (``tail`` of ``count``), the Kolmogorov-Smirnov distance of the
    fit, and the exponent from each start (:data:`STARTS`, by quantile; NaN where fewer than
    :data:`MIN_TAIL` sizes lie above it)."""

    exponent: float
    stderr: float
    cutoff: float
    cutoff_stderr: float
    s_min: float
    tail: int
    count: int
    ks: float
    by_start: dict[str, float]

    def density(self, sizes: ArrayLike) -> NDArray[np.float64]:
        """The fitted probability density at ``sizes`` (>= ``s_min``), normalized over all
        ``count`` sizes (the fitted ``tail`` carry their fraction of it)."""
        s = np.asarray(sizes, dtype=np.float64)
        ratio = self.s_min / self.cutoff
        mass = _integral(self.exponent, ratio, 0.0, np.inf) * self.s_min ** (1.0 - self.exponent)
        shape = s ** (-self.exponent) * np.exp(-(s - self.s_min) / self.cutoff)
        return self.tail / self.count * shape / mass


def _integral(tau: float, ratio: float, a: float, b: float) -> float:
    """``int_a^b exp((1 - tau) u - ratio (e^u - 1)) du``: the law's mass between ``S = s_min
    e^a`` and ``s_min e^b`` in ``u = ln(S / s_min)``, scaled by ``s_min^(tau - 1) e^-ratio``
    (``ratio = s_min / cutoff``)."""
    with np.errstate(over="ignore"):  # far beyond the cutoff the integrand is 0
        value, _ = integrate.quad(
            lambda u: np.exp((1.0 - tau) * u - ratio * (np.exp(u) - 1.0)), a, b, limit=200
        )
    return float(value)


def _cost(p: NDArray[np.float64], tail: NDArray[np.float64], s_min: float) -> float:
    """Mean negative log-likelihood of ``p = (tau, ln cutoff)`` for ``tail`` (sizes >=
    ``s_min``)."""
    tau, cutoff = float(p[0]), float(np.exp(p[1]))
    ratio = s_min / cutoff
    norm = np.log(_integral(tau, ratio, 0.0, np.inf)) + (1.0 - tau) * np.log(s_min) - ratio
    return tau * float(np.mean(np.log(tail))) + float(np.mean(tail)) / cutoff + norm


def _fit(tail: NDArray[np.float64], s_min: float) -> NDArray[np.float64]:
    """The maximum-likelihood ``(tau, ln cutoff)`` of ``tail`` (sizes >= ``s_min``), from the
    pure power law's estimate and a cutoff beyond the largest size."""
    pure = 1.0 + 1.0 / max(float(np.mean(np.log(tail / s_min))), 1e-12)
    best = optimize.minimize(
        _cost,
        np.array([pure, np.log(10.0 * tail.max())]),
        args=(tail, s_min),
        method="Nelder-Mead",
        options={"xatol": 1e-6, "fatol": 1e-12, "maxiter": 2000},
    )
    return np.asarray(best.x, dtype=np.float64)


def _errors(tail: NDArray[np.float64], s_min: float, p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Standard errors of ``(tau, ln cutoff)``: the inverse of the log-likelihood's curvature
    (central differences) over the ``tail.size`` sizes; NaN where it is not positive."""
    h = 1e-3 * np.maximum(np.abs(p), 1.0)
    hess = np.zeros((2, 2))
    for i in range(2):
        for j in range(2):
            ei, ej = np.eye(2)[i] * h[i], np.eye(2)[j] * h[j]
            corners = [_cost(p + a * ei + b * ej, tail, s_min) for a, b in SIGNS]
            hess[i, j] = (corners[0] - corners[1] - corners[2] + corners[3]) / (4.0 * h[i] * h[j])
    variance = np.diag(np.linalg.pinv(hess * tail.size))
    return np.where(variance > 0.0, np.sqrt(np.abs(variance)), np.nan)


def _ks(tail: NDArray[np.float64], s_min: float, p: NDArray[np.float64]) -> float:
    """Kolmogorov-Smirnov distance between the sorted ``tail`` and the fitted law."""
    tau, ratio = float(p[0]), s_min / float(np.exp(p[1]))
    logs = np.log(tail / s_min)
    pieces = [
        _integral(tau, ratio, a, b)
        for a, b in zip(np.concatenate([[0.0], logs[:-1]]), logs, strict=True)
    ]
    model = np.cumsum(pieces) / _integral(tau, ratio, 0.0, np.inf)
    empirical = np.arange(1, tail.size + 1) / tail.size
    return float(
        max(np.max(np.abs(model - empirical)), np.max(np.abs(model - empirical + 1.0 / tail.size)))
    )


def power_law_tail(sizes: ArrayLike) -> PowerTail | None:
    """The power law with cutoff fitted to the positive ``sizes`` (module docstring); None with
    fewer than :data:`MIN_TAIL` of them.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> s = (1.0 - rng.random(5000)) ** (-1.0 / 0.5)  # P(S) ~ S^-1.5 above 1, no cutoff
    >>> fit = power_law_tail(s)
    >>> abs(fit.exponent - 1.5) < 3 * fit.stderr
    True
    """
    values = float_array(sizes, "sizes", (None,))
    x = np.sort(values[np.isfinite(values) & (values > 0.0)])
    if x.size < MIN_TAIL:
        return None
    fits = {}
    for q in STARTS:
        s_min = float(np.quantile(x, q))
        tail = x[x >= s_min]
        if tail.size >= MIN_TAIL:
            p = _fit(tail, s_min)
            fits[q] = (s_min, tail, p, _ks(tail, s_min, p))
    s_min, tail, p, ks = min(fits.values(), key=lambda fit: fit[3])
    errors = _errors(tail, s_min, p)
    return PowerTail(
        exponent=float(p[0]),
        stderr=float(errors[0]),
        cutoff=float(np.exp(p[1])),
        cutoff_stderr=float(np.exp(p[1]) * errors[1]),
        s_min=s_min,
        tail=int(tail.size),
        count=int(x.size),
        ks=ks,
        by_start={f"{q:g}": float(fits[q][2][0]) if q in fits else float("nan") for q in STARTS},
    )


def log_binned(
    sizes: ArrayLike, per_decade: int = 4
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """The probability density of the positive ``sizes`` in logarithmic bins
    (``per_decade`` a decade, spanning them): the bins' geometric centres, the densities
    (normalized over all positive sizes) and the counts; empty bins included (density 0)."""
    values = float_array(sizes, "sizes", (None,))
    x = values[np.isfinite(values) & (values > 0.0)]
    if x.size == 0:
        empty = np.zeros(0)
        return empty, empty, np.zeros(0, dtype=np.int64)
    lo, hi = np.log10(x.min()), np.log10(x.max())
    bins = max(1, int(np.ceil((hi - lo) * per_decade)))
    pad = 0.5 / per_decade if bins == 1 else 1e-9 * (hi - lo)  # the largest size inside
    edges = np.logspace(lo - (pad if bins == 1 else 0.0), hi + pad, bins + 1)
    counts, _ = np.histogram(x, edges)
    density = counts / np.diff(edges) / x.size
    return np.sqrt(edges[1:] * edges[:-1]), density, counts.astype(np.int64)
