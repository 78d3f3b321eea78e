"""Vibrational modes of a packing at an energy minimum: eigenpairs of its stiffness matrix (the
Hessian, unit masses), the density of states ``D(omega)``, participation ratios and the plateau
frequency ``omega*``.

Rattlers (:func:`~athermal.observables.rattlers`) and their contacts are removed; the Hessian
of the remaining ``N'`` particles is taken whole, so that its ``d`` translations are exact zero
modes. A stable minimum has exactly ``d`` eigenvalues within round-off of zero
(:data:`~athermal.moduli.STABILITY_TOL` x the mean diagonal entry) and none below it; the
remaining ``d (N' - 1)`` are the vibrations, ``omega = sqrt(lambda)`` in units of
``sqrt(k l^(alpha-2) / m)`` (``m = 1``).

Near jamming ``D(omega)`` develops a plateau that extends down to ``omega* ~ Delta z`` (Silbert,
Liu and Nagel, PRL 95, 098301 (2005)); :func:`plateau_frequency` locates its lower edge.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from .atomic import replacing
from .contact import ContactModel
from .errors import InputError
from .moduli import STABILITY_TOL, stiffness_matrix
from .packing import Packing

DENSE_MODES_DOFS = 12_288
"""Largest stiffness matrix (``N' d`` rows, N = 4096 spheres) whose full spectrum is computed
(dense ``eigh``); above it only the lowest ``k`` modes (shift-invert ``eigsh``)."""
PLATEAU_FRACTION = 0.5
""":func:`plateau_frequency` puts ``omega*`` where ``D(omega)`` falls below this fraction of its
plateau."""


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
        """Eigenvalues within the tolerance of zero (``d`` at a stable minimum)."""
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


def vibrational_modes(
    packing: Packing, model: ContactModel, k: int | None = None, *, vectors: int | None = None
) -> Modes:
    """The lowest ``k`` eigenpairs of the stiffness matrix of ``packing``, or all of them
    (``k`` None: dense, up to :data:`DENSE_MODES_DOFS` rows).

    The lowest ``k`` come from ARPACK in shift-invert mode about ``-tolerance`` (so the matrix
    it factors is positive definite at a minimum), from a fixed start vector (reproducible).
    ``vectors`` keeps the eigenvectors of that many of the lowest modes that are not zero modes
    (None: of every mode computed); participation ratios are computed for all.
    """
    h, dofs, rattler = stiffness_matrix(packing, model)
    size = h.shape[0]
    n_live = size // packing.dim
    if n_live < 2:
        raise InputError("modes: fewer than two particles that are not rattlers")
    tolerance = STABILITY_TOL * float(np.mean(np.abs(h.diagonal())))
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
        start = np.full(size, 1.0 / np.sqrt(size))  # ARPACK's own start is random
        values, vecs = spla.eigsh(
            h.tocsc(), k=int(k), sigma=-tolerance, which="LM", tol=1e-12, v0=start
        )
        order = np.argsort(values)
        values, vecs = values[order], vecs[:, order]
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


def plateau_frequency(frequencies: NDArray[np.float64], bins: int = 40) -> float:
    """``omega*``, the lower edge of the plateau of ``D(omega)``.

    The plateau level is the median of ``D`` over the bins between the frequency of its
    maximum and a decade below it; coming down from the maximum, ``omega*`` is where ``D``
    first falls below :data:`PLATEAU_FRACTION` of that level (interpolated in log-log between
    the bin centres). Returns the lowest frequency when ``D`` never falls that low.
    """
    edges, density = density_of_states(frequencies, bins)
    centres = np.sqrt(edges[:-1] * edges[1:])
    top = int(np.argmax(density))
    window = (centres <= centres[top]) & (centres >= centres[top] / 10.0)
    level = float(np.median(density[window]))
    threshold = PLATEAU_FRACTION * level
    for b in range(top, 0, -1):
        if density[b - 1] < threshold:
            lo, hi = density[b - 1], density[b]
            if lo <= 0.0:
                return float(centres[b])
            t = (np.log(threshold) - np.log(lo)) / (np.log(hi) - np.log(lo))
            return float(np.exp(np.log(centres[b - 1]) + t * np.log(centres[b] / centres[b - 1])))
    return float(np.min(frequencies))


def save_modes(path: str | os.PathLike[str], modes: Modes, bins: int = 40) -> Path:
    """Write ``modes`` to the NPZ file ``path`` atomically: ``eigenvalues``, ``participation``,
    ``vectors`` and ``vector_index``, ``frequencies``, ``zero_modes``, ``negative_modes``,
    ``n_rattlers``, ``tolerance`` and, for a full spectrum, ``dos_edges``, ``dos`` and
    ``omega_star``."""
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
        data.update(dos_edges=edges, dos=dos, omega_star=plateau_frequency(modes.frequencies, bins))
    with replacing(path) as temporary, open(temporary, "wb") as handle:
        np.savez(handle, **data)
    return Path(path)
