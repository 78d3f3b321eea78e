"""Certified jamming points: force balance beyond float64, by Newton refinement in double-double.

At a jamming point float64 runs out: positions of order one carry absolute errors of ~1e-16, so
overlaps, and with them the contact forces (mean ~1e-8 at epsilon = 1e-6), cannot balance better
than ~1e-7 of the mean force. :func:`certify` holds the positions as ``hi + lo``
(:mod:`athermal.certify.extended`), computes the residual forces in double-double and corrects the
positions by Newton's method on the non-rattlers: each correction ``dx = -H^+ g`` is solved in
float64 (the sparse Hessian at ``hi``, its first non-rattler pinned against the translations,
CHOLMOD: :func:`athermal.analysis.moduli.pinned_solve`) and added in double-double. This is
iterative refinement (Wilkinson; Higham, *Accuracy and Stability of Numerical Algorithms*, ch. 12):
the residual falls by about ``cond(H) x 1e-16`` per step until it reaches the double-double floor,
``~1e-32`` of the positions.

The contacts are those of the start's double-double overlaps; after the refinement they are
derived again from the refined positions, and a contact that formed or broke between non-rattlers
is refused (:class:`~athermal.errors.InputError`): the certificate would describe another
network. Rattlers (fewer than ``d + 1`` contacts, removed iteratively) carry no force at a
certified point: each moves with the mean step of the non-rattlers near it (a Newton step moves
a cage by up to ~1e-9 along soft modes), and one that still overlaps a neighbour is moved to
the nearest place in its cage clear of every neighbour (:mod:`athermal.certify.cage`); a rattler
with no such place bears load, and the packing is not certified. A step that does not improve the
force balance is undone.

:func:`athermal.certify.bisection.bisect_jamming_point` brackets a jamming point below float64's
resolution (~1e-9), each verdict a force balance of the contact network in double-double.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from .._double import two_sum
from .._portable import row_dots, transform
from ..analysis.moduli import (
    lowest_eigenpairs,
    nonrattler_hessian,
    pinned_solve,
    relaxing_displacement,
    zero_tolerance,
)
from ..analysis.observables import isostatic_contacts, rattlers
from ..errors import ConvergenceError, InputError
from ..linalg import supernodal_cholesky
from ..model.contact import ContactModel, Contacts, hessian_floor
from ..model.packing import Packing
from ..relaxation import round_off_floor
from .cage import free_place, free_places
from .extended import PRECISION, NearPairs, PairSums, displace

TARGET = 1e-20
"""Force balance a certificate asks for: ``max_i |F_i| <= TARGET x`` the mean contact force."""
RELAXED = 1e-6
"""A packing to certify must balance its forces in float64 to this fraction of its mean contact
force, or to :data:`ROUND_OFF_SLACK` x float64's round-off floor where that is larger
(:func:`athermal.relaxation.round_off_floor`: Hertzian contacts near jamming, whose forces vanish
faster than the floor); a start farther from its minimum is refused as not relaxed."""
ROUND_OFF_SLACK = 10.0
"""How far above float64's round-off floor a relaxed start may be (:data:`RELAXED`)."""
MAX_ITERATIONS = 12
"""Newton steps at most (``docs/decisions.md``, "Certified jamming points")."""
STALL = 0.5
"""Two steps in a row that do not reduce the largest residual force below this fraction of the
previous one have reached the limit of the precision (one such step alone may be the first
along a soft mode, before Newton's quadratic convergence: ``docs/decisions.md``)."""
DD_FLOOR = 1e-30
"""The force balance double-double reaches, in units of ``k L^(alpha - 1)`` (``L`` the cell
width; measured in ``docs/decisions.md``, "Certified jamming points")."""
LOG_PREFIX = "certificate_"
"""The certificate's fields in a GSD frame's log are ``log/athermal/certificate_<name>``."""
RATTLER_PASSES = 20
"""Rounds of moving overlapping rattlers out at most."""
TOGETHER_DEPTH = 3
"""Rattlers with no room alone move with their rattler neighbours, and where those have no room
either, with the neighbours' rattler neighbours, this many rings deep at most
(:func:`_place_together`)."""
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
    mean_force : mean contact force ``f(delta)`` over the non-rattlers' contacts.
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
    linear_phi_c : the jamming point by the packing's linear response (:func:`toward_jamming`):
        ``phi / (1 + e_c)^d``, ``e_c`` the isotropic expansion at which its overlaps vanish;
        first order in ``phi - phi_c`` while the network holds on the way.
    linearity : ``max |delta / (e_c d|x_ij|/de) - 1|`` over the contacts: 0 when their overlaps
        vanish together (an isostatic network in its linear regime).
    iterations : Newton steps taken.
    target : the relative force balance asked for.
    converged : ``relative_force_balance <= target``, or ``force_balance`` at double-double's
        floor (:func:`precision_floor`: a packing of tiny forces, ~1e-13 above its jamming
        point, reaches ~1e-18 of its mean force); False: the refinement stalled above both.
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
    linear_phi_c: float
    linearity: float
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


def certify(
    packing: Packing,
    model: ContactModel,
    position_lo: NDArray[np.float64] | None = None,
    *,
    target: float = TARGET,
    max_iterations: int = MAX_ITERATIONS,
    portable: bool = True,
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
    portable : the Newton corrections and the linear response solved by cholespy's CHOLMOD, the
        same bits on every CPU; False: by CHOLMOD on the machine's BLAS (cvxopt), many times
        faster on large 3D packings (``docs/decisions.md``, "Factorizations on the machine's
        BLAS"), the bits this machine's.

    Returns
    -------
    The refined packing, its low parts and its :class:`Certificate`; ``converged`` False when
    the precision's limit came first (the certificate states what was reached).

    Raises
    ------
    InputError
        The packing lies between walls, is not jammed (no contacts between non-rattlers, or
        fewer than isostatic),
        not relaxed (float64 force balance above :data:`RELAXED` of its mean contact force), or
        its contact network changed during the refinement (names the pair).
    ConvergenceError
        The Newton correction could not be solved (a Hessian singular beyond the translations),
        or a rattler has no place in its cage clear of its neighbours (it bears load), or
        cannot be moved there without passing through a neighbour.
    """
    if not target > 0.0:
        raise InputError(f"target: must be > 0, got {target}")
    if packing.cell.walls:
        raise InputError(
            "certify: packings between walls are not certified yet (the double-double sums "
            "have no wall terms)"
        )
    model.law.half_steps()
    dim = packing.dim
    hi = np.array(packing.positions, dtype=np.float64, order="C")
    lo = np.zeros_like(hi) if position_lo is None else np.array(position_lo, np.float64, order="C")
    if lo.shape != hi.shape:
        raise InputError(f"position_lo: expected shape {hi.shape}, got {lo.shape}")
    pairs = NearPairs(packing, model, GAP_REACH)
    sums = pairs.sums(hi, lo)
    contacts, rattler = contact_network(pairs, hi, sums)
    live = int((~rattler).sum())
    excess = contacts.i.size - isostatic_contacts(live, dim)
    if contacts.i.size == 0 or excess < 0:
        raise InputError(
            f"not jammed: {contacts.i.size} contacts between {live} non-rattlers, "
            f"{-excess if excess < 0 else 0} fewer than isostatic; jam it first"
        )
    mean_force = float(contacts.force_magnitude.mean())
    start = sums.largest_force()
    floor = ROUND_OFF_SLACK * round_off_floor(contacts, packing.cell)
    if not start <= max(RELAXED * mean_force, floor):
        raise InputError(
            f"not relaxed: its largest net force is {start / mean_force:.1e} of its mean contact "
            f"force (certify takes <= {max(RELAXED, floor / mean_force):.1e}); relax it first"
        )
    live_pair = ~(rattler[pairs.first] | rattler[pairs.second])
    network = live_pair & (sums.overlap[0] > 0.0)
    sums = _freed(pairs, hi, lo, rattler)
    force, iterations, slow = sums.largest_force(), 0, 0
    best = (force, hi.copy(), lo.copy(), sums)
    enough = max(target * mean_force, precision_floor(packing, model))
    while force > enough and iterations < max_iterations:
        _same_network(pairs, network, live_pair & (sums.overlap[0] > 0.0))
        step = _newton_step(pairs, hi, sums, network, rattler, portable)
        carry_rattlers(pairs, step, rattler)
        displace(hi, lo, step)
        sums, previous = _freed(pairs, hi, lo, rattler), force
        iterations += 1
        force = sums.largest_force()
        if force < best[0]:
            best = (force, hi.copy(), lo.copy(), sums)
        slow = slow + 1 if force > STALL * previous else 0
        if slow == 2:
            break
    force, hi, lo, sums = best
    _same_network(pairs, network, live_pair & (sums.overlap[0] > 0.0))
    refined = packing.with_positions(hi)
    certificate = _certificate(
        refined, model, pairs, sums, rattler, start, iterations, target, portable
    )
    return CertifiedPacking(refined, lo, certificate)


def precision_floor(packing: Packing, model: ContactModel) -> float:
    """The force balance double-double resolves at ``packing``: :data:`DD_FLOOR` x the largest
    law's force at the largest stiffness and an overlap of the largest cell width (``k
    L^(alpha - 1)``; force units)."""
    width = np.array([packing.cell.widths.max()])
    return DD_FLOOR * float(model.law.force(width, float(model.kmat.max()))[0])


def contact_network(
    pairs: NearPairs, hi: NDArray[np.float64], sums: PairSums
) -> tuple[Contacts, NDArray[np.bool_]]:
    """The contacts between non-rattlers at ``hi`` by the double-double overlaps of ``sums``
    (float64 misses the smallest overlaps near a jamming point), and the rattler mask ``(N,)``."""
    overlap = sums.overlap[0] + sums.overlap[1]
    touching = overlap > 0.0
    rattler = rattlers(pairs.contacts(hi, overlap, touching), hi.shape[0], hi.shape[1])
    live = touching & ~(rattler[pairs.first] | rattler[pairs.second])
    return pairs.contacts(hi, overlap, live), rattler


def _lowest_eigenvalue(contacts: Contacts, rattler: NDArray[np.bool_], dim: int) -> float:
    """The smallest eigenvalue of the non-rattlers' Hessian beyond its ``d`` translations (NaN
    when there is none); the shifted Hessian factored on the machine's BLAS (a number reported,
    never fed back: :func:`~athermal.linalg.supernodal_cholesky`)."""
    h, _ = nonrattler_hessian(contacts, rattler, dim)
    floor = hessian_floor(contacts, rattler.size)
    values, _ = lowest_eigenpairs(
        h, min(dim + 2, h.shape[0] - 2), floor, factor=supernodal_cholesky
    )
    values = values[np.abs(values) > zero_tolerance(h)]
    return float(values[0]) if values.size else float("nan")


def _newton_step(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    sums: PairSums,
    network: NDArray[np.bool_],
    rattler: NDArray[np.bool_],
    portable: bool,
) -> NDArray[np.float64]:
    """``-H^+ g`` ``(N, d)`` on the non-rattlers (first one pinned), zero on the rattlers, with
    ``H`` the float64 Hessian of the contacts ``network`` at ``hi`` (``portable``:
    :func:`certify`)."""
    n, dim = hi.shape
    contacts = pairs.contacts(hi, sums.overlap[0], network)
    gradient = sums.gradient[0].reshape(n, dim, 1)
    y, residual, _ = pinned_solve(contacts, rattler, gradient, portable=portable)
    if not np.all(np.isfinite(y)) or residual > 1e-6:
        raise ConvergenceError(
            f"certify: the Newton correction did not solve (relative residual {residual:.1e}): "
            "the Hessian of the non-rattlers is singular beyond the translations"
        )
    return -y.reshape(n, dim)


def carry_rattlers(pairs: NearPairs, step: NDArray[np.float64], rattler: NDArray[np.bool_]) -> None:
    """Give each rattler, in ``step`` ``(N, d)``, the mean step of the non-rattlers near it: its
    cage moves by up to ~1e-9 along soft modes, and a rattler left behind would touch it."""
    near = rattler[pairs.first] != rattler[pairs.second]
    cage = np.where(rattler[pairs.first[near]], pairs.second[near], pairs.first[near])
    inside = np.where(rattler[pairs.first[near]], pairs.first[near], pairs.second[near])
    total = np.zeros_like(step)
    np.add.at(total, inside, step[cage])
    count = np.bincount(inside, minlength=step.shape[0])
    moved = rattler & (count > 0)
    step[moved] = total[moved] / count[moved, None]


def free_rattlers(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    lo: NDArray[np.float64],
    rattler: NDArray[np.bool_],
    radii: NDArray[np.float64] | None = None,
) -> tuple[PairSums, NDArray[np.int64]]:
    """Move every rattler that overlaps a neighbour to a place in its cage clear of every
    neighbour (a rattler's place in its cage is free): the nearest, the others held
    (:func:`athermal.certify.cage.free_place`), or, for rattlers with no room alone, one found with
    their rattler neighbours moved too (:func:`athermal.certify.cage.free_places`); a few rounds,
    since a rattler may touch another. Rattlers that have no room even so are left where they
    overlap least: they bear load. Returns the pair sums at the positions reached (the packing's
    radii or ``radii``) and those squeezed rattlers."""
    radii = pairs.packing.radii if radii is None else radii
    reach = radii[pairs.first] + radii[pairs.second]
    free = rattler.copy()
    ends = np.concatenate([pairs.first, pairs.second])
    by_end = np.argsort(ends, kind="stable") % pairs.first.size  # each particle's pairs
    start = np.concatenate([[0], np.cumsum(np.bincount(ends, minlength=hi.shape[0]))])
    for _ in range(RATTLER_PASSES):
        sums = pairs.sums(hi, lo, radii)
        hit = (sums.overlap[0] > 0.0) & (free[pairs.first] | free[pairs.second])
        if not hit.any():
            return sums, np.flatnonzero(rattler & ~free)
        touched = np.concatenate([pairs.first[hit], pairs.second[hit]])
        stuck = []
        for i in np.unique(touched[free[touched]]):
            mine = np.unique(by_end[start[i] : start[i + 1]])  # a self-image pair once
            move = free_place(_offsets(pairs, hi, lo, mine, i), reach[mine])
            if move is None:
                stuck.append(i)
                continue
            step = np.zeros_like(hi)
            step[i] = move
            displace(hi, lo, step)
        if stuck:
            free[_place_together(pairs, hi, lo, reach, free, np.array(stuck))] = False
    raise ConvergenceError(
        f"certify: rattlers still overlap their neighbours after {RATTLER_PASSES} rounds"
    )


def _freed(
    pairs: NearPairs, hi: NDArray[np.float64], lo: NDArray[np.float64], rattler: NDArray[np.bool_]
) -> PairSums:
    """:func:`free_rattlers` where no rattler may bear load."""
    sums, squeezed = free_rattlers(pairs, hi, lo, rattler)
    if squeezed.size:
        raise ConvergenceError(
            f"certify: rattler(s) {', '.join(map(str, squeezed))} cannot be placed in their "
            "cage without overlapping a neighbour: they bear load"
        )
    return sums


def _offsets(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    lo: NDArray[np.float64],
    which: NDArray[np.int64],
    movers: NDArray[np.int64] | int,
) -> NDArray[np.float64]:
    """``x_j - x_i`` ``(len(which), d)`` of the pairs ``which`` at ``hi + lo``, ``i`` the end
    that is among ``movers`` (the first end where both are), rounded once from double-double."""
    one, two = pairs.first[which], pairs.second[which]
    shift = transform(pairs.images[which], pairs.packing.cell.h)
    near, error = two_sum(hi[one], -hi[two])  # x_first - x_second, rounded once at the end
    near, more = two_sum(near, shift)
    sep = near + ((error + more) + (lo[one] - lo[two]))
    return np.where(np.isin(one, movers)[:, None], -sep, sep)


def _place_together(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    lo: NDArray[np.float64],
    reach: NDArray[np.float64],
    free: NDArray[np.bool_],
    stuck: NDArray[np.int64],
) -> NDArray[np.int64]:
    """Move the rattlers ``stuck`` and their rattler neighbours (``free``) together to places
    clear of every neighbour (:func:`athermal.certify.cage.free_places`); where they have no
    room so, with the rattler neighbours of those too, up to :data:`TOGETHER_DEPTH` rings
    (rattlers held fixed may box the movers in); else where the first ring overlaps least.
    Returns those that still overlap there."""
    movers, first = stuck, None
    for _ in range(TOGETHER_DEPTH):
        near = np.isin(pairs.first, movers) | np.isin(pairs.second, movers)
        ends = np.concatenate([pairs.first[near], pairs.second[near]])
        grown = np.union1d(movers, ends[free[ends]])
        if first is not None and grown.size == movers.size:
            break  # no more rattlers near
        movers = grown
        group = _Group(pairs, hi, lo, reach, movers)
        if group.found is not None and group.found[1]:
            group.move(hi, lo)
            return np.empty(0, dtype=np.int64)
        if first is None:
            first = group
    assert first is not None
    if first.found is None:
        raise ConvergenceError(
            f"certify: rattler(s) {', '.join(map(str, stuck))} cannot be moved in their cage "
            "without passing through a neighbour"
        )
    return first.move(hi, lo)


class _Group:
    """Rattlers ``movers`` moved together (:func:`athermal.certify.cage.free_places`): their
    pairs ``which``, each pair's mover and partner (-1: a fixed neighbour) by index among the
    movers, the pairs' offsets, and the moves found with whether they clear every pair."""

    def __init__(
        self,
        pairs: NearPairs,
        hi: NDArray[np.float64],
        lo: NDArray[np.float64],
        reach: NDArray[np.float64],
        movers: NDArray[np.int64],
    ) -> None:
        self.movers = movers
        self.which = np.flatnonzero(np.isin(pairs.first, movers) | np.isin(pairs.second, movers))
        one, two = pairs.first[self.which], pairs.second[self.which]
        first_moves = np.isin(one, movers)
        index = np.full(hi.shape[0], -1)
        index[movers] = np.arange(movers.size)
        self.mover = index[np.where(first_moves, one, two)]
        self.partner = index[np.where(first_moves, two, one)]
        self.offsets = _offsets(pairs, hi, lo, self.which, movers)
        self.reach = reach[self.which]
        self.found = free_places(self.mover, self.partner, self.offsets, self.reach, movers.size)

    def move(self, hi: NDArray[np.float64], lo: NDArray[np.float64]) -> NDArray[np.int64]:
        """Displace the movers (``hi + lo`` updated) by the moves found; the movers that still
        overlap a neighbour there."""
        assert self.found is not None
        moves, clear = self.found
        step = np.zeros_like(hi)
        step[self.movers] = moves
        displace(hi, lo, step)
        if clear:
            return np.empty(0, dtype=np.int64)
        partner, mover = self.partner, self.mover
        sep = self.offsets + np.where((partner < 0)[:, None], 0.0, moves[partner]) - moves[mover]
        touching = np.linalg.norm(sep, axis=1) < self.reach
        ends = np.concatenate([mover[touching], partner[touching & (partner >= 0)]])
        return np.unique(self.movers[ends])


def _same_network(pairs: NearPairs, before: NDArray[np.bool_], after: NDArray[np.bool_]) -> None:
    changed = np.flatnonzero(before != after)
    if changed.size:
        k = int(changed[0])
        what = "broke" if before[k] else "formed"
        raise InputError(
            f"the contact network changed during the refinement: contact {pairs.first[k]}-"
            f"{pairs.second[k]} {what} ({changed.size} pair(s) in all); the float64 packing is "
            "not at the minimum its contacts define"
        )


def _certificate(
    packing: Packing,
    model: ContactModel,
    pairs: NearPairs,
    sums: PairSums,
    rattler: NDArray[np.bool_],
    start: float,
    iterations: int,
    target: float,
    portable: bool,
) -> Certificate:
    overlap = sums.overlap[0] + sums.overlap[1]
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    touching = live & (overlap > 0.0)
    force = model.law.force(overlap[touching], pairs.stiffness[touching])
    gaps = -overlap[live & (overlap <= 0.0)]
    n_live = int((~rattler).sum())
    network, _ = contact_network(pairs, packing.positions, sums)
    lowest = _lowest_eigenvalue(network, rattler, packing.dim)
    strain, _, linearity = toward_jamming(
        pairs, packing.positions, overlap, network, rattler, live, portable=portable
    )
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
        lowest_eigenvalue=lowest,
        smallest_force=float(force.min()),
        smallest_gap=float(gaps.min()) if gaps.size else float("inf"),
        energy=sums.energy[0] + sums.energy[1],
        pressure=float(np.trace(virial)) / (packing.dim * volume),
        linear_phi_c=packing.phi / (1.0 + strain) ** packing.dim,
        linearity=linearity,
        iterations=iterations,
        target=target,
        converged=balance <= max(target * mean_force, precision_floor(packing, model)),
        precision=PRECISION,
    )


def toward_jamming(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    overlap: NDArray[np.float64],
    contacts: Contacts,
    rattler: NDArray[np.bool_],
    live: NDArray[np.bool_],
    *,
    portable: bool = True,
) -> tuple[float, NDArray[np.float64], float]:
    """The jamming point of a jammed packing by its linear response, to first order in its
    distance from it.

    Under an isotropic expansion ``x -> (1 + e) x`` of the cell (radii fixed) with the
    non-affine relaxation of the non-rattlers
    (:func:`athermal.analysis.moduli.relaxing_displacement`),
    each pair's distance grows at the rate ``d|x_ij|/de``, and each contact's ``overlap`` falls
    at that rate; the expansion ``e_c`` at which they vanish (least squares over the
    ``contacts``: in an isostatic network in its linear regime they vanish together) is the
    jamming point, where a gap has grown by ``e_c`` times its rate. Returns ``e_c``, the rates
    ``(P,)`` of the ``pairs`` at positions ``hi`` (``overlap`` their double-double overlaps,
    ``live`` those between non-rattlers; ``contacts``, found at ``hi``, are the pairs of ``live``
    that overlap) and the largest ``|overlap / (e_c rate) - 1|`` over the contacts (infinite
    where a contact does not open; ``portable``: :func:`certify`).
    """
    u = relaxing_displacement(contacts, rattler, np.eye(hi.shape[1]), portable=portable)
    every = slice(None)  # the affine part stretches each pair by its length
    rate = np.linalg.norm(pairs.separations(hi), axis=1) + pair_rates(pairs, hi, u, every)
    touch = live & (overlap > 0.0)
    strain = float(np.sum(overlap[touch] * rate[touch]) / np.sum(rate[touch] ** 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        share = overlap[touch] / (strain * rate[touch])
    linearity = float(np.max(np.abs(np.nan_to_num(share, nan=np.inf) - 1.0)))
    return strain, rate, linearity


def pair_rates(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    mode: NDArray[np.float64],
    which: NDArray[np.intp] | slice,
) -> NDArray[np.float64]:
    """How fast the distance of each pair ``which`` grows along ``mode`` ``(N, d)``."""
    sep = pairs.separations(hi)[which]
    unit = sep / np.linalg.norm(sep, axis=1)[:, None]
    return row_dots(unit, mode[pairs.first[which]] - mode[pairs.second[which]])
