"""Athermal quasi-static (AQS) shear with its plastic events located exactly.

A relaxed packing under a slowly increasing strain follows a branch of local minima until the
branch ends and the packing falls into another minimum: a plastic event, with its drop of
energy and (usually) of stress. Generically the branch ends in a saddle-node bifurcation: the
lowest nonzero eigenvalue of the Hessian vanishes as ``lambda_min ~ (gamma_c - gamma)^(1/2)``
(Maloney & Lemaitre, PRE 74, 016118, 2006) and the minimum merges with a saddle; with harmonic
contacts it mostly ends where a contact opens and the Hessian loses that contact's stiffness at
once. :func:`plastic_events` follows the branches and locates each end in strain to a tolerance
``tol`` (default :data:`EVENT_TOL`), whatever the step:

* a state is on the branch of the previous one when the packing, taken back to the previous
  strain and relaxed, returns to the previous minimum (:data:`SAME_STATE`): a state past the end
  returns elsewhere (another basin), one before it to the same minimum; a state that stayed
  where the previous minimum, strained, was is on the branch without that return;
* between events the strain step grows (x :data:`GROWTH`, up to ``max_step``; by default only
  where a contact's opening can end a branch, :data:`LONGEST`) and is held below
  the end of the branch extrapolated from ``lambda_min^2``, linear in ``gamma_c - gamma`` near
  it; an event is bracketed by a state on the branch and one off it;
* with Hooke's law a branch can also end where a contact opens (the Hessian loses the contact's
  stiffness at once, with no eigenvalue falling toward it), and an event whose hysteresis loop
  lies within one step would pass the return test: the branch ends and comes back inside the
  step. So a step over which a contact of the network opened is narrowed like an event, until
  the opening is crossed by a step no wider than ``tol``: every loop wider than ``tol`` is
  seen (``docs/decisions.md``, "Events a long step misses"). An opening whose contact's removal
  leaves the Hessian positive definite cannot end the branch (``k b^T H^-1 b < 1`` at zero
  force, :meth:`~athermal.analysis.network.NetworkHessian.removal`, extrapolated to the opening
  from the states short of it) and is crossed without narrowing;
* the bracket shrinks by trials short of the predicted end (``lambda_min^2`` extrapolated to
  zero, or the next contact to open, its overlap extrapolated from the states before) and then
  just past it, or by bisection where no end is predicted inside it or the predictions fail,
  until it is narrower than ``tol``; the state past the end is then one reached from within
  the bracket.

Each event reports its strains (the last on the branch, the first off it, the extrapolated
critical strain), the driven stress and energy just before and just after, the lowest
eigenvalue and its mode (the critical mode) before, how many particles moved (participation
number of the displacement), the largest displacement, and the contacts made and broken.
Relaxations are the protocols' (:class:`~athermal.relaxation.Relaxer`, each checked to be a
minimum), to the round-off floor; modes as :func:`~athermal.protocols.shear.shear_steps`.
:func:`cyclic_shear` shears back and forth to a limit cycle.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from .._portable import coarse
from .._records import Value, as_row
from .._validate import positive_scalar
from ..analysis.moduli import nonrattler_contacts
from ..analysis.network import NetworkHessian
from ..errors import ConvergenceError, InputError
from ..model.contact import ContactModel, Contacts
from ..model.objective import Objective
from ..model.packing import Packing
from ..relaxation import Minimizer, Relaxer, force_tolerance
from .shear import Layers, ShearMode, check_mode, rough_walls, step_stress, strained

EVENT_TOL = 1e-9
"""Default width in strain of the bracket that locates an event."""
SAME_STATE = 1e-6
"""Two relaxed states are one minimum when no non-rattler lies farther from its place in the
other than this x the mean diameter (far above what relaxations of one basin differ by, far
below what an event moves: ``docs/decisions.md``, "Plastic events")."""
GROWTH = 2.0
"""Factor by which the strain step grows after a step that stayed on the branch."""
LONGEST = 10.0
"""The largest strain step by default, x the first step, where a contact's opening can end a
branch (:func:`opens_at_once`: every loop wider than ``tol`` is seen whatever the step); else
the step does not grow by default (``docs/decisions.md``, "Events a long step misses")."""
APPROACH = 0.5
"""Between events a step goes at most this fraction of the way to the extrapolated end of the
branch."""
MAX_TRIALS = 100
"""Trials at most to locate one event, or one opening of a contact, without progress."""
NETWORKS = 4
"""The network Hessians (and their factors) kept: of the last states, where the openings ahead
are tested (:meth:`_Shear.removal`)."""
STALE = 4.0
"""The state past the end of a branch is reached again from the bracket's lower end once the
bracket is this many times narrower than the step that reached it: a long step's relaxation may
leave the branch's basin while the branch goes on, and a bisection toward such a state would
narrow the bracket to ``tol`` around no event."""


@dataclass(frozen=True, eq=False)
class BranchState:
    """A relaxed minimum at ``strain``: its packing, driven stress ``tau``, energy, pressure,
    the lowest nonzero eigenvalue of its Hessian (rattlers out, translations skipped; to 24
    significant bits, :func:`~athermal._portable.coarse`) and that mode ``(N, d)`` (unit, zero
    on rattlers), the rattlers, the contacts of the others (pairs
    and walls: the contact network), and the relaxations' iterations."""

    strain: float
    packing: Packing = field(repr=False)
    tau: float
    energy: float
    pressure: float
    lowest_eigenvalue: float
    mode: NDArray[np.float64] = field(repr=False)
    rattler: NDArray[np.bool_] = field(repr=False)
    contacts: Contacts = field(repr=False)
    iterations: int = 0

    def row(self) -> dict[str, Value]:
        """The state's numbers (no packing, mode, rattlers or contacts)."""
        return as_row(self)


@dataclass(frozen=True, eq=False)
class PlasticEvent:
    """One plastic event: the end of a branch of minima and where the packing fell.

    ``strain`` is the last strain on the branch and ``strain_after`` the first off it
    (``strain_after - strain <= tol``); ``critical_strain`` the end extrapolated from
    ``lambda_min^2``, linear in ``gamma_c - gamma`` (NaN when the eigenvalue did not fall);
    ``before`` and ``after`` the relaxed states there; ``moved`` the participation number
    ``(sum |u_i|^2)^2 / sum |u_i|^4`` of the displacement ``u`` from ``before`` (taken to
    ``strain_after``) to ``after`` over the particles that are no rattler in either, and
    ``max_displacement`` its largest ``|u_i|`` in mean diameters; ``contacts_made`` and
    ``contacts_broken`` between those particles; ``trials`` the relaxations that located it.
    """

    index: int
    strain: float
    strain_after: float
    critical_strain: float
    moved: float
    max_displacement: float
    contacts_made: int
    contacts_broken: int
    trials: int
    before: BranchState = field(repr=False)
    after: BranchState = field(repr=False)

    @property
    def saddle_node(self) -> bool:
        """Whether the branch ended in a saddle-node: ``lambda_min^2`` fell to zero within the
        bracket (within a bracket's width past it). Else the Hessian lost its stability at once,
        as where a harmonic contact opens and its stiffness vanishes (``docs/decisions.md``,
        "Plastic events")."""
        width = abs(self.strain_after - self.strain)
        return bool(abs(self.critical_strain - self.strain) <= 2.0 * width)

    @property
    def stress_drop(self) -> float:
        """``tau`` before minus ``tau`` after."""
        return self.before.tau - self.after.tau

    @property
    def energy_drop(self) -> float:
        """The energy before minus the energy after."""
        return self.before.energy - self.after.energy

    def row(self) -> dict[str, Value]:
        """The event's numbers, for tables and JSON."""
        return {
            **as_row(self),
            "tau_before": self.before.tau,
            "tau_after": self.after.tau,
            "stress_drop": self.stress_drop,
            "energy_before": self.before.energy,
            "energy_after": self.after.energy,
            "energy_drop": self.energy_drop,
            "lowest_eigenvalue_before": self.before.lowest_eigenvalue,
            "saddle_node": int(self.saddle_node),
        }


def soft_mode(
    packing: Packing, model: ContactModel, frozen: NDArray[np.bool_] | None = None
) -> tuple[float, NDArray[np.float64], NDArray[np.bool_]]:
    """The lowest nonzero eigenvalue of the Hessian of ``packing``'s non-rattlers (the
    translations along its periodic axes skipped; with ``frozen``, those particles held), its
    unit mode ``(N, d)`` (zero on rattlers, the sign fixed by its largest component) and the
    rattler mask ``(N,)``; infinity and a zero mode when every particle is a rattler
    (:meth:`~athermal.analysis.network.NetworkHessian.soft_mode`)."""
    contacts, rattler = nonrattler_contacts(packing, model, frozen)
    value, mode = NetworkHessian(packing, contacts, rattler, frozen).soft_mode()
    return value, mode, rattler


@dataclass(frozen=True, eq=False)
class Checkpoint:
    """Where an interrupted run goes on from: the relaxed ``packing`` at ``strain`` (the state
    just after an event, or a cycle's end), the ``events`` found before it, and in cyclic shear
    the packings at the ends of the cycles done, the start's first (``ends``; the last is
    ``packing``)."""

    packing: Packing = field(repr=False)
    strain: float
    events: int
    ends: tuple[Packing, ...] = field(default=(), repr=False)


class _Shear:
    """One AQS run: its model, mode, rough walls, minimizer and sameness threshold, and the
    relaxations and events counted so far."""

    def __init__(
        self,
        model: ContactModel,
        mode: ShearMode,
        layers: Layers | None,
        minimizer: Minimizer | None = None,
        same: float = SAME_STATE,
    ) -> None:
        self.model, self.mode, self.layers = model, mode, layers
        self.minimizer = minimizer or Minimizer()
        self.same_state = positive_scalar(same, "same")
        self.frozen = None if layers is None else layers[0] | layers[1]
        self.openings = opens_at_once(model)
        self.relaxations = 0
        self.events = 0
        self._networks: dict[int, tuple[BranchState, NetworkHessian]] = {}
        """The network Hessians of the last :data:`NETWORKS` states, by the states' ids (each
        kept with its state, so that the id is not reused)."""

    @classmethod
    def of(
        cls,
        start: Packing,
        model: ContactModel,
        mode: ShearMode,
        strain: float,
        minimizer: Minimizer | None,
        wall_layer: float | None,
        same: float,
    ) -> _Shear:
        """The run of ``mode`` from ``start`` up to ``strain`` after the mode's checks
        (:func:`~athermal.protocols.shear.check_mode`), with its rough walls in plane shear."""
        check_mode(mode, strain, start.cell, wall_layer)
        layers = rough_walls(start, wall_layer) if mode == "plane" else None
        return cls(model, mode, layers, minimizer, same)

    def first(self, start: Packing, strain: float) -> BranchState:
        """``start`` (at ``strain``) relaxed: the first state."""
        relaxed, iterations = self.relax(start, strain)
        return self.state(relaxed, strain, iterations)

    def relax(self, packing: Packing, strain: float) -> tuple[Packing, int]:
        """``packing`` relaxed to a minimum (the protocols' relaxation) at the round-off floor,
        and its iterations: near the end of a branch the minimum is ill-conditioned, and a state
        relaxed to a force ``f`` lies ``f / lambda_min`` from it along the soft mode."""
        objective = Objective(packing, self.model, frozen=self.frozen)
        result, _ = Relaxer(objective, self.minimizer).relax_to_minimum(
            objective.x0,
            gtol=force_tolerance(packing, self.model, 0.0),
            what=f"AQS state at strain {strain:.12g}",
        )
        self.relaxations += 1
        return result.packing, result.iterations

    def state(self, packing: Packing, strain: float, iterations: int = 0) -> BranchState:
        """The :class:`BranchState` of the relaxed ``packing`` at ``strain``."""
        obs, tau = step_stress(packing, self.model, self.mode, self.layers)
        contacts, rattler = nonrattler_contacts(packing, self.model, self.frozen)
        network = NetworkHessian(packing, contacts, rattler, self.frozen)
        value, mode = network.soft_mode()
        state = BranchState(
            strain,
            packing,
            tau,
            obs.energy,
            obs.pressure,
            coarse(value),  # it sets the steps: the same on every machine
            mode,
            rattler,
            contacts,
            iterations,
        )
        self._networks[id(state)] = (state, network)
        while len(self._networks) > NETWORKS:
            del self._networks[next(iter(self._networks))]
        return state

    def network(self, state: BranchState) -> NetworkHessian:
        """The Hessian of ``state``'s network (kept for the last :data:`NETWORKS` states,
        built again for an earlier one)."""
        kept = self._networks.get(id(state))
        if kept is not None and kept[0] is state:
            return kept[1]
        return NetworkHessian(state.packing, state.contacts, state.rattler, self.frozen)

    def advance(self, base: BranchState, strain: float) -> tuple[BranchState, bool]:
        """The minimum reached from ``base`` strained to ``strain``, and whether it lies on
        ``base``'s branch: it stayed where ``base``'s minimum, strained, was (:meth:`same`: no
        other minimum lies that close), or strained back and relaxed it returns to ``base``
        (near the end of a branch the basin of ``base`` can be narrower than a relaxation's
        first steps, and the return alone fails). A ``base`` without a contact network
        (unjammed: every particle a rattler) has no branch: any state reached from it counts
        as on it (floppy AQS depends on the step)."""
        moved = strained(base.packing, self.mode, base.strain, strain, self.layers)
        forward, iterations = self.relax(moved, strain)
        if base.rattler.all():
            return self.state(forward, strain, iterations), True
        if self.same(forward, base, moved):
            return self.state(forward, strain, iterations), True
        back, more = self.relax(
            strained(forward, self.mode, strain, base.strain, self.layers), base.strain
        )
        return self.state(forward, strain, iterations + more), self.same(back, base)

    def tracked(self, state: BranchState) -> Contacts:
        """The contacts of ``state``'s network whose opening changes the Hessian of the free
        particles: all but those between two held particles and held particles' wall
        contacts."""
        if self.frozen is None:
            return state.contacts
        held = self.frozen
        kept = state.contacts.subset(~(held[state.contacts.i] & held[state.contacts.j]))
        if kept.walls is None:
            return kept
        return replace(kept, walls=kept.walls.subset(~held[kept.walls.particle]))

    def crossing(
        self,
        lo: BranchState,
        hi: BranchState,
        below: BranchState | None = None,
        cleared: Key | None = None,
    ) -> tuple[float, Key] | None:
        """Where the first contact of ``lo``'s network that is open in ``hi`` (a state on the
        same branch) opened, and that contact (:func:`_key`): extrapolated from ``below`` and
        ``lo`` (:meth:`opening`) where that falls between ``lo`` and ``hi``, else its overlap
        interpolated linearly between ``lo`` and ``hi`` (an overlap's slope changes where
        another contact opens, so the states on one side predict it better); None when none
        is open but the one ``cleared`` (its opening cannot end the branch), or when an
        opening cannot end a branch at once (the law's stiffness vanishes at zero overlap: its
        Hessian is continuous there)."""
        if not self.openings:
            return None
        tracked = self.tracked(lo)
        at, after = tracked.overlaps_in(lo.packing), tracked.overlaps_in(hi.packing)
        opened = np.array(
            [c for c in np.flatnonzero(after <= 0.0).tolist() if _key(tracked, c) != cleared],
            dtype=np.intp,
        )
        if not opened.size:
            return None
        width = hi.strain - lo.strain
        fraction = at[opened] / (at[opened] - after[opened])
        if below is not None:
            ahead = _ahead(tracked, at, below.packing)[opened] * (lo.strain - below.strain) / width
            fraction = np.where(ahead <= 1.0, ahead, fraction)
        first = int(np.argmin(fraction))
        return lo.strain + float(fraction[first]) * width, _key(tracked, int(opened[first]))

    def removal(self, state: BranchState, key: Key) -> float:
        """``k b^T H^-1 b`` at ``state`` for its network's contact ``key``
        (:meth:`~athermal.analysis.network.NetworkHessian.removal`, to 24 significant bits: it
        decides the path), infinity where ``state`` lacks it."""
        which = _index(state.contacts, key)
        if which is None:
            return float("inf")
        return coarse(self.network(state).removal(which))

    def opening(self, lo: BranchState, below: BranchState | None) -> float | None:
        """Where the first contact of ``lo``'s network opens ahead of ``lo``, its overlap
        extrapolated linearly from ``below`` (a state before ``lo`` on its branch) and ``lo``;
        None when no overlap falls, without ``below``, or when an opening cannot end a branch
        at once (:meth:`crossing`)."""
        if not self.openings or below is None:
            return None
        tracked = self.tracked(lo)
        ahead = _ahead(tracked, tracked.overlaps_in(lo.packing), below.packing)
        if not np.isfinite(ahead).any():
            return None
        return lo.strain + float(np.min(ahead)) * (lo.strain - below.strain)

    def same(self, packing: Packing, base: BranchState, where: Packing | None = None) -> bool:
        """Whether ``packing`` is ``base``'s minimum (:data:`SAME_STATE`): its particles that are
        no rattlers in ``base`` in their places (``where``: ``base``'s packing, or it strained
        to ``packing``'s strain), or all of them where ``base`` has no contact network
        (unjammed)."""
        live = ~base.rattler if (~base.rattler).any() else np.ones(base.packing.n, dtype=bool)
        delta = self.displacement(base.packing if where is None else where, packing, live)
        diameter = 2.0 * float(np.mean(base.packing.radii))
        limit = self.same_state * diameter
        return bool(np.max(np.linalg.norm(delta, axis=1), initial=0.0) <= limit)

    def displacement(
        self, old: Packing, new: Packing, live: NDArray[np.bool_]
    ) -> NDArray[np.float64]:
        """The displacement ``(N', d)`` of the particles of ``live`` from ``old`` to ``new``
        (one cell, minimum image), without its mean along the periodic axes when nothing is held:
        a translation of the particles that are no rattlers costs no energy (a rattler that
        touches them takes up the difference), so it is no change of minimum."""
        delta = old.cell.minimum_image(new.positions[live] - old.positions[live])
        if self.frozen is None and delta.size:
            axes = [a for a in range(old.dim) if a not in old.cell.walls]
            delta[:, axes] -= delta[:, axes].mean(axis=0)
        return delta


def _end_of_branch(states: list[BranchState], direction: float = 1.0) -> float:
    """The strain where ``lambda_min^2`` reaches zero ahead of the last of ``states`` (one branch,
    strained in ``direction``, +1 or -1): the root of the parabola through the last three
    states, or of the line through the last two when the parabola has none; NaN unless the
    eigenvalue fell toward it."""
    if len(states) < 2:
        return float("nan")
    a, b = states[-2], states[-1]
    if not all(np.isfinite(s.lowest_eigenvalue) for s in states[-3:]):
        return float("nan")
    fall = a.lowest_eigenvalue**2 - b.lowest_eigenvalue**2
    ahead = direction * (b.strain - a.strain)
    if not (fall > 0.0 and ahead > 0.0 and b.lowest_eigenvalue > 0.0):
        return float("nan")
    line = b.lowest_eigenvalue**2 * ahead / fall
    if len(states) >= 3:
        u = np.array([direction * (s.strain - b.strain) for s in states[-3:]])
        y = np.array([s.lowest_eigenvalue**2 for s in states[-3:]])
        roots = np.roots(np.polyfit(u, y, 2))
        real = [r.real for r in roots if abs(r.imag) <= 1e-12 * abs(r.real) and r.real > 0.0]
        line = min(real) if real else line
    return b.strain + direction * coarse(line)  # LAPACK's fit: the same on every machine


Key = tuple[int, int, int]
"""A contact by its particles: ``(0, i, j)`` with ``i < j`` for a pair, ``(1, particle, 2 axis +
(1 at the lower wall))`` for a wall contact."""


def _key(contacts: Contacts, which: int) -> Key:
    """The :data:`Key` of ``contacts``' contact ``which`` (pairs, then wall contacts)."""
    pairs = contacts.i.size
    if which < pairs:
        i, j = int(contacts.i[which]), int(contacts.j[which])
        return (0, min(i, j), max(i, j))
    assert contacts.walls is not None
    wall = which - pairs
    lower = int(contacts.walls.side[wall] > 0.0)
    return (1, int(contacts.walls.particle[wall]), 2 * int(contacts.walls.axis[wall]) + lower)


def _index(contacts: Contacts, key: Key) -> int | None:
    """Where the contact ``key`` is among ``contacts`` (pairs, then wall contacts), or None."""
    kind, a, b = key
    if kind == 0:
        low, high = np.minimum(contacts.i, contacts.j), np.maximum(contacts.i, contacts.j)
        found = np.flatnonzero((low == a) & (high == b))
        return int(found[0]) if found.size else None
    if contacts.walls is None:
        return None
    walls = contacts.walls
    code = 2 * walls.axis + (walls.side > 0.0)
    found = np.flatnonzero((walls.particle == a) & (code == b))
    return contacts.i.size + int(found[0]) if found.size else None


def _ahead(contacts: Contacts, at: NDArray[np.float64], below: Packing) -> NDArray[np.float64]:
    """For each of ``contacts``, whose overlaps are ``at`` now, how many steps from ``below``
    (the packing a step before) ahead its overlap reaches zero, extrapolated linearly;
    infinity where it does not fall."""
    before = contacts.overlaps_in(below)
    falling = before > at
    ahead = np.full(at.size, np.inf)
    ahead[falling] = at[falling] / (before[falling] - at[falling])
    return ahead


def opens_at_once(model: ContactModel) -> bool:
    """Whether a contact that opens takes its stiffness from the Hessian at once (a law with
    stiffness at zero overlap, as Hooke's): a branch can then end where a contact opens, with
    no eigenvalue falling toward it."""
    return bool(model.law.stiffness(np.zeros(1), 1.0)[0] > 0.0)


def default_max_step(step: float, grows: bool) -> float:
    """The largest step when none is given: :data:`LONGEST` x ``step`` where the step
    ``grows`` (:func:`opens_at_once`), else ``step``."""
    return LONGEST * step if grows else step


def check_steps(
    step: float, max_step: float | None, tol: float, strain: float, grows: bool = True
) -> float:
    """``max_step`` (default :data:`LONGEST` x ``step`` if ``grows``, else ``step``; at most
    ``strain``) after the settings' checks: ``tol < step <= max_step <= strain``, each > 0."""
    step = positive_scalar(step, "step")
    tol = positive_scalar(tol, "tol")
    longest = default_max_step(step, grows)
    largest = min(longest, strain) if max_step is None else positive_scalar(max_step, "max_step")
    if not tol < step <= largest <= strain:
        raise InputError(
            f"step: need tol < step <= max_step <= strain, got {tol:g}, {step:g}, {largest:g}, "
            f"{strain:g}"
        )
    return largest


def plastic_events(
    start: Packing,
    model: ContactModel,
    *,
    mode: ShearMode = "simple",
    strain: float = 0.01,
    step: float = 1e-4,
    max_step: float | None = None,
    tol: float = EVENT_TOL,
    minimizer: Minimizer | None = None,
    wall_layer: float | None = None,
    same: float = SAME_STATE,
    checkpoint: Checkpoint | None = None,
) -> Iterator[BranchState | PlasticEvent]:
    """Shear ``start`` quasi-statically to ``strain`` and yield every branch state and every
    plastic event, each event located to ``tol`` in strain (module docstring); from a
    ``checkpoint``, the run goes on from there (its state, relaxed again, is not yielded).

    Parameters
    ----------
    start : a packing above jamming, relaxed first (the first state yielded, at strain 0).
    model : contact law.
    mode : ``"simple"`` (default), ``"pure"``, ``"uniaxial"`` or ``"plane"``
        (:func:`~athermal.protocols.shear.check_mode`).
    strain : the final strain.
    step : the first strain step, and the step after each event; it grows by :data:`GROWTH`
        up to ``max_step`` while the packing stays on its branch: by default to :data:`LONGEST`
        x ``step`` where a contact's opening can end a branch (:func:`opens_at_once`, Hooke's
        law), whose events do not depend on the step (a step over which a contact opened is
        narrowed to ``tol``, module docstring); else it does not grow, and an event whose
        hysteresis loop lies inside one step can be missed (``docs/decisions.md``, "Events a
        long step misses").
    tol : the largest bracket of an event, in strain.
    minimizer : how each state is relaxed (default L-BFGS), to the round-off floor
        (:func:`~athermal.relaxation.round_off_floor`).
    wall_layer : plane shear's rough walls (:func:`~athermal.protocols.shear.rough_walls`).
    same : two relaxed states are one minimum when no particle that is no rattler lies farther
        than this x the mean diameter from its place in the other (:data:`SAME_STATE`).
    checkpoint : where an interrupted run of the same settings from the same ``start`` goes on
        (the rough walls are still ``start``'s).
    """
    strain = positive_scalar(strain, "strain")
    largest = check_steps(step, max_step, tol, strain, opens_at_once(model))
    run = _Shear.of(start, model, mode, strain, minimizer, wall_layer, same)
    if checkpoint is None:
        first = run.first(start, 0.0)
        yield first
    else:
        first = run.first(checkpoint.packing, checkpoint.strain)
        run.events = checkpoint.events
    yield from _follow(run, [first], strain, step, largest, tol)


def _follow(
    run: _Shear,
    branch: list[BranchState],
    target: float,
    step: float,
    largest: float,
    tol: float,
) -> Iterator[BranchState | PlasticEvent]:
    """Follow the branches from the last of ``branch`` to the strain ``target``, yielding each
    state and event (the events numbered on from ``run.events``); the branch the path ends on
    is left in ``branch``."""
    direction = 1.0 if target > branch[-1].strain else -1.0
    del branch[:-1]  # the eigenvalue's trend is the leg's
    size = step
    while direction * (target - branch[-1].strain) > 0.0:
        base = branch[-1]
        ahead = min(size, direction * (target - base.strain))
        end = _end_of_branch(branch, direction)
        if direction * (end - base.strain) > 0.0:
            ahead = min(ahead, max(APPROACH * direction * (end - base.strain), tol))
        state, on = run.advance(base, base.strain + direction * ahead)
        opened = on and ahead > tol and run.crossing(base, state) is not None
        if on and not opened:
            branch.append(state)
            yield state
            size = min(GROWTH * size, largest)
            continue
        seen = len(branch)
        event = _locate(run, branch, state, tol, direction, opened)
        yield from branch[seen:]  # the states the search found on the branch
        size = step
        if event is None:  # no event: the branch went on through the bracket
            continue
        yield event
        branch[:] = [event.after]
        yield event.after


@dataclass(frozen=True, eq=False)
class _Above:
    """A state past a bracket's lower end: reached from the strain ``origin``, and either
    ``off`` the branch (strained back it returned elsewhere) or on it past an opened contact
    (``off`` False), where the branch may have ended and come back within the step."""

    state: BranchState
    origin: float
    off: bool


def _locate(
    run: _Shear,
    branch: list[BranchState],
    past: BranchState,
    tol: float,
    direction: float,
    opened: bool = False,
) -> PlasticEvent | None:
    """The event between the branch's last state and ``past``, a state past its end in
    ``direction`` (``opened``: a state on the branch past an opened contact, which may hide an
    event whose loop lies within the step), the states found on the branch appended to
    ``branch``; None when the branch goes on through ``past``.

    The bracket shrinks below ``tol`` toward the nearest of the states above it, by trials aimed
    at the predicted end (:func:`_trial`), bisection when the distance to their target did not
    halve in two trials. An opened contact is crossed by a step no wider than ``tol``: a branch
    that ends there and comes back within a wider step is seen by the return test; unless its
    opening cannot end the branch (:func:`_harmless`, one opening at a time). A state off the
    branch must be reached from within the bracket: one reached from farther (a long step's
    relaxation may leave the branch's basin while the branch goes on) is reached again from the
    bracket's lower end, once the bracket is :data:`STALE` times narrower than that step and
    when it is narrower than ``tol``."""
    start = run.relaxations
    lo = branch[-1]
    above = [_Above(past, lo.strain, not opened)]
    gaps: list[float] = []  # each trial's distance to its target, since the last progress
    predicted: float | None = None  # the last trial's predicted opening
    missed = False  # whether the last step across a predicted opening opened nothing
    trials = 0  # since the last progress: a state above left behind, or an opening crossed
    cleared: Key | None = None  # the contact whose opening, the next ahead of lo, cannot end
    # the branch (one: an opening changes the removals of the others)
    tested: dict[Key, tuple[float, float]] = {}  # each one's last strain tested and removal
    while trials < MAX_TRIALS:
        trials += 1
        if branch[-1] is not lo:  # an opening of another contact changes the removals
            cleared = None
        lo, top = branch[-1], above[-1]
        width = direction * (top.state.strain - lo.strain)
        reached = direction * (top.state.strain - top.origin)
        if top.off and _within(width, tol, lo.strain) and _within(reached, tol, lo.strain):
            event = _event(run, branch, top.state, run.events, run.relaxations - start, direction)
            run.events += 1
            return event
        below = branch[-2] if len(branch) > 1 else None
        if top.off:
            opens = run.opening(lo, below)
        else:
            found = run.crossing(lo, top.state, below, cleared)
            if found is None:  # no contact of lo's opens before it: it is on the branch
                branch.append(top.state)
                above.pop()
                gaps, trials = [], 0
                if not above:
                    return None
                continue
            opens, key = found
            if cleared is None and _harmless(run, lo, below, key, opens, direction, tested):
                cleared = key  # the next one is tested past this opening
                trials = 0
                continue
        shift = None if opens is None or predicted is None else abs(opens - predicted)
        ahead, kind, gap = _trial(branch, top, width, tol, direction, opens, shift)
        if (kind == "across" and missed) or (
            kind != "again" and len(gaps) >= 2 and gap > 0.5 * gaps[-2]
        ):
            ahead, kind, gap = 0.5 * width, "half", width  # the predictions fail: bisect
        gaps.append(gap)
        predicted = opens
        state, on = run.advance(lo, lo.strain + direction * ahead)
        if ahead == width:  # reached again from within the bracket
            above.pop()
            gaps, trials = [], 0
        opened = run.crossing(lo, state, cleared=cleared) is not None
        if on and (ahead <= tol or not opened):
            branch.append(state)
            missed = kind == "across" and not opened
            if kind == "across" and opened:  # progress: the next opening is the target
                gaps, trials, predicted = [], 0, None
            if not above:
                return None
        else:
            above.append(_Above(state, lo.strain, not on))
    raise ConvergenceError(
        f"plastic event after strain {branch[-1].strain:.12g}: not located to {tol:g} in "
        f"{MAX_TRIALS} trials"
    )


def _harmless(
    run: _Shear,
    lo: BranchState,
    below: BranchState | None,
    key: Key,
    opens: float,
    direction: float,
    tested: dict[Key, tuple[float, float]],
) -> bool:
    """Whether the contact ``key`` of ``lo``'s network, predicted to open at the strain
    ``opens``, cannot end the branch there: its removal (:meth:`_Shear.removal`) is below 1 at
    ``lo`` and extrapolated to ``opens`` from the last state where it was evaluated
    (``tested``, updated), or else from ``below`` (the state before ``lo`` on its branch),
    linearly, no farther ahead than the two states lie apart, and only where it rises. Between
    the two states and the opening no contact of the network opens (``key`` opens first), so
    the removal changes smoothly there, or falls where a contact closes."""
    previous = tested.get(key)
    if previous is not None and previous[0] == lo.strain:
        return False
    value = run.removal(lo, key)
    tested[key] = (lo.strain, value)
    if not value < 1.0:
        return False
    if previous is None and below is not None:  # only where it matters: a factor at below
        previous = (below.strain, run.removal(below, key))
    if previous is None or not np.isfinite(previous[1]):
        return False
    strain, before = previous
    span, left = direction * (lo.strain - strain), direction * (opens - lo.strain)
    if not 0.0 <= left <= span:
        return False
    return value + max(value - before, 0.0) * left / span < 1.0


def _trial(
    branch: list[BranchState],
    top: _Above,
    width: float,
    tol: float,
    direction: float,
    opens: float | None,
    shift: float | None = None,
) -> tuple[float, str, float]:
    """How far past the branch's last state to try toward ``top``, ``width`` ahead, the kind
    of trial and the distance to its target: all the way (``"again"``) when ``top`` is off the
    branch and must be reached again from the bracket (:data:`STALE`); else short of the nearer
    of the predicted ends inside the bracket (``"aim"``), ``lambda_min^2`` extrapolated to zero
    (short by a tenth of the way, or just past it within ``tol``) and the next contact to open
    (``opens``, :meth:`_Shear.opening` or :meth:`_Shear.crossing`; short by ``0.4 tol``, and
    where ``top`` is off the branch by a tenth of the way or, when the prediction moved by
    ``shift`` since the last trial, twice that if less; or across it by a step of ``tol``:
    ``"across"``); halfway (``"half"``) when neither lies inside."""
    lo = branch[-1]
    if top.off and (
        _within(width, tol, lo.strain)
        or direction * (top.state.strain - top.origin) > STALE * width
    ):
        return width, "again", width
    aims = []
    end = direction * (_end_of_branch(branch, direction) - lo.strain)
    if 0.0 < end < width:
        ahead = end - max(0.1 * end, 0.3 * tol) if end > tol else end + 0.4 * tol
        aims.append((min(max(ahead, 0.1 * tol), width - 0.1 * tol), "aim", end))
    if opens is not None and 0.0 <= direction * (opens - lo.strain) < width:
        target = direction * (opens - lo.strain)
        short = 0.0
        if top.off:
            short = 0.1 * target if shift is None else min(0.1 * target, 2.0 * shift)
        ahead = target - max(short, 0.4 * tol)
        aims.append(
            (ahead, "aim", target) if ahead > 0.1 * tol else (min(tol, width), "across", target)
        )
    return min(aims) if aims else (0.5 * width, "half", width)


def _within(width: float, tol: float, strain: float) -> bool:
    """Whether a bracket ``width`` wide near ``strain`` is no wider than ``tol``, up to the
    rounding of the strains (a few units in the last place of ``strain``)."""
    return width <= tol + 4.0 * float(np.spacing(abs(strain)))


def _event(
    run: _Shear,
    branch: list[BranchState],
    off: BranchState,
    index: int,
    trials: int,
    direction: float,
) -> PlasticEvent:
    """The :class:`PlasticEvent` from the branch's last state to ``off``."""
    before = branch[-1]
    moved_to = strained(before.packing, run.mode, before.strain, off.strain, run.layers)
    live = ~(before.rattler | off.rattler)
    u = run.displacement(moved_to, off.packing, live)
    squares = np.einsum("ij,ij->i", u, u)
    moved = float(squares.sum() ** 2 / np.sum(squares**2)) if squares.any() else 0.0
    diameter = 2.0 * float(np.mean(before.packing.radii))
    made, broken = _contact_changes(before, off, live)
    return PlasticEvent(
        index=index,
        strain=before.strain,
        strain_after=off.strain,
        critical_strain=_end_of_branch(branch, direction),
        moved=moved,
        max_displacement=float(np.sqrt(squares.max(initial=0.0))) / diameter,
        contacts_made=made,
        contacts_broken=broken,
        trials=trials,
        before=before,
        after=off,
    )


def _contact_changes(
    before: BranchState, after: BranchState, live: NDArray[np.bool_]
) -> tuple[int, int]:
    """Contacts between the particles of ``live`` made and broken from ``before`` to
    ``after``."""
    pairs = []
    for contacts in (before.contacts, after.contacts):
        keep = live[contacts.i] & live[contacts.j]
        pairs.append(set(zip(contacts.i[keep].tolist(), contacts.j[keep].tolist(), strict=True)))
    return len(pairs[1] - pairs[0]), len(pairs[0] - pairs[1])


@dataclass(frozen=True, eq=False)
class CycleEnd:
    """The state at the end of cycle ``cycle`` (1, 2, ...; back at strain 0), the events of
    that cycle, and ``repeats``: the smallest ``p`` such that this state is the end of cycle
    ``cycle - p`` (cycle 0: the start), the same minimum to :data:`SAME_STATE`, or None."""

    cycle: int
    state: BranchState = field(repr=False)
    events: int
    repeats: int | None

    def row(self) -> dict[str, Value]:
        """The cycle's numbers: its end's energy, stress and pressure, events and repeat."""
        return {
            "cycle": self.cycle,
            "energy": self.state.energy,
            "tau": self.state.tau,
            "pressure": self.state.pressure,
            "events": self.events,
            "repeats": -1 if self.repeats is None else self.repeats,
        }


@dataclass(frozen=True)
class LimitCycle:
    """What cyclic shear reached: a limit cycle (``reached``) entered at the end of cycle
    ``cycle`` (0: the start), of ``period`` cycles with ``events`` plastic events in one
    period; ``cycles`` the cycles run."""

    reached: bool
    cycle: int | None
    period: int | None
    events: int | None
    cycles: int

    def row(self) -> dict[str, bool | int | None]:
        """Its numbers for JSON: ``reached``, ``cycle``, ``period``, ``events_per_period``,
        ``cycles_run`` (None where no limit cycle was reached)."""
        return {
            "reached": self.reached,
            "cycle": self.cycle,
            "period": self.period,
            "events_per_period": self.events,
            "cycles_run": self.cycles,
        }


def check_cycles(amplitude: float, cycles: int) -> float:
    """``amplitude`` after the checks of a cyclic shear's settings (> 0, and ``cycles`` an
    integer >= 1)."""
    if int(cycles) != cycles or cycles < 1:
        raise InputError(f"cycles: must be an integer >= 1, got {cycles!r}")
    return positive_scalar(amplitude, "amplitude")


def cyclic_shear(
    start: Packing,
    model: ContactModel,
    *,
    amplitude: float,
    cycles: int,
    mode: ShearMode = "simple",
    step: float = 1e-4,
    max_step: float | None = None,
    tol: float = EVENT_TOL,
    minimizer: Minimizer | None = None,
    wall_layer: float | None = None,
    stop: bool = True,
    same: float = SAME_STATE,
    checkpoint: Checkpoint | None = None,
) -> Iterator[BranchState | PlasticEvent | CycleEnd]:
    """Shear ``start`` quasi-statically back and forth between strains ``+amplitude`` and
    ``-amplitude`` (each cycle 0 -> A -> -A -> 0), yielding every branch state and plastic
    event (located as :func:`plastic_events` does) and, after each cycle, its
    :class:`CycleEnd`. A cycle whose end is the end of an earlier cycle (the same minimum to
    ``same``, as :func:`plastic_events` compares states) closes a limit cycle
    (:func:`limit_cycle`); with ``stop`` the run ends there, else after ``cycles`` cycles.
    From a ``checkpoint`` (at a cycle's end) the run goes on with the next cycle, the ends
    before compared as ever (with ``stop``, not when the checkpoint's cycle closed a limit
    cycle)."""
    amplitude = check_cycles(amplitude, cycles)
    largest = check_steps(step, max_step, tol, amplitude, opens_at_once(model))
    run = _Shear.of(start, model, mode, amplitude, minimizer, wall_layer, same)
    if checkpoint is None:
        branch = [run.first(start, 0.0)]
        yield branch[0]
        ends = [branch[0]]
    else:
        ends = [run.state(packing, 0.0) for packing in checkpoint.ends[:-1]]
        branch = [run.first(checkpoint.packing, 0.0)]
        ends.append(branch[0])
        run.events = checkpoint.events
        if stop and _repeats(run, ends[-1], ends[:-1]) is not None:
            return  # the checkpoint's cycle closed the limit cycle: the run ended there
    for cycle in range(len(ends), int(cycles) + 1):
        before = run.events
        for target in (amplitude, -amplitude, 0.0):
            yield from _follow(run, branch, target, step, largest, tol)
        end = branch[-1]
        repeats = _repeats(run, end, ends)
        ends.append(end)
        yield CycleEnd(cycle, end, run.events - before, repeats)
        if stop and repeats is not None:
            return


def _repeats(run: _Shear, end: BranchState, earlier: Sequence[BranchState]) -> int | None:
    """How many cycles back ``end`` (a cycle's end) repeats one of the ``earlier`` ends (the
    same minimum, :meth:`_Shear.same`): the nearest, or None."""
    return next((p for p in range(1, len(earlier) + 1) if run.same(end.packing, earlier[-p])), None)


class Ended(Protocol):
    """What :func:`limit_cycle` reads of a cycle's end (a :class:`CycleEnd`, or its row read
    back)."""

    @property
    def cycle(self) -> int: ...
    @property
    def events(self) -> int: ...
    @property
    def repeats(self) -> int | None: ...


def limit_cycle(ends: Sequence[Ended]) -> LimitCycle:
    """The limit cycle of the first of ``ends`` (a cyclic shear's, in order) that repeats an
    earlier cycle's end: entered at the end of cycle ``cycle - repeats``, ``repeats`` cycles
    long, with the events of its last ``repeats`` cycles; not reached when none repeats."""
    for k, end in enumerate(ends):
        if end.repeats is not None:
            events = sum(e.events for e in ends[k - end.repeats + 1 : k + 1])
            return LimitCycle(True, end.cycle - end.repeats, end.repeats, events, len(ends))
    return LimitCycle(False, None, None, None, len(ends))
