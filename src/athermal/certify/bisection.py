"""The jamming point bracketed below float64's resolution: a bisection in packing fraction whose
every verdict is taken in double-double on the packing's contact network
(:func:`bisect_jamming_point`; ``docs/decisions.md``, "Jamming below float64's resolution")."""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .._portable import root, row_dots, vnorm
from ..analysis.modes import lowest_eigenpair_near
from ..analysis.moduli import (
    lowest_eigenpairs,
    nonrattler_hessian,
    pinned_hessian,
    pinned_solve,
    unit_translations,
    unpinned,
    zero_tolerance,
)
from ..analysis.observables import rattlers
from ..errors import ConvergenceError, InputError
from ..linalg import (
    Factor,
    NotPositiveDefinite,
    dissection_order,
    factor_cg,
    row_order,
    supernodal_cholesky,
)
from ..model.contact import ContactModel, Contacts, find_contacts, hessian_floor
from ..model.objective import Objective
from ..model.packing import Packing
from ..protocols.jamming import FINAL_RTOL, JAMMING_MINIMIZER, RESOLUTION, energy_threshold
from ..relaxation import Relaxer, energy_scale, force_tolerance
from . import (
    GAP_REACH,
    CertifiedPacking,
    carry_rattlers,
    certify,
    contact_network,
    free_rattlers,
    pair_rates,
)
from .extended import NearPairs, displace

START_EPSILON = 1e-7
"""The float64 bracket of the jammed packing :func:`bisect_jamming_point` starts from (``jam
--certify`` jams to it first): a hundred times float64's resolution, so that the march in
double-double covers at most ~1e-7 (``docs/decisions.md``, "Three costs of the certified march
removed", on why not closer)."""
FIRST_STEP = 1e-9
"""The first step down in ``phi`` of :func:`bisect_jamming_point`'s march."""
LARGEST_STEP = 1e-8
"""Its largest step (``docs/decisions.md``, "Jamming below float64's resolution")."""
MAX_TRIALS = 2000
"""Its trials at most."""
MAX_LIFTS = 1
"""How often a march takes a rearrangement that float64 cannot resolve :data:`START_EPSILON`
higher (:func:`_landing`): the packing compressed may return to the network that gave way, and
give way again where it did (``docs/decisions.md``, "A rearrangement that lands at its own
jamming point")."""
MARCH_BITS = (
    "this machine's: the march factors on cvxopt's BLAS, and ARPACK finds its unstable modes"
)
"""What ``jam`` prints as ``bits`` when a march ran: its factorizations are CHOLMOD's supernodal
ones on the machine's BLAS (:func:`~athermal.linalg.supernodal_cholesky`), and its unstable
modes ARPACK's and LOBPCG's (BLAS inside)."""
TRIAL_ITERATIONS = 30
"""Newton steps, and network changes, of one trial at most."""
BLOCKED_MOVE = 1e-3
"""How far (in mean diameters, the largest particle's move) a trial's network, unstable once a
bond parted, is moved along its unstable mode to close the gap that holds it
(:func:`_blocking_pair`): a small rearrangement, well within the pairs' :data:`GAP_REACH`."""
TRIAL_BALANCE = 1e-14
"""A trial's verdict needs its network's forces balanced to this fraction of their mean."""
CORRECTION_RTOL = 1e-12
"""Relative residual of a Newton correction found by conjugate gradients (:class:`_KeptFactor`):
a direct solve's, at the condition numbers of a network near jamming."""
CORRECTION_ITERATIONS = 50
"""Conjugate gradient iterations of a Newton correction at most before a fresh factorization."""
MODE_ITERATIONS = 100
"""LOBPCG iterations of an unstable mode at most before a shift-invert factorization."""
CHECKPOINT_TRIALS = 8
"""The march hands its state to ``on_checkpoint`` every this many trials, and starts its linear
algebra afresh there (:class:`_KeptFactor`), so that a march resumed from that state takes the
path of one that was not stopped, bit for bit."""


def float64_epsilon(epsilon: float) -> float:
    """The bracket the float64 jam runs to for a jamming point wanted to ``epsilon``:
    ``epsilon`` itself where float64 takes the verdict (at least :data:`~athermal.protocols.
    RESOLUTION`), else :data:`START_EPSILON`, from which the double-double march goes on."""
    return epsilon if epsilon >= RESOLUTION else START_EPSILON


@dataclass(frozen=True, eq=False)
class MarchState:
    """:func:`bisect_jamming_point`'s march between two trials: what a resumed march starts from.

    Attributes
    ----------
    source_positions, source_radii : ``(N, d)``, ``(N,)`` the packing whose near pairs the march
        uses (the certified start, or the packing relaxed where the march last rearranged).
    first, bonds : ``(P,)`` the bonds of the march's first network and of the last jammed one,
        over those pairs.
    rattler : ``(N,)`` the rattlers of the last jammed trial.
    hi, lo : ``(N, d)`` its positions, ``hi + lo``.
    radii : ``(N,)`` its radii.
    high, low, step : the bracket (``low`` -1: none yet) and the next step down.
    counts : trials, contacts shed, contacts formed, rattlers readmitted, instabilities,
        rearrangements, rearrangements lifted so far (a state of six counts: none lifted).
    """

    source_positions: NDArray[np.float64]
    source_radii: NDArray[np.float64]
    first: NDArray[np.bool_]
    bonds: NDArray[np.bool_]
    rattler: NDArray[np.bool_]
    hi: NDArray[np.float64]
    lo: NDArray[np.float64]
    radii: NDArray[np.float64]
    high: float
    low: float
    step: float
    counts: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class CertifiedJamming:
    """A jamming point bracketed below float64's resolution (:func:`bisect_jamming_point`): the
    jammed bound at ``phi_high`` with its certificate, the unjammed bound ``phi_low``, the
    trials, the contacts the network shed on the way (a hyperstatic network loses the contacts
    whose forces vanish first) and formed, the rattlers readmitted (squeezed by their cage), and
    the instabilities: how often a network that a parted contact left unstable was held by a
    gap that closed along its unstable mode, the rearrangements: trials relaxed in float64
    because their network gave way at any step, and of them those lifted: relaxed
    :data:`START_EPSILON` higher, where float64 resolves them (:func:`_landing`)."""

    jammed: CertifiedPacking
    phi_low: float
    phi_high: float
    trials: int
    contacts_shed: int
    contacts_formed: int
    rattlers_readmitted: int
    instabilities: int
    rearrangements: int
    lifted: int

    def march(self) -> dict[str, int]:
        """The trials and what happened on the way, by name (``jam --json``'s
        ``bisected_in_double_double``)."""
        names = ("trials", "contacts_shed", "contacts_formed", "rattlers_readmitted")
        return {n: getattr(self, n) for n in (*names, "instabilities", "rearrangements", "lifted")}


def bisect_jamming_point(
    packing: Packing,
    model: ContactModel,
    epsilon: float,
    *,
    max_trials: int = MAX_TRIALS,
    resume: MarchState | None = None,
    on_checkpoint: Callable[[MarchState], None] | None = None,
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
    its network; where the rearranged packing lands within float64's resolution of its own
    jamming point (no minimum found, or its network gives no verdict), it is relaxed
    :data:`START_EPSILON` higher instead, at most :data:`MAX_LIFTS` times a march, and the
    march starts again from there.
    The trials march down from the certified packing, each from the last jammed one and at
    most a step away (doubled after a balanced trial up to :data:`LARGEST_STEP`, quartered
    after one that gives no verdict: the network's response runs along its soft modes), then
    bisect the last step. float64 cannot do this below ~1e-9: overlaps of ~1e-17 and energies
    of ~1e-28 are round-off there, and a float64 minimum lies ~1e-8 away along the soft modes.
    Harmonic contacts (alpha = 2) only: a spring in tension continues the contact's force
    linearly. Rattlers are placed with a clearance of :data:`athermal.certify.cage.CLEARANCE` x the
    sum of the radii, which bounds the epsilon this resolves (``docs/decisions.md``).

    Raises :class:`InputError` for another alpha or an ``epsilon`` outside ``[1e-15, 1e-6]``;
    :class:`ConvergenceError` when a packing rearranged is not jammed :data:`START_EPSILON`
    above where its network gave way, or lands unresolved after :data:`MAX_LIFTS` lifts, or
    ``max_trials`` run out (never a
    verdict on an unbalanced state, a saddle, or a rattler with no room); what :func:`certify`
    raises for the start and the jammed bound. The returned certificate states the force
    balance reached: at a pressure ~1e-13, double-double's ~1e-32 is ~1e-18 of the mean
    contact force.

    Every :data:`CHECKPOINT_TRIALS` trials the march's state goes to ``on_checkpoint``; the
    march of the same ``packing`` and ``epsilon`` given that state as ``resume`` continues from
    it to the bracket an uninterrupted march reaches, bit for bit.
    """
    if model.law.half_steps() != 2:
        raise InputError("alpha: the certified bisection takes harmonic contacts (alpha = 2)")
    if not 1e-15 <= epsilon <= 1e-6:
        raise InputError(f"epsilon: must lie in [1e-15, 1e-6], got {epsilon}")
    phi0, radii0, dim = packing.phi, packing.radii, packing.dim
    if resume is None:
        start = certify(packing, model, portable=False)
        source = start.packing
        pairs = NearPairs(source, model, GAP_REACH)
        sums = pairs.sums(source.positions, start.position_lo)
        _, rattler = contact_network(pairs, source.positions, sums)
        bonds = ~(rattler[pairs.first] | rattler[pairs.second]) & (sums.overlap[0] > 0.0)
        first = bonds.copy()
        hi, lo = source.positions.copy(), start.position_lo.copy()
        high, low, step, radii = phi0, -1.0, FIRST_STEP, radii0
        trials, shed, formed, readmitted, instabilities, rearranged, lifted = 0, 0, 0, 0, 0, 0, 0
    else:
        source = Packing(resume.source_positions, resume.source_radii, packing.cell)
        pairs = NearPairs(source, model, GAP_REACH)
        first, bonds, rattler = resume.first, resume.bonds, resume.rattler
        hi, lo, radii = resume.hi.copy(), resume.lo.copy(), resume.radii
        high, low, step = resume.high, resume.low, resume.step
        counts = (*resume.counts, 0)[:7]  # a state of six counts was written before lifts
        trials, shed, formed, readmitted, instabilities, rearranged, lifted = counts
    stiffness = pairs.stiffness
    kept, saved = _KeptFactor(packing, model), trials
    while low < 0.0 or high - low > epsilon:
        if trials % CHECKPOINT_TRIALS == 0 and trials != saved:
            kept, saved = kept.afresh(), trials
            if on_checkpoint is not None:
                counts = (trials, shed, formed, readmitted, instabilities, rearranged, lifted)
                on_checkpoint(
                    MarchState(
                        source.positions.copy(),
                        source.radii.copy(),
                        first.copy(),
                        bonds.copy(),
                        rattler.copy(),
                        hi.copy(),
                        lo.copy(),
                        radii.copy(),
                        high,
                        low,
                        step,
                        counts,
                    )
                )
        if trials == max_trials:
            raise ConvergenceError(f"certify: no bracket of {epsilon:g} in {max_trials} trials")
        phi = high - step if low < 0.0 else max(0.5 * (low + high), high - step)
        trial_radii = radii0 * root(phi / phi0, dim)
        trial_hi, trial_lo = hi.copy(), lo.copy()
        trials += 1
        verdict, trial_bonds, trial_rattler, held = _trial(
            pairs, stiffness, trial_hi, trial_lo, trial_radii, bonds, rattler, kept
        )
        if verdict is None and step >= epsilon / 4.0:
            step /= 4.0
            continue
        if verdict is None:  # at any step the network gives way: the packing rearranges
            trial_hi, trial_lo = hi.copy(), lo.copy()
            _trial(
                pairs,
                stiffness,
                trial_hi,
                trial_lo,
                trial_radii,
                bonds,
                rattler,
                kept,
                escape=True,
            )
            moved_from = trial_hi + trial_lo
            rearranged += 1
            try:
                landing = _landing(Packing(moved_from, trial_radii, packing.cell), model, phi, kept)
            except ConvergenceError as exc:  # unresolved this near its jamming point: lift it
                if lifted == MAX_LIFTS:
                    raise ConvergenceError(
                        f"{exc}; the march took {lifted} such rearrangement {START_EPSILON:g} "
                        "higher already"
                    ) from exc
                lifted += 1
                phi += START_EPSILON
                trial_radii = radii0 * root(phi / phi0, dim)
                landing = _landing(Packing(moved_from, trial_radii, packing.cell), model, phi, kept)
                if landing is None or not landing.trial[0]:
                    raise ConvergenceError(
                        f"certify: the packing rearranged at phi = {phi - START_EPSILON:.15f} "
                        f"is not jammed {START_EPSILON:g} above it"
                    ) from None
                step = FIRST_STEP / 2.0  # a march from a new start: doubled below to FIRST_STEP
            if landing is None:
                low = phi
                continue
            verdict, trial_bonds, trial_rattler, held = landing.trial
            trial_hi, trial_lo = landing.hi, landing.lo
            if verdict:  # another packing from here on: it may stay jammed below the old bound
                shed += int(np.sum(first & ~bonds))
                formed += int(np.sum(bonds & ~first))
                pairs, stiffness = landing.pairs, landing.pairs.stiffness
                first, rattler = landing.bonds, landing.rattler
                source = landing.relaxed
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
    jammed = certify(final, model, lo, portable=False)
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
        lifted,
    )


class _KeptFactor:
    """The linear algebra of one march's trials, with the last factor of a trial network's
    Hessian kept (its first non-rattler pinned, :func:`~athermal.analysis.moduli.
    pinned_hessian`): the networks of neighbouring trials differ by a few bonds and a small
    pre-stress, so a few solves with it replace a factorization. Newton corrections
    ``H^-1 force`` by conjugate gradients preconditioned with it (:func:`~athermal.linalg.
    factor_cg`), else, or when they do not reach :data:`CORRECTION_RTOL` in
    :data:`CORRECTION_ITERATIONS`, by a fresh factor, kept; unstable modes by LOBPCG
    preconditioned with it; positive definiteness by a fresh factor, kept. Every factor is
    CHOLMOD's supernodal one on the machine's BLAS (:func:`~athermal.linalg.
    supernodal_cholesky`), its rows in the order of :func:`~athermal.linalg.dissection_order`
    of the contact network of ``packing`` (the march's start: its particles move by far less
    than a diameter)."""

    def __init__(self, packing: Packing, model: ContactModel) -> None:
        contacts = find_contacts(packing, model)
        widths = packing.cell.widths
        points = np.mod(packing.cell.fractional(packing.positions), 1.0) * widths
        self._rank = dissection_order(points, widths, contacts.i, contacts.j)
        self._dim = packing.dim
        self._kept: tuple[NDArray[np.intp], Factor] | None = None  # its rows' dofs, factor

    def afresh(self) -> _KeptFactor:
        """The same order, no factor kept (the march's linear algebra started again)."""
        fresh = copy.copy(self)
        fresh._kept = None
        return fresh

    def solve(
        self, contacts: Contacts, rattler: NDArray[np.bool_], force: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], float, str]:
        """``y`` ``(N d, 1)`` (zero on the rattlers) of ``force`` ``(N, d, 1)``, its relative
        residual and how it was found: ``"cg"``, or ``"cholmod"`` (a fresh factor: the Hessian is
        positive definite); zeros, an infinite residual and ``"none"`` when the Hessian is not
        positive definite (a factor that fails, or a direction of no curvature)."""
        h, dofs = pinned_hessian(contacts, rattler, force.shape[1])
        b = np.ascontiguousarray(force.reshape(-1)[dofs])
        y = np.zeros((force.size, 1))
        near = self._near(dofs)
        if near is not None:
            try:
                found = factor_cg(h, b, near, CORRECTION_RTOL, CORRECTION_ITERATIONS)
            except NotPositiveDefinite:
                return y, np.inf, "none"
            if found is not None:
                y[dofs, 0] = found[0]
                return y, found[1], "cg"
        factor = self._factor(h, dofs)
        if factor is None:
            return y, np.inf, "none"
        y[dofs] = factor.solve(b[:, None])
        residual = vnorm(h @ y[dofs, 0] - b) / max(vnorm(b), np.finfo(float).tiny)
        return y, residual, "cholmod"

    def unstable_mode(
        self, contacts: Contacts, rattler: NDArray[np.bool_], shape: tuple[int, ...]
    ) -> NDArray[np.float64] | None:
        """The eigenvector ``shape`` ``(N, d)`` (zero on the rattlers) of the lowest eigenvalue
        of the non-rattlers' Hessian (pre-stress included) beyond its translations, when that
        eigenvalue is negative; None otherwise. By LOBPCG preconditioned with the kept factor
        where it is of these non-rattlers (:func:`~athermal.analysis.modes.
        lowest_eigenpair_near`, to a residual of the zero tolerance), else, or where that does
        not converge in :data:`MODE_ITERATIONS`, by shift-invert below the contacts' floor
        (:func:`~athermal.analysis.moduli.lowest_eigenpairs`)."""
        n, dim = shape
        h, dofs = nonrattler_hessian(contacts, rattler, dim)
        tolerance = zero_tolerance(h)
        rows = unpinned(dofs.size, dim, ())
        near = self._near(dofs[rows])
        found = None
        if near is not None:
            null = unit_translations(dofs, dim)
            found = lowest_eigenpair_near(h, near, tolerance, MODE_ITERATIONS, rows=rows, null=null)
        if found is None:
            values, vectors = lowest_eigenpairs(
                h,
                1,
                hessian_floor(contacts, n),
                saddle=True,
                factor=lambda shifted: self._cholesky(shifted, dofs),
            )
            found = float(values[0]), vectors[:, 0]
        if not found[0] < -tolerance:
            return None
        flat = np.zeros(n * dim)
        flat[dofs] = found[1]
        return flat.reshape(shape)

    def definite(self, contacts: Contacts, rattler: NDArray[np.bool_], dim: int) -> bool:
        """Whether the Hessian is positive definite (a fresh factor, kept)."""
        return self._factor(*pinned_hessian(contacts, rattler, dim)) is not None

    def _factor(self, h: sp.csr_matrix, dofs: NDArray[np.intp]) -> Factor | None:
        """The factor of ``h`` (a pinned Hessian, its rows those of ``dofs``), kept; None when
        ``h`` is not positive definite."""
        factor = self._cholesky(h, dofs)
        if factor is not None:
            self._kept = dofs, factor
        return factor

    def _cholesky(self, h: sp.csr_matrix, dofs: NDArray[np.intp]) -> Factor | None:
        """A factor of ``h`` (its rows those of ``dofs``) in the kept rank, or None when ``h``
        is not positive definite."""
        return supernodal_cholesky(h, row_order(self._rank, dofs, self._dim))

    def _near(self, dofs: NDArray[np.intp]) -> Factor | None:
        """The kept factor where it is of a pinned Hessian on the rows ``dofs``, else None."""
        if self._kept is None or not np.array_equal(self._kept[0], dofs):
            return None
        return self._kept[1]


def _clear(
    pairs: NearPairs, hi: NDArray[np.float64], lo: NDArray[np.float64], radii: NDArray[np.float64]
) -> bool | None:
    """A trial whose network came apart (its tensile contacts parted, and the particles left
    with too few contacts cascaded into rattlers): False (unjammed) when every particle that
    still overlaps a neighbour moves to a place clear of all of them (:func:`free_rattlers`,
    ``hi + lo`` updated), none by more than :data:`BLOCKED_MOVE` mean diameters: a state
    without overlaps, so without load, lies a small move away. None (no verdict: the packing
    rearranges) when some bear load, or clear only farther away."""
    start = hi.copy(), lo.copy()
    try:
        _, squeezed = free_rattlers(pairs, hi, lo, np.ones(hi.shape[0], dtype=bool), radii)
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


@dataclass(frozen=True, eq=False)
class _Landing:
    """Where a rearrangement lands (:func:`_landing`): the packing relaxed in float64, its near
    pairs (with their stiffness), the network it starts the trial from (bonds, rattlers), and
    the trial of that network at the relaxed radii (:func:`_trial`'s verdict, bonds, rattlers
    and instabilities held) with its positions ``hi + lo``."""

    relaxed: Packing
    pairs: NearPairs
    bonds: NDArray[np.bool_]
    rattler: NDArray[np.bool_]
    trial: tuple[bool | None, NDArray[np.bool_], NDArray[np.bool_], int]
    hi: NDArray[np.float64]
    lo: NDArray[np.float64]


def _landing(start: Packing, model: ContactModel, phi: float, kept: _KeptFactor) -> _Landing | None:
    """A rearrangement from ``start`` at ``phi`` relaxed in float64 (:func:`_rearranged`) and its
    network balanced in double-double (:func:`_trial`): None when the relaxed packing is
    unjammed. Raises :class:`ConvergenceError` when the relaxation finds no minimum or the trial
    gives no verdict. Where a rearrangement ends within float64's resolution of its new jamming
    point, its float64 minimum balances the forces only to the round-off floor, above the
    smallest of them: which contacts bear load is undecided there, the relaxation may stop at a
    saddle held by pairs that touch with no force, and the network may come apart in
    double-double (``docs/decisions.md``, "A rearrangement that lands at its own jamming
    point"); the march then lands the rearrangement :data:`START_EPSILON` higher, where float64
    resolves it as it resolves the march's start."""
    relaxed = _rearranged(start, model, phi)
    if relaxed is None:
        return None
    moved = NearPairs(relaxed, model, GAP_REACH)
    hi, lo = relaxed.positions.copy(), np.zeros_like(relaxed.positions)
    sums = moved.sums(hi, lo)
    _, rattler = contact_network(moved, hi, sums)
    bonds = ~(rattler[moved.first] | rattler[moved.second]) & (sums.overlap[0] > 0.0)
    full = moved.stiffness.copy()
    trial = _trial(moved, full, hi, lo, start.radii, bonds, rattler, kept)
    moved.stiffness = full
    if trial[0] is None:
        raise ConvergenceError(
            f"certify: at phi = {phi:.15f} the network gives way, and the network of the packing "
            "relaxed there does not balance"
        )
    return _Landing(relaxed, moved, bonds, rattler, trial, hi, lo)


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
        senses = (1.0,) if pair_rates(pairs, hi, mode, np.array([worst]))[0] > 0.0 else (-1.0,)
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
    carry_rattlers(pairs, step, rattler)
    displace(hi, lo, step)
    return best[1]


def _trial(
    pairs: NearPairs,
    stiffness: NDArray[np.float64],
    hi: NDArray[np.float64],
    lo: NDArray[np.float64],
    radii: NDArray[np.float64],
    bonds: NDArray[np.bool_],
    rattler: NDArray[np.bool_],
    kept: _KeptFactor,
    *,
    escape: bool = False,
) -> tuple[bool | None, NDArray[np.bool_], NDArray[np.bool_], int]:
    """Balance the network ``bonds`` at ``radii`` from ``hi + lo`` (updated in place), the
    rattlers' pairs without force: whether it is jammed (None: Newton did not converge in
    :data:`TRIAL_ITERATIONS`, or its correction could not be solved: never a verdict), its bonds,
    its rattlers (a particle left with fewer than ``d + 1`` bonds by shed contacts joins them)
    and how often its network gave way and a closing gap held it (:func:`_blocking_pair`).
    With ``escape``, it stops (no verdict) once it has moved along the first unstable mode:
    where a rearrangement starts, below float64's resolution. Once its Hessian is not positive
    definite, it looks for the unstable mode first (a shifted factorization that cannot fail)
    until a Newton step is solved again: a failed CHOLMOD factorization costs its time and
    keeps its memory (:func:`~athermal.linalg.cholesky`)."""
    n, dim = hi.shape
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    pairs.stiffness = np.where(live, stiffness, 0.0)
    sums = pairs.sums(hi, lo, radii, bonds)
    parted: NDArray[np.bool_] | None = None  # the bonds that parted last, until a solve
    definite, held = False, 0  # definite: the last factor was of the network as it is
    stable = True  # the last factorization did not fail
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
                if not definite and not kept.definite(contacts, rattler, dim):
                    return None, bonds, rattler, held  # balanced on a saddle: no verdict
                pairs.stiffness = stiffness
                try:
                    free, squeezed = free_rattlers(pairs, hi, lo, rattler, radii)
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
        mode = None if stable else kept.unstable_mode(contacts, rattler, hi.shape)
        if mode is None:
            y, residual, solver = kept.solve(contacts, rattler, force)
            if residual == np.inf:  # not positive definite: unstable, or singular
                if stable:  # else its unstable mode was sought above, and there is none
                    mode = kept.unstable_mode(contacts, rattler, hi.shape)
                if mode is None:  # singular, consistent
                    y, residual, solver = pinned_solve(contacts, rattler, force, cholmod=False)
                stable = False
            else:
                stable = True
        if mode is not None:
            blocking = _blocking_pair(pairs, hi, lo, mode, rattler, bonds, overlap, parted)
            if blocking is None or escape:  # it gives way further than a small move
                return None, bonds, rattler, held
            held, parted, definite = held + 1, None, False
            bonds = bonds.copy()
            bonds[blocking] = True
            sums = pairs.sums(hi, lo, radii, bonds)
            continue
        if not np.all(np.isfinite(y)) or residual > 1e-6:
            return None, bonds, rattler, held
        parted, definite = None, solver == "cholmod"
        step = -y.reshape(n, dim)
        carry_rattlers(pairs, step, rattler)
        displace(hi, lo, step)
        sums = pairs.sums(hi, lo, radii, bonds)
    return None, bonds, rattler, held
