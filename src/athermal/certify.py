"""Certified jamming points: force balance beyond float64, by Newton refinement in double-double.

At a jamming point float64 runs out: positions of order one carry absolute errors of ~1e-16, so
overlaps, and with them the contact forces (mean ~1e-8 at epsilon = 1e-6), cannot balance better
than ~1e-7 of the mean force. :func:`certify` holds the positions as ``hi + lo``
(:mod:`athermal.extended`), computes the residual forces in double-double and corrects the
positions by Newton's method on the non-rattlers: each correction ``dx = -H^+ g`` is solved in
float64 (the sparse Hessian at ``hi``, its first non-rattler pinned against the translations,
CHOLMOD: :func:`athermal.moduli.pinned_solve`) and added in double-double. This is iterative
refinement (Wilkinson; Higham, *Accuracy and Stability of Numerical Algorithms*, ch. 12): the
residual falls by about ``cond(H) x 1e-16`` per step until it reaches the double-double floor,
``~1e-32`` of the positions.

The contacts are those of the float64 packing; after the refinement they are derived again from
the refined positions, in double-double, and a contact that opened or closed is refused
(:class:`~athermal.errors.InputError`): the certificate would describe another network. Rattlers
(fewer than ``d + 1`` contacts, removed iteratively) are not moved; a rattler that carries a load
is refused as not relaxed.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from .contact import ContactModel
from .errors import ConvergenceError, InputError
from .extended import PRECISION, contact_sums, displace, half_steps
from .modes import vibrational_modes
from .moduli import nonrattler_contacts, pinned_solve
from .neighbors import build_neighbor_list
from .observables import isostatic_contacts
from .packing import Packing

TARGET = 1e-20
"""Force balance a certificate asks for: ``max_i |F_i| <= TARGET x`` the mean contact force."""
RELAXED = 1e-6
"""A packing to certify must balance its forces in float64 to this fraction of its mean contact
force (``jam`` ends at 1e-10): a start farther from its minimum is refused as not relaxed."""
MAX_ITERATIONS = 12
"""Newton steps at most; each gains ~8 digits near jamming, and 3-4 reach :data:`TARGET`."""
STALL = 0.5
"""A step that does not reduce the largest residual force below this fraction of the previous
one has reached the limit of the precision."""
LOG_PREFIX = "certificate_"
"""The certificate's fields in a GSD frame's log are ``log/athermal/certificate_<name>``."""
GAP_REACH = 0.2
"""Pairs up to this many mean diameters apart (surface to surface) are the near neighbours whose
gaps the certificate and the gap statistics take."""


@dataclass(frozen=True)
class Certificate:
    """What a certified jamming point guarantees (units of the packing: forces in
    ``k l^(alpha-1)``, lengths in ``l``).

    Attributes
    ----------
    force_balance : ``max_i |grad_i E|`` over every particle, in double-double.
    relative_force_balance : ``force_balance`` over the mean contact force.
    mean_force : mean contact force ``k delta^(alpha-1)`` over the non-rattlers' contacts.
    start_force_balance : ``force_balance`` of the float64 packing it started from.
    contacts : contacts between non-rattlers (``N_c``).
    n_rattlers : rattlers (fewer than ``d + 1`` contacts, removed iteratively).
    excess_contacts : ``N_c - N_iso``, ``N_iso = d (N' - 1) + 1``.
    lowest_eigenvalue : the smallest non-zero eigenvalue of the non-rattlers' Hessian (> 0 at a
        stable minimum), ``k l^(alpha-2)``.
    smallest_force : the smallest contact force between non-rattlers.
    smallest_gap : the smallest surface-to-surface gap ``|x_i - x_j| - r_i - r_j`` between
        non-rattlers not in contact (within :data:`GAP_REACH` mean diameters).
    energy, pressure : of the refined packing, in double-double, rounded to float64.
    iterations : Newton steps taken.
    target : the relative force balance asked for.
    converged : ``relative_force_balance <= target``; False: the precision's limit, stated by
        ``relative_force_balance``.
    precision : the arithmetic used.
    """

    force_balance: float
    relative_force_balance: float
    mean_force: float
    start_force_balance: float
    contacts: int
    n_rattlers: int
    excess_contacts: int
    lowest_eigenvalue: float
    smallest_force: float
    smallest_gap: float
    energy: float
    pressure: float
    iterations: int
    target: float
    converged: bool
    precision: str

    def log(self) -> dict[str, float]:
        """The numeric fields as ``certificate_<name>`` entries for a GSD frame's log."""
        return {
            LOG_PREFIX + name: float(value)
            for name, value in asdict(self).items()
            if not isinstance(value, str)
        }


@dataclass(frozen=True, eq=False)
class CertifiedPacking:
    """A packing whose positions are ``packing.positions + position_lo`` (double-double), with
    its :class:`Certificate`."""

    packing: Packing
    position_lo: NDArray[np.float64]
    certificate: Certificate


@dataclass(frozen=True, eq=False)
class _Sums:
    """The pair sums at ``hi + lo``: overlaps ``(P,)`` (negative: gaps), gradient ``(N, d)``,
    virial ``(d, d)``, energy, each as ``(hi, lo)``."""

    overlap: tuple[NDArray[np.float64], NDArray[np.float64]]
    gradient: tuple[NDArray[np.float64], NDArray[np.float64]]
    virial: tuple[NDArray[np.float64], NDArray[np.float64]]
    energy: tuple[float, float]

    def largest_force(self) -> float:
        """``max_i |grad_i|`` (the norm of each particle's ``hi + lo``)."""
        g = self.gradient[0] + self.gradient[1]
        return float(np.sqrt((g * g).sum(axis=1)).max())


class _Pairs:
    """The near pairs of a packing (contacts and gaps within :data:`GAP_REACH`), their images
    and stiffnesses, fixed for a refinement."""

    def __init__(self, packing: Packing, model: ContactModel) -> None:
        skin = GAP_REACH * 2.0 * float(packing.radii.mean())
        nlist = build_neighbor_list(packing.positions, packing.radii, packing.cell, skin=skin)
        self.first = nlist.first.astype(np.int64)
        self.second = nlist.second.astype(np.int64)
        self.images = np.ascontiguousarray(nlist.images[nlist.code])
        typeid = model.typeid(packing)
        self.stiffness = np.ascontiguousarray(model.kmat[typeid[self.first], typeid[self.second]])
        self.half_steps = half_steps(model.alpha)
        self.alpha = float(model.alpha)
        self.packing = packing

    def sums(self, hi: NDArray[np.float64], lo: NDArray[np.float64]) -> _Sums:
        """The pair sums at ``hi + lo`` ``(N, d)``."""
        p, (n, d) = self.first.size, hi.shape
        overlap = (np.empty(p), np.empty(p))
        gradient = (np.empty((n, d)), np.empty((n, d)))
        virial = (np.empty((d, d)), np.empty((d, d)))
        energy = contact_sums(
            np.ascontiguousarray(hi),
            np.ascontiguousarray(lo),
            self.packing.radii,
            self.first,
            self.second,
            self.images,
            np.ascontiguousarray(self.packing.cell.h),
            self.stiffness,
            self.half_steps,
            self.alpha,
            *overlap,
            *gradient,
            *virial,
        )
        return _Sums(overlap, gradient, virial, (float(energy[0]), float(energy[1])))


def certify(
    packing: Packing,
    model: ContactModel,
    position_lo: NDArray[np.float64] | None = None,
    *,
    target: float = TARGET,
    max_iterations: int = MAX_ITERATIONS,
) -> CertifiedPacking:
    """Refine a jammed packing to force balance ``target`` x its mean contact force in
    double-double, and certify it (module docstring).

    Parameters
    ----------
    packing : a relaxed jammed packing (``jam``'s output), float64; its positions are ``hi``.
    model : the contact model (``2 (alpha - 1)`` an integer: alpha = 2, 2.5, 3, ...).
    position_lo : ``(N, d)`` the low parts of a double-double start (a certified file's
        ``position_lo``); default zeros.
    target : relative force balance to reach, > 0.
    max_iterations : Newton steps at most.

    Returns
    -------
    The refined packing, its low parts and its :class:`Certificate`; ``converged`` False when
    the precision's limit came first (the certificate states what was reached).

    Raises
    ------
    InputError
        The packing is not jammed (no contacts between non-rattlers, or fewer than isostatic),
        not relaxed (float64 force balance above :data:`RELAXED` of its mean contact force, or a
        loaded rattler), or its contact network changed during the refinement (names the pair).
    ConvergenceError
        The Newton correction could not be solved (a Hessian singular beyond the translations).
    """
    if not target > 0.0:
        raise InputError(f"target: must be > 0, got {target}")
    half_steps(model.alpha)
    dim = packing.dim
    hi = np.array(packing.positions, dtype=np.float64)
    lo = np.zeros_like(hi) if position_lo is None else np.array(position_lo, dtype=np.float64)
    if lo.shape != hi.shape:
        raise InputError(f"position_lo: expected shape {hi.shape}, got {lo.shape}")
    contacts, rattler = nonrattler_contacts(packing, model)
    live = int((~rattler).sum())
    excess = contacts.i.size - isostatic_contacts(live, dim)
    if contacts.i.size == 0 or excess < 0:
        raise InputError(
            f"not jammed: {contacts.i.size} contacts between {live} non-rattlers, "
            f"{-excess if excess < 0 else 0} fewer than isostatic; jam it first"
        )
    mean_force = float(contacts.force_magnitude.mean())
    pairs = _Pairs(packing, model)
    sums = pairs.sums(hi, lo)
    start = sums.largest_force()
    if not start <= RELAXED * mean_force:
        raise InputError(
            f"not relaxed: its largest net force is {start / mean_force:.1e} of its mean contact "
            f"force (certify takes <= {RELAXED:g}); relax it first"
        )
    network = sums.overlap[0] > 0.0
    loaded = network & (rattler[pairs.first] | rattler[pairs.second])
    if loaded.any():
        k = int(np.flatnonzero(loaded)[0])
        raise InputError(
            f"not relaxed: rattler contact {pairs.first[k]}-{pairs.second[k]} carries a load"
        )
    force, iterations = start, 0
    while force > target * mean_force and iterations < max_iterations:
        current = packing.with_positions(hi)
        step = _newton_step(current, model, sums.gradient[0], rattler)
        displace(hi, lo, step)
        iterations += 1
        sums, previous = pairs.sums(hi, lo), force
        force = sums.largest_force()
        if force > STALL * previous:
            break
    _same_network(pairs, network, sums.overlap[0] > 0.0)
    refined = packing.with_positions(hi)
    certificate = _certificate(refined, model, pairs, sums, rattler, start, iterations, target)
    return CertifiedPacking(refined, lo, certificate)


def _newton_step(
    packing: Packing,
    model: ContactModel,
    gradient: NDArray[np.float64],
    rattler: NDArray[np.bool_],
) -> NDArray[np.float64]:
    """``-H^+ g`` ``(N, d)`` on the non-rattlers (first one pinned), zero on the rattlers."""
    contacts, _ = nonrattler_contacts(packing, model)
    n, dim = packing.n, packing.dim
    y, residual, _ = pinned_solve(contacts, rattler, gradient.reshape(n, dim, 1))
    if not np.all(np.isfinite(y)) or residual > 1e-6:
        raise ConvergenceError(
            f"certify: the Newton correction did not solve (relative residual {residual:.1e}): "
            "the Hessian of the non-rattlers is singular beyond the translations"
        )
    return -y.reshape(n, dim)


def _same_network(pairs: _Pairs, before: NDArray[np.bool_], after: NDArray[np.bool_]) -> None:
    changed = np.flatnonzero(before != after)
    if changed.size:
        k = int(changed[0])
        what = "opened" if before[k] else "closed"
        raise InputError(
            f"the contact network changed during the refinement: contact {pairs.first[k]}-"
            f"{pairs.second[k]} {what} ({changed.size} pair(s) in all); the float64 packing is "
            "not at the minimum its contacts define"
        )


def _certificate(
    packing: Packing,
    model: ContactModel,
    pairs: _Pairs,
    sums: _Sums,
    rattler: NDArray[np.bool_],
    start: float,
    iterations: int,
    target: float,
) -> Certificate:
    overlap = sums.overlap[0] + sums.overlap[1]
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    touching = live & (overlap > 0.0)
    force = pairs.stiffness[touching] * overlap[touching] ** (model.alpha - 1.0)
    gaps = -overlap[live & (overlap <= 0.0)]
    n_live = int((~rattler).sum())
    modes = vibrational_modes(packing, model, packing.dim + 1, vectors=0)
    balance = sums.largest_force()
    mean_force = float(force.mean())
    volume = packing.cell.volume
    virial = sums.virial[0] + sums.virial[1]
    return Certificate(
        force_balance=balance,
        relative_force_balance=balance / mean_force,
        mean_force=mean_force,
        start_force_balance=start,
        contacts=int(touching.sum()),
        n_rattlers=int(rattler.sum()),
        excess_contacts=int(touching.sum()) - isostatic_contacts(n_live, packing.dim),
        lowest_eigenvalue=float(modes.eigenvalues[modes.zero_modes]),
        smallest_force=float(force.min()),
        smallest_gap=float(gaps.min()) if gaps.size else float("inf"),
        energy=sums.energy[0] + sums.energy[1],
        pressure=float(np.trace(virial)) / (packing.dim * volume),
        iterations=iterations,
        target=target,
        converged=balance <= target * mean_force,
        precision=PRECISION,
    )
