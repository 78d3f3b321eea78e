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

:func:`bisect_jamming_point` brackets a jamming point below float64's resolution (~1e-9), each
verdict a force balance of the contact network in double-double.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from .._double import two_sum
from .._portable import root, row_dots, transform
from ..analysis.modes import lowest_eigenpairs, zero_tolerance
from ..analysis.moduli import nonrattler_hessian, pinned_solve, relaxing_displacement
from ..analysis.observables import isostatic_contacts, rattlers
from ..errors import ConvergenceError, InputError
from ..model.contact import ContactModel, Contacts
from ..model.objective import Objective
from ..model.packing import Packing
from ..protocols.jamming import FINAL_RTOL, JAMMING_MINIMIZER, energy_threshold
from ..relaxation import Relaxer, energy_scale, force_tolerance, round_off_floor
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
FIRST_STEP = 1e-9
"""The first step down in ``phi`` of :func:`bisect_jamming_point`'s march."""
LARGEST_STEP = 1e-8
"""Its largest step (``docs/decisions.md``, "Jamming below float64's resolution")."""
MAX_TRIALS = 2000
"""Its trials at most."""
TRIAL_ITERATIONS = 30
"""Newton steps, and network changes, of one trial at most."""
BLOCKED_MOVE = 1e-3
"""How far (in mean diameters, the largest particle's move) a trial's network, unstable once a
bond parted, is moved along its unstable mode to close the gap that holds it
(:func:`_blocking_pair`): a small rearrangement, well within the pairs' :data:`GAP_REACH`."""
TRIAL_BALANCE = 1e-14
"""A trial's verdict needs its network's forces balanced to this fraction of their mean."""
DD_FLOOR = 1e-30
"""The force balance double-double reaches, in units of ``k L^(alpha - 1)`` (``L`` the cell
width; measured in ``docs/decisions.md``, "Certified jamming points")."""
LOG_PREFIX = "certificate_"
"""The certificate's fields in a GSD frame's log are ``log/athermal/certificate_<name>``."""
RATTLER_PASSES = 20
"""Rounds of moving overlapping rattlers out at most."""
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
        step = _newton_step(pairs, hi, sums, network, rattler)
        _carry_rattlers(pairs, step, rattler)
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
    certificate = _certificate(refined, model, pairs, sums, rattler, start, iterations, target)
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
    when there is none)."""
    h, _ = nonrattler_hessian(contacts, rattler, dim)
    values, _ = lowest_eigenpairs(h, min(dim + 2, h.shape[0] - 2))
    values = values[np.abs(values) > zero_tolerance(h)]
    return float(values[0]) if values.size else float("nan")


def _newton_step(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    sums: PairSums,
    network: NDArray[np.bool_],
    rattler: NDArray[np.bool_],
) -> NDArray[np.float64]:
    """``-H^+ g`` ``(N, d)`` on the non-rattlers (first one pinned), zero on the rattlers, with
    ``H`` the float64 Hessian of the contacts ``network`` at ``hi``."""
    n, dim = hi.shape
    contacts = pairs.contacts(hi, sums.overlap[0], network)
    y, residual, _ = pinned_solve(contacts, rattler, sums.gradient[0].reshape(n, dim, 1))
    if not np.all(np.isfinite(y)) or residual > 1e-6:
        raise ConvergenceError(
            f"certify: the Newton correction did not solve (relative residual {residual:.1e}): "
            "the Hessian of the non-rattlers is singular beyond the translations"
        )
    return -y.reshape(n, dim)


def _carry_rattlers(
    pairs: NearPairs, step: NDArray[np.float64], rattler: NDArray[np.bool_]
) -> None:
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


def _free_rattlers(
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
    for _ in range(RATTLER_PASSES):
        sums = pairs.sums(hi, lo, radii)
        hit = (sums.overlap[0] > 0.0) & (free[pairs.first] | free[pairs.second])
        if not hit.any():
            return sums, np.flatnonzero(rattler & ~free)
        ends = np.concatenate([pairs.first[hit], pairs.second[hit]])
        stuck = []
        for i in np.unique(ends[free[ends]]):
            mine = np.flatnonzero((pairs.first == i) | (pairs.second == i))
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
    """:func:`_free_rattlers` where no rattler may bear load."""
    sums, squeezed = _free_rattlers(pairs, hi, lo, rattler)
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
    clear of every neighbour (:func:`athermal.certify.cage.free_places`), or where they overlap
    least; returns those that still overlap there."""
    near = np.isin(pairs.first, stuck) | np.isin(pairs.second, stuck)
    ends = np.concatenate([pairs.first[near], pairs.second[near]])
    movers = np.unique(ends[free[ends]])
    which = np.flatnonzero(np.isin(pairs.first, movers) | np.isin(pairs.second, movers))
    one, two = pairs.first[which], pairs.second[which]
    first_moves = np.isin(one, movers)
    index = np.full(hi.shape[0], -1)
    index[movers] = np.arange(movers.size)
    mover, partner = index[np.where(first_moves, one, two)], index[np.where(first_moves, two, one)]
    offsets = _offsets(pairs, hi, lo, which, movers)
    found = free_places(mover, partner, offsets, reach[which], movers.size)
    if found is None:
        raise ConvergenceError(
            f"certify: rattler(s) {', '.join(map(str, stuck))} cannot be moved in their cage "
            "without passing through a neighbour"
        )
    moves, clear = found
    step = np.zeros_like(hi)
    step[movers] = moves
    displace(hi, lo, step)
    if clear:
        return np.empty(0, dtype=np.int64)
    sep = offsets + np.where((partner < 0)[:, None], 0.0, moves[partner]) - moves[mover]
    touching = np.linalg.norm(sep, axis=1) < reach[which]
    return np.unique(movers[np.concatenate([mover[touching], partner[touching & (partner >= 0)]])])


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
) -> Certificate:
    overlap = sums.overlap[0] + sums.overlap[1]
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    touching = live & (overlap > 0.0)
    force = model.law.force(overlap[touching], pairs.stiffness[touching])
    gaps = -overlap[live & (overlap <= 0.0)]
    n_live = int((~rattler).sum())
    network, _ = contact_network(pairs, packing.positions, sums)
    lowest = _lowest_eigenvalue(network, rattler, packing.dim)
    strain, _, linearity = toward_jamming(pairs, packing.positions, overlap, network, rattler, live)
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
    where a contact does not open).
    """
    u = relaxing_displacement(contacts, rattler, np.eye(hi.shape[1]))
    every = slice(None)  # the affine part stretches each pair by its length
    rate = np.linalg.norm(pairs.separations(hi), axis=1) + _rates(pairs, hi, u, every)
    touch = live & (overlap > 0.0)
    strain = float(np.sum(overlap[touch] * rate[touch]) / np.sum(rate[touch] ** 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        share = overlap[touch] / (strain * rate[touch])
    linearity = float(np.max(np.abs(np.nan_to_num(share, nan=np.inf) - 1.0)))
    return strain, rate, linearity


@dataclass(frozen=True, eq=False)
class CertifiedJamming:
    """A jamming point bracketed below float64's resolution (:func:`bisect_jamming_point`): the
    jammed bound at ``phi_high`` with its certificate, the unjammed bound ``phi_low``, the
    trials, the contacts the network shed on the way (a hyperstatic network loses the contacts
    whose forces vanish first) and formed, the rattlers readmitted (squeezed by their cage), and
    the instabilities: how often a network that a parted contact left unstable was held by a
    gap that closed along its unstable mode, and the rearrangements: trials relaxed in float64
    because their network gave way at any step."""

    jammed: CertifiedPacking
    phi_low: float
    phi_high: float
    trials: int
    contacts_shed: int
    contacts_formed: int
    rattlers_readmitted: int
    instabilities: int
    rearrangements: int

    def march(self) -> dict[str, int]:
        """The trials and what happened on the way, by name (``jam --json``'s
        ``bisected_in_double_double``)."""
        names = ("trials", "contacts_shed", "contacts_formed", "rattlers_readmitted")
        return {n: getattr(self, n) for n in (*names, "instabilities", "rearrangements")}


def bisect_jamming_point(
    packing: Packing, model: ContactModel, epsilon: float, *, max_trials: int = MAX_TRIALS
) -> CertifiedJamming:
    """Bracket the jamming point of a jammed ``packing`` (``jam``'s output) to ``epsilon`` in
    packing fraction, each verdict taken in double-double on its contact network.

    Near its jamming point a packing keeps its contact network, and the contact forces vanish as
    ``phi`` falls to ``phi_c``. A trial ``phi`` (the radii scaled, float64) balances the forces
    by Newton's method in double-double with the network's contacts as springs of rest length
    ``r_i + r_j`` (pushing when they overlap, pulling when apart); a pair that comes to overlap
    joins the network. The trial is jammed when every contact of the balanced network overlaps
    (a minimum with positive pressure) and every rattler has room in its cage, unjammed when
    every contact is apart (the network holds only in tension: relaxed, the packing loses its
    load). Contacts that part while others hold leave the network (a hyperstatic network sheds
    contacts on its way to ``phi_c``) and the trial is balanced again; a particle left with
    fewer than ``d + 1`` contacts becomes a rattler. Rattlers carry no force in the trials; one
    that has no room in its cage (the network closed in on it) bears load and is readmitted with
    the contacts it has at the least overlapping place there. When the network's Hessian
    (pre-stress included) is not positive definite, and has a negative eigenvalue (a parted
    contact left it unstable), the network is moved along that mode, in the sense that opens the
    most stretched contact that parted, until a near gap closes; that pair joins the network
    (``docs/decisions.md``, "Jamming below float64's resolution"). A singular one is solved by
    MINRES, and a jammed verdict needs a positive definite Hessian. A trial that gives no
    verdict at any step (a network that turns floppy and collapses, or comes apart into rattlers
    while it bears load: not unjammed, ``docs/decisions.md``) is relaxed in float64 from where
    it first moved along an unstable mode, the packing rearranging, and the march goes on from
    its network.
    The trials march down from the certified packing, each from the last jammed one and at
    most a step away (doubled after a balanced trial up to :data:`LARGEST_STEP`, quartered
    after one that gives no verdict: the network's response runs along its soft modes), then
    bisect the last step. float64 cannot do this below ~1e-9: overlaps of ~1e-17 and energies
    of ~1e-28 are round-off there, and a float64 minimum lies ~1e-8 away along the soft modes.
    Harmonic contacts (alpha = 2) only: a spring in tension continues the contact's force
    linearly. Rattlers are placed with a clearance of :data:`athermal.certify.cage.CLEARANCE` x the
    sum of the radii, which bounds the epsilon this resolves (``docs/decisions.md``).

    Raises :class:`InputError` for another alpha or an ``epsilon`` outside ``[1e-15, 1e-6]``;
    :class:`ConvergenceError` when a trial that gives no verdict at a step of ``epsilon / 4``
    cannot be relaxed, or its relaxed network balanced, or ``max_trials`` run out (never a
    verdict on an unbalanced state, a saddle, or a rattler with no room); what :func:`certify`
    raises for the start and the jammed bound. The returned certificate states the force
    balance reached: at a pressure ~1e-13, double-double's ~1e-32 is ~1e-18 of the mean
    contact force.
    """
    if model.law.half_steps() != 2:
        raise InputError("alpha: the certified bisection takes harmonic contacts (alpha = 2)")
    if not 1e-15 <= epsilon <= 1e-6:
        raise InputError(f"epsilon: must lie in [1e-15, 1e-6], got {epsilon}")
    start = certify(packing, model)
    pairs = NearPairs(start.packing, model, GAP_REACH)
    sums = pairs.sums(start.packing.positions, start.position_lo)
    _, rattler = contact_network(pairs, start.packing.positions, sums)
    stiffness = pairs.stiffness
    bonds = ~(rattler[pairs.first] | rattler[pairs.second]) & (sums.overlap[0] > 0.0)
    first = bonds.copy()
    hi, lo = start.packing.positions.copy(), start.position_lo.copy()
    phi0, radii0, dim = packing.phi, packing.radii, packing.dim
    high, low, step, trials, radii = phi0, -1.0, FIRST_STEP, 0, radii0
    readmitted, instabilities, rearranged, shed, formed = 0, 0, 0, 0, 0
    while low < 0.0 or high - low > epsilon:
        if trials == max_trials:
            raise ConvergenceError(f"certify: no bracket of {epsilon:g} in {max_trials} trials")
        phi = high - step if low < 0.0 else max(0.5 * (low + high), high - step)
        trial_radii = radii0 * root(phi / phi0, dim)
        trial_hi, trial_lo = hi.copy(), lo.copy()
        trials += 1
        verdict, trial_bonds, trial_rattler, held = _trial(
            pairs, stiffness, trial_hi, trial_lo, trial_radii, bonds, rattler
        )
        if verdict is None and step >= epsilon / 4.0:
            step /= 4.0
            continue
        if verdict is None:  # at any step the network gives way: the packing rearranges
            trial_hi, trial_lo = hi.copy(), lo.copy()
            _trial(pairs, stiffness, trial_hi, trial_lo, trial_radii, bonds, rattler, escape=True)
            start_moved = Packing(trial_hi + trial_lo, trial_radii, packing.cell)
            relaxed = _rearranged(start_moved, model, phi)
            rearranged += 1
            if relaxed is None:
                low = phi
                continue
            moved = NearPairs(relaxed, model, GAP_REACH)
            trial_hi, trial_lo = relaxed.positions.copy(), np.zeros_like(relaxed.positions)
            sums = moved.sums(trial_hi, trial_lo)
            _, start_rattler = contact_network(moved, trial_hi, sums)
            live = ~(start_rattler[moved.first] | start_rattler[moved.second])
            start_bonds = live & (sums.overlap[0] > 0.0)
            full = moved.stiffness.copy()
            verdict, trial_bonds, trial_rattler, held = _trial(
                moved, full, trial_hi, trial_lo, trial_radii, start_bonds, start_rattler
            )
            moved.stiffness = full
            if verdict is None:
                raise ConvergenceError(
                    f"certify: at phi = {phi:.15f} the network gives way, and the network of the "
                    "packing relaxed there does not balance"
                )
            if verdict:  # another packing from here on: it may stay jammed below the old bound
                shed += int(np.sum(first & ~bonds))
                formed += int(np.sum(bonds & ~first))
                pairs, stiffness, first, rattler = moved, full, start_bonds, start_rattler
                low = -1.0
        if verdict:
            readmitted += int(np.sum(rattler & ~trial_rattler))
            instabilities += held
            high, hi, lo, radii = phi, trial_hi, trial_lo, trial_radii
            bonds, rattler = trial_bonds, trial_rattler
            step = min(2.0 * step, LARGEST_STEP)
        else:
            low = phi
    pairs.stiffness = stiffness
    final = Packing(hi, radii, packing.cell)
    jammed = certify(final, model, lo)
    return CertifiedJamming(
        jammed,
        low,
        jammed.packing.phi,
        trials,
        shed + int(np.sum(first & ~bonds)),
        formed + int(np.sum(bonds & ~first)),
        readmitted,
        instabilities,
        rearranged,
    )


def _clear(
    pairs: NearPairs, hi: NDArray[np.float64], lo: NDArray[np.float64], radii: NDArray[np.float64]
) -> bool | None:
    """A trial whose network came apart (its tensile contacts parted, and the particles left
    with too few contacts cascaded into rattlers): False (unjammed) when every particle that
    still overlaps a neighbour moves to a place clear of all of them (:func:`_free_rattlers`,
    ``hi + lo`` updated), none by more than :data:`BLOCKED_MOVE` mean diameters: a state
    without overlaps, so without load, lies a small move away. None (no verdict: the packing
    rearranges) when some bear load, or clear only farther away."""
    start = hi.copy(), lo.copy()
    try:
        _, squeezed = _free_rattlers(pairs, hi, lo, np.ones(hi.shape[0], dtype=bool), radii)
    except ConvergenceError:
        return None
    moved = float(np.abs((hi - start[0]) + (lo - start[1])).max())
    if squeezed.size or moved > BLOCKED_MOVE * 2.0 * float(radii.mean()):
        return None
    return False


def _rearranged(start: Packing, model: ContactModel, phi: float) -> Packing | None:
    """A trial whose network gives no verdict at any step: a contact parts, the network turns
    floppy and collapses, and the packing rearranges. Relaxed from ``start`` (the trial's radii;
    the last jammed positions moved along the network's first unstable mode until a gap closes,
    so that a contact parted by less than float64 resolves starts the rearrangement, or where
    the trial, run again with ``escape``, stopped without meeting one) in float64 to a minimum,
    as ``jam``'s own steps are: that minimum, or None (unjammed) when its energy lies below
    ``jam``'s threshold. Raises :class:`ConvergenceError` when no minimum is found."""
    objective = Objective(start, model)
    floor = energy_threshold(start.dim, model.alpha) * start.n * energy_scale(start.radii, model)
    try:
        result, _ = Relaxer(objective, JAMMING_MINIMIZER).relax_to_minimum(
            objective.x0, gtol=force_tolerance(start, model, FINAL_RTOL), etol=floor
        )
    except ConvergenceError as exc:
        raise ConvergenceError(
            f"certify: at phi = {phi:.15f} the network gives way, and relaxing the packing there "
            f"found no minimum ({exc})"
        ) from exc
    return None if result.energy <= floor else result.packing


def _unstable_mode(
    contacts: Contacts, rattler: NDArray[np.bool_], shape: tuple[int, ...]
) -> NDArray[np.float64] | None:
    """The eigenvector ``shape`` ``(N, d)`` of the lowest eigenvalue of the non-rattlers'
    Hessian (pre-stress included) when that eigenvalue is negative; None otherwise."""
    h, dofs = nonrattler_hessian(contacts, rattler, shape[1])
    values, vectors = lowest_eigenpairs(h, min(shape[1] + 2, h.shape[0] - 2))
    if not values[0] < -zero_tolerance(h):
        return None
    flat = np.zeros(shape[0] * shape[1])
    flat[dofs] = vectors[:, 0]
    return flat.reshape(shape)


def _blocking_pair(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    lo: NDArray[np.float64],
    mode: NDArray[np.float64],
    rattler: NDArray[np.bool_],
    bonds: NDArray[np.bool_],
    overlap: NDArray[np.float64],
    parted: NDArray[np.bool_] | None,
) -> int | None:
    """A network unstable along ``mode`` (a negative eigenvalue of its Hessian: the pre-stress
    of the bonds left after some parted) gives way along it until a near gap closes, and the new
    contact holds the mode. Moves ``hi + lo`` (rattlers carried) along ``mode`` until the first
    gap closes, exactly, and returns that pair: in the sense that opens the most stretched of
    the bonds ``parted`` (they parted in tension; none of them is taken), or where none did,
    the sense that closes a gap first. None when no gap closes within :data:`BLOCKED_MOVE`."""
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    candidate = live & ~bonds & (overlap <= 0.0)
    senses: tuple[float, ...] = (1.0, -1.0)
    if parted is not None and parted.any():
        candidate &= ~parted
        worst = int(np.argmin(np.where(parted, pairs.stiffness * overlap, np.inf)))
        senses = (1.0,) if _rates(pairs, hi, mode, np.array([worst]))[0] > 0.0 else (-1.0,)
    near = np.flatnonzero(candidate)
    sep = pairs.separations(hi)[near]
    length = np.linalg.norm(sep, axis=1)
    gap = -overlap[near]
    best: tuple[float, int, float] | None = None
    for sense in senses:  # |sep + t sense (m_i - m_j)| = r_i + r_j, the smallest t > 0
        along = sense * (mode[pairs.first[near]] - mode[pairs.second[near]])
        a = row_dots(along, along)
        b = 2.0 * row_dots(sep, along)
        c = gap * (2.0 * length - gap)  # |sep|^2 - (r_i + r_j)^2, from the double-double gap
        disc = b * b - 4.0 * a * c
        closing = (b < 0.0) & (disc >= 0.0)
        if not closing.any():
            continue
        t = 2.0 * c[closing] / (-b[closing] + np.sqrt(disc[closing]))
        k = int(np.argmin(t))
        if best is None or t[k] < best[0]:
            best = (float(t[k]), int(near[closing][k]), sense)
    diameter = 2.0 * float(pairs.packing.radii.mean())
    if best is None or best[0] * np.abs(mode).max() > BLOCKED_MOVE * diameter:
        return None
    step = best[2] * best[0] * (1.0 + 1e-9) * mode
    _carry_rattlers(pairs, step, rattler)
    displace(hi, lo, step)
    return best[1]


def _rates(
    pairs: NearPairs,
    hi: NDArray[np.float64],
    mode: NDArray[np.float64],
    which: NDArray[np.intp] | slice,
) -> NDArray[np.float64]:
    """How fast the distance of each pair ``which`` grows along ``mode`` ``(N, d)``."""
    sep = pairs.separations(hi)[which]
    unit = sep / np.linalg.norm(sep, axis=1)[:, None]
    return row_dots(unit, mode[pairs.first[which]] - mode[pairs.second[which]])


def _trial(
    pairs: NearPairs,
    stiffness: NDArray[np.float64],
    hi: NDArray[np.float64],
    lo: NDArray[np.float64],
    radii: NDArray[np.float64],
    bonds: NDArray[np.bool_],
    rattler: NDArray[np.bool_],
    *,
    escape: bool = False,
) -> tuple[bool | None, NDArray[np.bool_], NDArray[np.bool_], int]:
    """Balance the network ``bonds`` at ``radii`` from ``hi + lo`` (updated in place), the
    rattlers' pairs without force: whether it is jammed (None: Newton did not converge in
    :data:`TRIAL_ITERATIONS`, or its correction could not be solved: never a verdict), its bonds,
    its rattlers (a particle left with fewer than ``d + 1`` bonds by shed contacts joins them)
    and how often its network gave way and a closing gap held it (:func:`_blocking_pair`).
    With ``escape``, it stops (no verdict) once it has moved along the first unstable mode:
    where a rearrangement starts, below float64's resolution."""
    n, dim = hi.shape
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    pairs.stiffness = np.where(live, stiffness, 0.0)
    sums = pairs.sums(hi, lo, radii, bonds)
    parted: NDArray[np.bool_] | None = None  # the bonds that parted last, until a solve
    definite, held = False, 0  # definite: the last factor was of the network as it is
    for _ in range(TRIAL_ITERATIONS):
        overlap = sums.overlap[0] + sums.overlap[1]
        formed = live & ~bonds & (overlap > 0.0)
        if formed.any():
            bonds, definite = bonds | formed, False
            sums = pairs.sums(hi, lo, radii, bonds)
        scale = float(np.abs(pairs.stiffness * overlap)[bonds].mean())
        contacts = pairs.contacts(hi, sums.overlap[0], bonds)
        force = sums.gradient[0].reshape(n, dim, 1)
        if sums.largest_force() <= TRIAL_BALANCE * scale:
            apart = bonds & (overlap <= 0.0)
            if not apart.any():
                if (
                    not definite
                    and pinned_solve(contacts, rattler, force, iterative=False)[1] == np.inf
                ):
                    return None, bonds, rattler, held  # balanced on a saddle: no verdict
                pairs.stiffness = stiffness
                try:
                    free, squeezed = _free_rattlers(pairs, hi, lo, rattler, radii)
                except ConvergenceError:
                    return None, bonds, rattler, held
                if not squeezed.size:
                    return True, bonds, rattler, held
                rattler = rattler.copy()  # readmitted: they bear load
                rattler[squeezed] = False
                live = ~(rattler[pairs.first] | rattler[pairs.second])
                bonds, definite = bonds | (live & (free.overlap[0] > 0.0)), False
                ends = np.concatenate([pairs.first[bonds], pairs.second[bonds]])
                if np.any(np.bincount(ends, minlength=n)[squeezed] < dim + 1):
                    return None, bonds, rattler, held  # held at fewer contacts: not a minimum
                pairs.stiffness = np.where(live, stiffness, 0.0)
                sums = pairs.sums(hi, lo, radii, bonds)
                continue
            if apart.sum() == bonds.sum():
                return False, bonds, rattler, held
            parted = apart
            bonds, definite = bonds & ~apart, False
            rattler = rattler | rattlers(pairs.contacts(hi, overlap, bonds), n, dim)
            live = ~(rattler[pairs.first] | rattler[pairs.second])
            bonds = bonds & live
            if not bonds.any():  # the network came apart: unjammed if nothing overlaps
                return _clear(pairs, hi, lo, radii), bonds, rattler, held
            pairs.stiffness = np.where(live, stiffness, 0.0)
            sums = pairs.sums(hi, lo, radii, bonds)
            continue
        y, residual, solver = pinned_solve(contacts, rattler, force, iterative=False)
        if residual == np.inf:  # not positive definite: unstable, or singular
            mode = _unstable_mode(contacts, rattler, hi.shape)
            if mode is not None:
                blocking = _blocking_pair(pairs, hi, lo, mode, rattler, bonds, overlap, parted)
                if blocking is None or escape:  # it gives way further than a small move
                    return None, bonds, rattler, held
                held, parted, definite = held + 1, None, False
                bonds = bonds.copy()
                bonds[blocking] = True
                sums = pairs.sums(hi, lo, radii, bonds)
                continue
            y, residual, solver = pinned_solve(contacts, rattler, force)  # singular, consistent
        if not np.all(np.isfinite(y)) or residual > 1e-6:
            return None, bonds, rattler, held
        parted, definite = None, solver == "cholmod"
        step = -y.reshape(n, dim)
        _carry_rattlers(pairs, step, rattler)
        displace(hi, lo, step)
        sums = pairs.sums(hi, lo, radii, bonds)
    return None, bonds, rattler, held
