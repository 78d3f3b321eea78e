"""Vibrational modes of a packing at an energy minimum: eigenpairs of its stiffness matrix (the
Hessian, unit masses), the density of states ``D(omega)``, participation ratios and the plateau
frequency ``omega*``.

Rattlers (:func:`~athermal.analysis.observables.rattlers`) and their contacts are removed; the
Hessian of the remaining ``N'`` particles is taken whole, so that its ``t`` translations (``t = d``
in a periodic cell, the periodic axes between walls) are exact zero modes. A stable minimum has
exactly ``t`` eigenvalues within round-off of zero
(:data:`~athermal.analysis.moduli.STABILITY_TOL` x the mean diagonal entry) and none below it; the
remaining ``d N' - t`` are the vibrations, ``omega = sqrt(lambda)`` in units of
``sqrt(k l^(alpha-2) / m)`` (``m = 1``).

Near jamming ``D(omega)`` develops a plateau that extends down to ``omega* ~ Delta z`` (Silbert,
Liu and Nagel, PRL 95, 098301 (2005)); :func:`plateau_edge` locates its lower edge from the
cumulative count of modes, with a bootstrap uncertainty (the choice, and what it gives on
jammed packings: ``docs/modes.md``).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from .._portable import vdot, vnorm
from ..atomic import replacing
from ..errors import InputError
from ..linalg import Factor, arpack_start
from ..model.contact import ContactModel, hessian_floor
from ..model.packing import Packing
from .moduli import (
    lowest_eigenpairs,
    nonrattler_contacts,
    nonrattler_hessian,
    zero_tolerance,
)

DENSE_MODES_DOFS = 12_288
"""Largest stiffness matrix (``N' d`` rows, N = 4096 spheres) whose full spectrum is computed
(dense ``eigh``); above it only the lowest ``k`` modes (shift-invert ``eigsh``)."""
PLATEAU_FRACTION = 0.5
""":func:`plateau_edge` puts ``omega*`` where the mean density of states below it falls to this
fraction of the plateau."""
PLATEAU_WINDOW = (0.1, 0.4)
"""The plateau of ``D(omega)`` is measured between these fractions of the largest frequency:
above the crossover at ``omega*`` and below the rise to the band's peak (``docs/modes.md``)."""
BOOTSTRAP_RESAMPLES = 500
"""Resamples of the modes behind the uncertainty of ``omega*`` (:func:`plateau_edge`)."""


@dataclass(frozen=True)
class Modes:
    """Eigenpairs of a packing's stiffness matrix, rattlers removed.

    Attributes
    ----------
    eigenvalues : ``(M,)`` ascending, energy / length^2 (the lowest ``M`` of ``N' d``, or all).
    vectors : ``(V, N, d)`` unit eigenvectors, zero on rattlers, of the eigenvalues
        ``eigenvalues[vector_index]``.
    vector_index : ``(V,)`` which eigenvalues ``vectors`` belong to (ascending).
    participation : ``(M,)`` ``(sum_i |u_i|^2)^2 / (N' sum_i |u_i|^4)``: 1 for a mode spread
        evenly over the ``N'`` particles, ``1/N'`` for one particle.
    n_rattlers : particles removed.
    dofs : ``N' d``, the size of the matrix.
    tolerance : eigenvalues within ``tolerance`` of zero are zero modes.
    complete : every eigenvalue was computed (dense), not only the lowest.
    """

    eigenvalues: NDArray[np.float64]
    vectors: NDArray[np.float64]
    vector_index: NDArray[np.intp]
    participation: NDArray[np.float64]
    n_rattlers: int
    dofs: int
    tolerance: float
    complete: bool

    @property
    def zero_modes(self) -> int:
        """Eigenvalues within the tolerance of zero (the translations, ``d`` in a periodic cell,
        at a stable minimum)."""
        return int(np.sum(np.abs(self.eigenvalues) <= self.tolerance))

    @property
    def negative_modes(self) -> int:
        """Eigenvalues below minus the tolerance (0 at a minimum)."""
        return int(np.sum(self.eigenvalues < -self.tolerance))

    @property
    def frequencies(self) -> NDArray[np.float64]:
        """``(M',)`` ``omega = sqrt(lambda)`` of the vibrations (the eigenvalues above the
        tolerance)."""
        return np.sqrt(self.eigenvalues[self.eigenvalues > self.tolerance])


def lowest_eigenpair_near(
    h: sp.spmatrix,
    factor: Factor,
    tolerance: float,
    maxiter: int,
    *,
    rows: NDArray[np.intp] | None = None,
    null: NDArray[np.float64] | None = None,
) -> tuple[float, NDArray[np.float64]] | None:
    """The lowest eigenvalue of the symmetric ``h`` and its unit eigenvector ``(M,)`` by LOBPCG
    preconditioned with ``factor`` (the factor of a nearby positive definite matrix on ``h``'s
    ``rows``, all when None, its solves zero on the others: the preconditioned spectrum
    clusters at 1, and a negative eigenvalue stands apart), orthogonal to the columns of
    ``null`` ``(M, k)`` (orthonormal, in ``h``'s null space: a packing's translations), from a
    fixed start vector (:func:`~athermal.linalg.arpack_start`), to a residual ``|h v - lambda
    v|`` of ``tolerance``, which bounds the eigenvalue's error; None when ``maxiter``
    iterations do not reach it."""
    size = h.shape[0]
    rows = np.arange(size) if rows is None else rows

    def solve(v: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.zeros(size)
        out[rows] = factor.solve(v.reshape(-1, 1)[rows])[:, 0]
        return out

    inverse = spla.LinearOperator(h.shape, matvec=solve, dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # not converged: told by the residual
        _, vectors = spla.lobpcg(
            h,
            arpack_start(size)[:, None],
            M=inverse,
            Y=null,
            tol=tolerance,
            maxiter=maxiter,
            largest=False,
        )
    v = vectors[:, 0] / vnorm(vectors[:, 0])
    value = vdot(v, h @ v)
    return (value, v) if vnorm(h @ v - value * v) <= tolerance else None


def vibrational_modes(
    packing: Packing, model: ContactModel, k: int | None = None, *, vectors: int | None = None
) -> Modes:
    """The lowest ``k`` eigenpairs of the stiffness matrix of ``packing``, or all of them
    (``k`` None: dense, up to :data:`DENSE_MODES_DOFS` rows).

    The lowest ``k`` come from ARPACK in shift-invert mode
    (:func:`~athermal.analysis.moduli.lowest_eigenpairs`: about ``-tolerance`` at a minimum,
    below the contacts' floor at a saddle), from a fixed start vector (reproducible).
    ``vectors`` keeps the eigenvectors of that many of the lowest modes that are not zero modes
    (None: of every mode computed); participation ratios are computed for all.
    """
    contacts, rattler = nonrattler_contacts(packing, model)
    h, dofs = nonrattler_hessian(contacts, rattler, packing.dim)
    size = h.shape[0]
    n_live = size // packing.dim
    if n_live < 2:
        raise InputError("modes: fewer than two particles that are not rattlers")
    tolerance = zero_tolerance(h)
    if k is None:
        if size > DENSE_MODES_DOFS:
            raise InputError(
                f"modes: the full spectrum of {size} degrees of freedom is beyond the dense "
                f"limit {DENSE_MODES_DOFS}; ask for the lowest k"
            )
        values, vecs = np.linalg.eigh(h.toarray())
    else:
        if int(k) != k or not 1 <= k < size - 1:
            raise InputError(f"k: need an integer in [1, {size - 2}], got {k!r}")
        values, vecs = lowest_eigenpairs(h, int(k), hessian_floor(contacts, packing.n))
    per_particle = (vecs**2).reshape(n_live, packing.dim, -1).sum(axis=1)  # (N', M)
    participation = per_particle.sum(axis=0) ** 2 / (n_live * (per_particle**2).sum(axis=0))
    if vectors is None:
        index = np.arange(values.size)
    else:
        index = np.flatnonzero(np.abs(values) > tolerance)[:vectors]
    flat = np.zeros((index.size, packing.n * packing.dim))
    flat[:, dofs] = vecs[:, index].T
    return Modes(
        eigenvalues=values,
        vectors=flat.reshape(index.size, packing.n, packing.dim),
        vector_index=index,
        participation=participation,
        n_rattlers=int(rattler.sum()),
        dofs=size,
        tolerance=tolerance,
        complete=k is None,
    )


def density_of_states(
    frequencies: NDArray[np.float64], bins: int = 40
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``D(omega)`` on ``bins`` logarithmically spaced bins spanning ``frequencies`` (> 0):
    edges ``(B+1,)`` and density ``(B,)``, normalised so that ``sum D d_omega = 1``."""
    omega = np.asarray(frequencies, dtype=np.float64)
    if omega.size < 2 or np.any(omega <= 0.0):
        raise InputError("density_of_states: need at least two frequencies, all > 0")
    edges = np.geomspace(omega.min(), omega.max() * (1.0 + 1e-12), bins + 1)
    counts, _ = np.histogram(omega, bins=edges)
    return edges, counts / (omega.size * np.diff(edges))


def cumulative_count(
    frequencies: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The cumulative count of modes, no binning: the ``(M,)`` frequencies in ascending order
    and the fraction of the ``M`` modes at or below each, ``(k - 1/2) / M`` for the ``k``-th
    (the midpoint of the count's step there)."""
    omega = np.sort(np.asarray(frequencies, dtype=np.float64))
    if omega.size < 2 or omega[0] <= 0.0:
        raise InputError("cumulative_count: need at least two frequencies, all > 0")
    return omega, (np.arange(omega.size) + 0.5) / omega.size


@dataclass(frozen=True)
class PlateauEdge:
    """``omega*`` of a spectrum, its uncertainty and what decided it (:func:`plateau_edge`).

    Frequencies in ``sqrt(k l^(alpha-2) / m)``; densities normalised as
    :func:`density_of_states` (``sum D d_omega = 1`` over the ``M`` modes).

    Attributes
    ----------
    omega_star : where the count of modes below ``omega``, ``N(omega) / M``, crosses
        ``PLATEAU_FRACTION x plateau x omega`` coming down from the plateau.
    error : half the 16-84 % range of ``omega_star`` over bootstrap resamples of the modes
        (one standard deviation for a normal spread).
    plateau : the plateau level of ``D(omega)``: the fraction of the modes in ``window`` over
        its width.
    window : ``(omega_lo, omega_hi)``, :data:`PLATEAU_WINDOW` x the largest frequency.
    modes_below : modes below ``omega_star`` (how many decided it).
    modes : ``M``, the frequencies given.
    resamples, seed : the bootstrap's resamples and the seed of its generator.
    """

    omega_star: float
    error: float
    plateau: float
    window: tuple[float, float]
    modes_below: int
    modes: int
    resamples: int
    seed: int


def _edge(omega: NDArray[np.float64], fraction: NDArray[np.float64]) -> tuple[float, float]:
    """``(omega*, plateau)`` of ascending frequencies and their cumulative fractions."""
    lo, hi = PLATEAU_WINDOW[0] * omega[-1], PLATEAU_WINDOW[1] * omega[-1]
    inside = np.searchsorted(omega, hi, side="right") - np.searchsorted(omega, lo)
    plateau = float(inside / (omega.size * (hi - lo)))
    gap = fraction - PLATEAU_FRACTION * plateau * omega  # < 0: the count under the line
    rise = np.flatnonzero((gap[:-1] <= 0.0) & (gap[1:] > 0.0) & (omega[:-1] < hi))
    if rise.size == 0:
        return float(omega[0]), plateau
    k = rise[-1]
    t = gap[k] / (gap[k] - gap[k + 1])
    return float(omega[k] + t * (omega[k + 1] - omega[k])), plateau


def plateau_edge(
    frequencies: NDArray[np.float64], *, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = 0
) -> PlateauEdge:
    """``omega*``, the lower edge of the plateau of ``D(omega)``, with a bootstrap uncertainty.

    No histogram: the plateau level ``D_p`` is the fraction of the ``M`` modes between
    :data:`PLATEAU_WINDOW` x the largest frequency, over that window's width; ``omega*`` is the
    highest frequency below the window's top where the cumulative count ``N(omega) / M``
    (:func:`cumulative_count`) rises through ``PLATEAU_FRACTION x D_p x omega``, i.e. where the
    mean density of states below ``omega`` is half the plateau (interpolated linearly between
    modes). For ``D`` rising as ``omega`` below a sharp edge (Debye in 2D) that is the edge;
    for an empty gap below it, twice the edge. With no mode under the line, the lowest
    frequency (``omega*`` is not resolved).

    ``error`` is half the 16-84 % range of ``omega*`` over ``resamples`` resamples of the modes
    with replacement, drawn by ``numpy.random.default_rng(seed)``: the same frequencies and
    seed give the same numbers. It treats the modes as independent draws from ``D(omega)``;
    the modes of one packing are more regular than that, and on jammed packings the error
    came out larger than the spread of ``omega*`` over packings (``docs/modes.md``).

    Parameters
    ----------
    frequencies : ``(M,)`` vibrational frequencies ``> 0`` (:attr:`Modes.frequencies` of a
        full spectrum).
    resamples : bootstrap resamples, at least 2.
    seed : seed of the bootstrap's generator.

    Examples
    --------
    >>> u = (np.arange(2000) + 0.5) / 2000  # D ~ omega up to 0.1, then flat up to 2
    >>> omega = np.where(u < 0.05 / 1.95, np.sqrt(0.39 * u), 1.95 * u + 0.05)
    >>> edge = plateau_edge(omega)
    >>> round(edge.omega_star, 3), edge.modes_below
    (0.1, 51)
    """
    omega, fraction = cumulative_count(frequencies)
    if int(resamples) != resamples or resamples < 2:
        raise InputError(f"resamples: need an integer >= 2, got {resamples!r}")
    star, plateau = _edge(omega, fraction)
    rng = np.random.default_rng(seed)
    draws = np.empty(int(resamples))
    for i in range(draws.size):
        draws[i] = _edge(omega[np.sort(rng.integers(0, omega.size, omega.size))], fraction)[0]
    low, high = np.percentile(draws, [16.0, 84.0])
    return PlateauEdge(
        omega_star=star,
        error=float(high - low) / 2.0,
        plateau=plateau,
        window=(PLATEAU_WINDOW[0] * float(omega[-1]), PLATEAU_WINDOW[1] * float(omega[-1])),
        modes_below=int(np.searchsorted(omega, star)),
        modes=int(omega.size),
        resamples=int(resamples),
        seed=int(seed),
    )


def plateau_frequency(frequencies: NDArray[np.float64]) -> float:
    """``omega*`` alone, as :func:`plateau_edge` finds it, without the bootstrap."""
    return _edge(*cumulative_count(frequencies))[0]


def save_modes(
    path: str | os.PathLike[str], modes: Modes, bins: int = 40, *, seed: int = 0
) -> Path:
    """Write ``modes`` to the NPZ file ``path`` atomically: ``eigenvalues``, ``participation``,
    ``vectors`` and ``vector_index``, ``frequencies``, ``zero_modes``, ``negative_modes``,
    ``n_rattlers``, ``tolerance`` and, for a full spectrum, ``dos_edges``, ``dos`` (``bins``
    logarithmic bins) and :func:`plateau_edge`'s ``omega_star``, ``omega_star_err``,
    ``omega_star_modes`` (modes below it), ``plateau_density``, ``plateau_window`` and
    ``bootstrap_seed`` (``seed``, its bootstrap's)."""
    data: dict[str, Any] = {
        "eigenvalues": modes.eigenvalues,
        "participation": modes.participation,
        "vectors": modes.vectors,
        "vector_index": modes.vector_index,
        "frequencies": modes.frequencies,
        "zero_modes": modes.zero_modes,
        "negative_modes": modes.negative_modes,
        "n_rattlers": modes.n_rattlers,
        "tolerance": modes.tolerance,
    }
    if modes.complete:
        edges, dos = density_of_states(modes.frequencies, bins)
        edge = plateau_edge(modes.frequencies, seed=seed)
        data.update(
            dos_edges=edges,
            dos=dos,
            omega_star=edge.omega_star,
            omega_star_err=edge.error,
            omega_star_modes=edge.modes_below,
            plateau_density=edge.plateau,
            plateau_window=np.array(edge.window),
            bootstrap_seed=edge.seed,
        )
    with replacing(path) as temporary, open(temporary, "wb") as handle:
        np.savez(handle, **data)
    return Path(path)
