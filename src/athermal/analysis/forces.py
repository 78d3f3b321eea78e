"""Statistics of the contact-force network: the distribution ``P(f / <f>)``, its exponential
tail and the anisotropy of contact normals and forces.

Only contacts between non-rattlers count (:func:`~athermal.analysis.observables.rattlers`): a
rattler's contacts carry forces at round-off that say nothing about the load-bearing network.

Anisotropy. For unit normals ``n_c`` and weights ``w_c`` let ``chi = sum w_c n_c (x) n_c /
sum w_c``; the anisotropy is ``d (lambda_max - lambda_min) / trace(chi)`` and its axis the
eigenvector of ``lambda_max``. With ``w = 1`` it is the contact-normal anisotropy ``a_c`` (in 2D,
``P(theta) = (1 + a_c cos 2(theta - theta_c)) / (2 pi)``, Radjai et al., PRL 80, 61 (1998)); with
``w = f`` the force-weighted one, ``a_c + a_f`` to first order in 2D. Both are 0 for an isotropic
network.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.contact import ContactModel
from ..model.packing import Packing
from .moduli import nonrattler_contacts

FORCE_BIN = 0.1
"""Width of the histogram bins of ``f / <f>``."""
FORCE_RANGE = 10.0
"""The histogram covers ``0 <= f / <f> < FORCE_RANGE``; larger forces are counted as overflow."""
TAIL_FROM = 1.0
"""The exponential tail is fitted over bins whose centre is at least this ``f / <f>``."""
TAIL_MIN_COUNT = 5
"""Bins with fewer forces are left out of the tail fit (their log density is too noisy)."""
EDGES = np.linspace(0.0, FORCE_RANGE, round(FORCE_RANGE / FORCE_BIN) + 1)
"""The bin edges of every force histogram, so that histograms of many packings add up."""


@dataclass(frozen=True)
class ExponentialTail:
    """``P(x) = exp(log_prefactor - decay x)`` fitted to the histogram bins
    ``x_min <= x <= x_max`` (bin centres, ``x = f / <f>``, ``points`` bins) by weighted least
    squares on ``ln P`` (weights: the counts, as ``var ln P ~ 1 / count``); ``stderr`` from those
    weights, scaled by the reduced chi-square where it exceeds 1."""

    decay: float
    stderr: float
    log_prefactor: float
    points: int
    x_min: float
    x_max: float


@dataclass(frozen=True)
class ForceStatistics:
    """The force network of a packing.

    Attributes
    ----------
    contacts : contacts between non-rattlers.
    mean_force : ``<f>`` over them (``k`` x length^(alpha-1)).
    counts : ``(B,)`` forces per bin of ``f / <f>`` on :data:`EDGES`.
    overflow : forces with ``f / <f> >= FORCE_RANGE``.
    tail : the exponential tail (None: fewer than 3 bins qualify).
    contact_anisotropy, force_anisotropy : of the normals, unweighted and force-weighted.
    contact_axis, force_axis : ``(d,)`` unit major axes of those fabrics.
    """

    contacts: int
    mean_force: float
    counts: NDArray[np.int64]
    overflow: int
    tail: ExponentialTail | None
    contact_anisotropy: float
    force_anisotropy: float
    contact_axis: NDArray[np.float64]
    force_axis: NDArray[np.float64]

    @property
    def density(self) -> NDArray[np.float64]:
        """``P(f / <f>)`` ``(B,)`` on :data:`EDGES`: ``sum(density) x FORCE_BIN`` is the
        fraction of forces below ``FORCE_RANGE`` (1 without overflow)."""
        return histogram_density(self.counts, self.overflow)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (the histogram as bin edges and density)."""
        return {
            "contacts": self.contacts,
            "mean_force": self.mean_force,
            "tail_decay": None if self.tail is None else self.tail.decay,
            "tail": None if self.tail is None else self.tail.__dict__,
            "contact_anisotropy": self.contact_anisotropy,
            "force_anisotropy": self.force_anisotropy,
            "contact_axis": self.contact_axis.tolist(),
            "force_axis": self.force_axis.tolist(),
            "overflow": self.overflow,
            "edges": EDGES.tolist(),
            "density": self.density.tolist(),
        }


def force_statistics(packing: Packing, model: ContactModel) -> ForceStatistics:
    """The contact-force statistics of ``packing`` (best at a force-balanced minimum)."""
    contacts, _ = nonrattler_contacts(packing, model)
    live = contacts.subset(contacts.i != contacts.j)  # not a particle with its own image
    forces = live.force_magnitude
    dim = packing.dim
    if forces.size == 0:
        zero = np.zeros(dim)
        return ForceStatistics(
            0, 0.0, np.zeros(EDGES.size - 1, np.int64), 0, None, 0.0, 0.0, zero, zero
        )
    mean = float(forces.mean())
    counts, overflow = force_histogram(forces / mean)
    a_c, axis_c = anisotropy(live.normal, np.ones_like(forces))
    a_f, axis_f = anisotropy(live.normal, forces)
    return ForceStatistics(
        contacts=int(forces.size),
        mean_force=mean,
        counts=counts,
        overflow=overflow,
        tail=exponential_tail(counts, overflow),
        contact_anisotropy=a_c,
        force_anisotropy=a_f,
        contact_axis=axis_c,
        force_axis=axis_f,
    )


def force_histogram(x: NDArray[np.float64]) -> tuple[NDArray[np.int64], int]:
    """Counts ``(B,)`` of the normalized forces ``x`` on :data:`EDGES` and the overflow."""
    counts, _ = np.histogram(x, bins=EDGES)
    return counts.astype(np.int64), int(np.sum(x >= FORCE_RANGE))


def histogram_density(counts: NDArray[np.int64], overflow: int) -> NDArray[np.float64]:
    """Probability density ``(B,)`` of histogram ``counts`` on :data:`EDGES` (with ``overflow``
    forces beyond them in the total)."""
    total = int(counts.sum()) + overflow
    return counts / (total * FORCE_BIN) if total else np.zeros(counts.size)


def exponential_tail(counts: NDArray[np.int64], overflow: int) -> ExponentialTail | None:
    """The exponential tail of a histogram on :data:`EDGES` (bins from :data:`TAIL_FROM` with at
    least :data:`TAIL_MIN_COUNT` forces); None when fewer than 3 bins qualify."""
    centres = (EDGES[:-1] + EDGES[1:]) / 2.0
    use = (centres >= TAIL_FROM) & (counts >= TAIL_MIN_COUNT)
    if use.sum() < 3:
        return None
    x = centres[use]
    y = np.log(histogram_density(counts, overflow)[use])
    w = counts[use].astype(np.float64)  # var(ln count) ~ 1 / count
    xm = np.sum(w * x) / w.sum()
    sxx = np.sum(w * (x - xm) ** 2)
    slope = np.sum(w * (x - xm) * (y - np.sum(w * y) / w.sum())) / sxx
    intercept = np.sum(w * y) / w.sum() - slope * xm
    chi2 = float(np.sum(w * (y - intercept - slope * x) ** 2))
    dof = max(int(use.sum()) - 2, 1)
    stderr = float(np.sqrt(max(chi2 / dof, 1.0) / sxx))
    return ExponentialTail(
        float(-slope), stderr, float(intercept), int(use.sum()), float(x[0]), float(x[-1])
    )


def anisotropy(
    normals: NDArray[np.float64], weights: NDArray[np.float64]
) -> tuple[float, NDArray[np.float64]]:
    """``d (lambda_max - lambda_min) / trace(chi)`` of ``chi = sum w n (x) n / sum w`` for unit
    ``normals`` ``(M, d)`` and ``weights`` ``(M,)``, and the unit major axis ``(d,)``."""
    chi = np.einsum("c,ca,cb->ab", weights, normals, normals) / weights.sum()
    values, vectors = np.linalg.eigh(chi)
    axis = vectors[:, -1] * (1.0 if vectors[0, -1] >= 0 else -1.0)
    return float(normals.shape[1] * (values[-1] - values[0]) / values.sum()), axis
