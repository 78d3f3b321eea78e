"""Weak forces and small gaps at a jamming point, and their critical exponents.

The mean-field theory of jamming predicts power laws for the small contact forces,
``P(f) ~ f^theta``, and for the small gaps between near neighbours, ``g(h) ~ h^-gamma``, with
``theta_e = 0.42311`` and ``gamma = 0.41269`` (Charbonneau, Kurchan, Parisi, Urbani & Zamponi,
Nat. Commun. 5, 3725 (2014)). Charbonneau, Corwin, Parisi & Zamponi (PRL 114, 125504 (2015))
found both in d = 2, 3 and 4 once the forces of localized buckling excitations are set apart:
the contacts of *bucklers*, particles with exactly ``d + 1`` contacts, whose weak forces follow
a smaller exponent ``theta_l``. Here, over the non-rattlers (fewer than ``d + 1`` contacts,
removed iteratively) of a packing at its jamming point:

- forces ``f / <f>``, ``<f>`` the packing's mean contact force, split into the *localized* ones
  (the contact touches a buckler) and the *extended* ones (the others);
- gaps ``h = |x_i - x_j| / (r_i + r_j) - 1 > 0`` between non-rattlers not in contact, within
  :data:`~athermal.certify.GAP_REACH` mean diameters, taken at the packing's jamming point
  ``h_c`` (the packing expanded to it by its linear response,
  :func:`athermal.certify.toward_jamming`), so that they do not depend on how far above it the
  packing was jammed; pairs that touch there (the pressure made their gap) are counted apart;

each computed in double-double from the packing's positions (with their low parts when it is
certified, :mod:`athermal.certify`), so that the smallest values are not round-off. The
exponents come from pooling many packings: the cumulative distributions go as
``f^(1 + theta)`` and ``h^(1 - gamma)``, and each is fitted by maximum likelihood of a power-law
density truncated to a window (:func:`fit_truncated_power_law`); a window below which the
finite pressure of the packings (forces ~ its overlaps) or their count cuts the law,
and above which the law gives way to the bulk of the distribution, is a choice the report
states (:data:`FORCE_WINDOW`, :data:`GAP_WINDOW`).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.optimize
from numpy.typing import NDArray

from ..errors import InputError
from ..model.contact import ContactModel
from ..model.packing import Packing
from . import GAP_REACH, contact_network, toward_jamming
from .extended import NearPairs

THETA_E = 0.42311
"""The mean-field exponent of the extended weak forces (Charbonneau et al. 2014)."""
GAMMA = 0.41269
"""The mean-field exponent of the small gaps (Charbonneau et al. 2014)."""
A_RANGE = (1e-6, 50.0)
"""The cumulative exponents ``a`` a fit looks for (a density ``x^(a - 1)``)."""
FORCE_WINDOW = (1e-3, 1e-1)
"""Default window of ``f / <f>`` for the force exponents."""
GAP_WINDOW = (1e-5, 1e-2)
"""Default window of ``h`` for the gap exponent: far above the gaps' share of the pressure at
epsilon = 1e-6, below the first neighbour shell. Finite size lowers the local exponent where a
packing holds few gaps in a decade (``docs/criticality.md`` measures where, by N and
dimension); :func:`local_exponents` shows it for any packings."""


@dataclass(frozen=True, eq=False)
class WeakForcesAndGaps:
    """One packing's weak-force and gap samples (module docstring).

    Attributes
    ----------
    forces : ``(M,)`` ``f / <f>`` of the contacts between non-rattlers.
    localized : ``(M,)`` True where the contact touches a buckler.
    gaps : ``(G,)`` gaps ``h_c`` at the packing's jamming point (:func:`toward_jamming`)
        between non-rattlers that do not touch there, within reach.
    gap_localized : ``(G,)`` True where a particle of the gap's pair is a buckler.
    n_live : non-rattlers.
    bucklers : non-rattlers with exactly ``d + 1`` contacts.
    touching : pairs of non-rattlers apart in the packing that touch at its jamming point: the
        expansion to it closes more than half of their gap (``h_c < h - h_c``), a gap the
        pressure made, not one of the jammed structure. From a packing far above its jamming
        point this also takes real gaps smaller than that share (``docs/howto/certify.md``).
    jamming_strain : the isotropic expansion ``e_c`` of the cell to the jamming point.
    """

    forces: NDArray[np.float64]
    localized: NDArray[np.bool_]
    gaps: NDArray[np.float64]
    gap_localized: NDArray[np.bool_]
    n_live: int
    bucklers: int
    touching: int
    jamming_strain: float


@dataclass(frozen=True)
class TruncatedPowerLaw:
    """``density ~ x^(a - 1)`` on ``window``, fitted by maximum likelihood: ``a`` with its
    standard error (the inverse Fisher information), from ``points`` values in the window."""

    a: float
    stderr: float
    points: int
    window: tuple[float, float]


@dataclass(frozen=True)
class CriticalExponents:
    """``theta_e``, ``theta_l`` (``a - 1`` of the extended and localized forces) and ``gamma``
    (``1 - a`` of the gaps), each with its fit, over ``packings`` pooled packings."""

    theta_e: float
    theta_e_err: float
    theta_l: float
    theta_l_err: float
    gamma: float
    gamma_err: float
    extended: TruncatedPowerLaw
    localized: TruncatedPowerLaw
    gap: TruncatedPowerLaw
    packings: int
    contacts: int
    localized_contacts: int
    gaps: int


def weak_forces_and_gaps(
    packing: Packing,
    model: ContactModel,
    position_lo: NDArray[np.float64] | None = None,
) -> WeakForcesAndGaps:
    """The forces and gaps of ``packing`` (positions ``packing.positions + position_lo``), in
    double-double (module docstring). Packings between walls are refused
    (:class:`~athermal.errors.InputError`): the double-double sums have no wall terms."""
    if packing.cell.walls:
        raise InputError("criticality: packings between walls are not supported yet")
    pairs = NearPairs(packing, model, GAP_REACH)
    lo = np.zeros_like(packing.positions) if position_lo is None else np.asarray(position_lo)
    sums = pairs.sums(np.array(packing.positions), np.array(lo))
    contacts, rattler = contact_network(pairs, packing.positions, sums)
    if contacts.i.size == 0:
        raise InputError("weak forces: no contacts between non-rattlers (not a jammed packing)")
    i, j = contacts.i, contacts.j
    counts = np.bincount(i, minlength=packing.n) + np.bincount(j, minlength=packing.n)
    buckler = ~rattler & (counts == packing.dim + 1)
    force = contacts.force_magnitude
    overlap = sums.overlap[0] + sums.overlap[1]
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    strain, rate, _ = toward_jamming(pairs, packing.positions, overlap, contacts, rattler, live)
    sigma = packing.radii[pairs.first] + packing.radii[pairs.second]
    gap = live & (overlap <= 0.0)
    h = -overlap[gap] / sigma[gap]
    closing = strain * rate[gap] / sigma[gap]  # h_c - h
    h_c = h + closing
    touching = h_c < -closing
    near = buckler[pairs.first[gap]] | buckler[pairs.second[gap]]
    return WeakForcesAndGaps(
        forces=force / force.mean(),
        localized=buckler[i] | buckler[j],
        gaps=h_c[~touching],
        gap_localized=near[~touching],
        n_live=int((~rattler).sum()),
        bucklers=int(buckler.sum()),
        touching=int(touching.sum()),
        jamming_strain=strain,
    )


def fit_truncated_power_law(
    values: NDArray[np.float64], window: tuple[float, float]
) -> TruncatedPowerLaw:
    """Maximum-likelihood ``a`` of the density ``a x^(a-1) / (u^a - l^a)`` on ``[l, u]`` from
    the ``values`` inside the window. Raises :class:`InputError` with fewer than 10 of them."""
    low, high = (float(w) for w in window)
    if not 0.0 < low < high:
        raise InputError(f"window: need 0 < low < high, got {window}")
    x = np.asarray(values, dtype=np.float64)
    x = x[(x >= low) & (x <= high)]
    if x.size < 10:
        raise InputError(f"window {window}: {x.size} values in it, at least 10 needed")
    n, mean_log = x.size, float(np.log(x).mean())
    lu, ll = np.log(high), np.log(low)

    def score(a: float) -> float:  # d/da of the mean log-likelihood
        ratio = (low / high) ** a
        return 1.0 / a + mean_log - (lu - ratio * ll) / (1.0 - ratio)

    if score(A_RANGE[0]) < 0.0 or score(A_RANGE[1]) > 0.0:
        raise InputError(
            f"window {window}: the values follow no power law with a cumulative exponent in "
            f"{A_RANGE}"
        )
    a = float(scipy.optimize.brentq(score, *A_RANGE, xtol=1e-14))
    ratio = (low / high) ** a
    # Fisher information per value: 1/a^2 - (ln(u/l))^2 r / (1 - r)^2, r = (l/u)^a
    info = 1.0 / a**2 - (lu - ll) ** 2 * ratio / (1.0 - ratio) ** 2
    return TruncatedPowerLaw(a, float(1.0 / np.sqrt(n * info)), n, (low, high))


def critical_exponents(
    samples: Sequence[WeakForcesAndGaps],
    force_window: tuple[float, float] = FORCE_WINDOW,
    gap_window: tuple[float, float] = GAP_WINDOW,
) -> CriticalExponents:
    """``theta_e``, ``theta_l`` and ``gamma`` from the pooled samples of many packings."""
    if not samples:
        raise InputError("critical exponents: no packings")
    forces = np.concatenate([s.forces for s in samples])
    localized = np.concatenate([s.localized for s in samples])
    gaps = np.concatenate([s.gaps for s in samples])
    extended = fit_truncated_power_law(forces[~localized], force_window)
    local = fit_truncated_power_law(forces[localized], force_window)
    gap = fit_truncated_power_law(gaps, gap_window)
    return CriticalExponents(
        theta_e=extended.a - 1.0,
        theta_e_err=extended.stderr,
        theta_l=local.a - 1.0,
        theta_l_err=local.stderr,
        gamma=1.0 - gap.a,
        gamma_err=gap.stderr,
        extended=extended,
        localized=local,
        gap=gap,
        packings=len(samples),
        contacts=int(forces.size),
        localized_contacts=int(localized.sum()),
        gaps=int(gaps.size),
    )


def local_exponents(
    values: NDArray[np.float64], window: tuple[float, float], per_decade: int = 2
) -> list[TruncatedPowerLaw]:
    """Truncated power-law fits (:func:`fit_truncated_power_law`) over consecutive windows of
    ``1 / per_decade`` decade that tile ``window``: the local exponent of the distribution
    along its values, where a single fit over ``window`` would average a drift away. Windows
    holding fewer than 10 values, or following no power law, are left out."""
    low, high = (float(w) for w in window)
    if not 0.0 < low < high or int(per_decade) != per_decade or per_decade < 1:
        raise InputError(
            f"local exponents: need 0 < low < high and an integer per_decade >= 1, got "
            f"{window}, {per_decade!r}"
        )
    count = max(1, round(np.log10(high / low) * per_decade))
    edges = np.geomspace(low, high, count + 1)
    fits = []
    for a, b in itertools.pairwise(edges):
        try:
            fits.append(fit_truncated_power_law(values, (float(a), float(b))))
        except InputError:
            continue
    return fits


def packing_bootstrap(
    samples: Sequence[WeakForcesAndGaps],
    estimate: Callable[[Sequence[WeakForcesAndGaps]], float],
    draws: int = 200,
    seed: int = 0,
) -> float:
    """The standard deviation of ``estimate`` over ``draws`` resamplings of the packings with
    replacement: an error that holds when the values of one packing are correlated (the
    Fisher error of a pooled fit counts them as independent). Resamplings where ``estimate``
    raises :class:`InputError` (too few values in its window) are left out."""
    if len(samples) < 2 or draws < 2:
        raise InputError(
            f"bootstrap: need 2 or more packings and draws, got {len(samples)}, {draws}"
        )
    rng = np.random.default_rng(seed)
    found = []
    for _ in range(draws):
        pick = rng.integers(0, len(samples), size=len(samples))
        try:
            found.append(estimate([samples[k] for k in pick]))
        except InputError:
            continue
    if len(found) < 2:
        raise InputError("bootstrap: the estimate failed on nearly every resampling")
    return float(np.std(found, ddof=1))
