"""Jamming by growth and bisection (the paper's Algorithm 1, and O'Hern et al. 2003).

**The scheme.** From a start packing at ``phi_init`` the radii grow by ``dphi`` (in packing
fraction) and the packing is relaxed, until a relaxed state is jammed. The jamming point is then
bisected. Two protocols differ in the configuration a bisection trial starts from:

- ``seed`` (the paper's Algorithm 1): every trial grows the last unjammed configuration
  ``C_ref`` (the relaxed state at ``phi_low``); a jammed verdict leaves ``C_ref`` as it is.
- ``ohern`` (O'Hern et al.'s compression and decompression of one configuration): every trial
  starts from the previous trial's relaxed configuration, jammed or not, so a trial below a
  jammed state decompresses that state's own basin.

The run ends only when the jammed packing at ``phi_high`` is the relaxation of the unjammed
configuration at ``phi_low``, grown by at most ``epsilon``: the paper's ``C_jam`` one ``epsilon``
above its ``C_ref``. When the bracket is that narrow but the jammed state came from another
configuration, the unjammed one is grown to ``phi_high`` (one more trial); if it stays unjammed,
the jammed bound belonged to another basin: the bracket reopens there and growth goes on from
the unjammed state with a small increment (``RESTART`` x ``epsilon``, doubled after every
unjammed step, at most ``dphi``), then bisection. The jammed trial that closes the bracket is
relaxed once more to force balance (``final``); if it unjams then, the bracket reopens the same
way. Radii are always ``r0 (phi / phi_init)^(1/d)`` from the start radii, every step builds its
own objective and preconditioner from its start configuration, and what a step does is a
function of the steps before it (:func:`_next_trial`): an interrupted run resumes bit for bit
(``resume``).

**The verdict does not depend on epsilon.** A trial relaxation ends in one of two states,
told apart by the configuration's own scales:

- *unjammed*: the energy per particle falls to :func:`energy_threshold`, the energy of a
  packing ``~RESOLUTION / 10`` above jamming (``RESOLUTION`` is the smallest ``epsilon``
  accepted);
- *jammed*: ``max_i |grad_i| <= rtol`` (1e-6) x the packing's own mean contact force, or the
  round-off floor (:func:`~athermal.relaxation.round_off_floor`) where that is larger,
  with a positive pressure. A relaxation that meets its tolerance relative to its start's
  forces, but not to its own (forces that fell on the way down, as an unjammed packing's do),
  relaxes on. An unjammed packing cannot balance its contact forces (it has no state of
  self-stress), so it reaches the energy threshold instead.

Neither the threshold nor the tolerance depends on ``epsilon``, so runs from the same start
with the same ``dphi`` and protocol follow the same trials until the coarser one stops: the
jamming point of a smaller ``epsilon`` lies inside the bracket of a larger one, unless a
bracket reopens (measured in ``docs/jamming.md``; after a reopening the growth increment is the
one step whose size depends on ``epsilon``). The ``final``
step relaxes to ``max_i |grad_i| <= final_rtol`` (1e-10) x the packing's own mean contact force,
or to the round-off floor where that is larger.

**Checked** (:func:`check_jammed`, run by :func:`jam`): decompressed by ``DECOMPRESSION`` x
``epsilon`` and relaxed the packing unjams; its contacts among non-rattlers are isostatic,
``N_c - N_iso`` in ``[0, ISOSTATIC_SLACK + ISOSTATIC_SPREAD N' Z_SLOPE sqrt(overlap) / 2]`` (a
packing ``Delta phi`` above jamming has on average ``N' (z - z_iso) / 2 ~ N' Z_SLOPE sqrt(Delta
phi) / 2`` extra contacts: 1 at N = 1024 and 5 at N = 4096 for ``Delta phi = 5e-7``, and single
packings scatter about that mean by as much as the mean itself); its mean overlap, expressed as a
distance in packing fraction ``d phi <delta / (r_i + r_j)>``, is at most ``OVERLAP_SLACK`` x
``epsilon``; and it is a local minimum (:func:`~athermal.analysis.moduli.stability`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._portable import power
from .._records import Value, as_row
from .._validate import choice, positive_scalar
from ..analysis.moduli import stability
from ..analysis.observables import (
    Observables,
    coordination,
    isostatic_contacts,
    measure,
    pressure,
    rattlers,
    stress,
)
from ..errors import ConvergenceError, InputError
from ..model.contact import ContactModel, Contacts, find_contacts
from ..model.objective import Objective
from ..model.packing import Packing
from ..relaxation import Minimizer, Relaxer, energy_scale, force_tolerance

JAMMING_MINIMIZER = Minimizer("lbfgs", "exp")
"""Default minimizer of the jamming protocol: P-L-BFGS, its Exp preconditioner factored
incompletely below N = 200,000 (the measurements that chose it: ``docs/jamming.md``)."""
JAMMING_SCHEME = 3
"""Version of the scheme (part of a run's identity: a trajectory of an older scheme is refused).
3: the verdict independent of ``epsilon``, and the protocol chosen (``seed`` or ``ohern``)."""
DPHI = 1e-3
"""Default growth increment of the packing fraction (the paper's ``delta phi``)."""
EPSILON = 1e-6
"""Default width of the bracket the bisection ends on (the paper's ``epsilon``)."""
JamProtocol = Literal["seed", "ohern"]
JAM_PROTOCOLS: tuple[JamProtocol, ...] = ("seed", "ohern")
"""The bisection protocols (module docstring): trials from the last unjammed configuration
(``seed``), or from the previous trial (``ohern``)."""
JAM_PROTOCOL: JamProtocol = "ohern"
"""The default protocol: its brackets nest over ``epsilon`` more often than ``seed``'s, it is
faster, and the two give the same mean ``phi_c`` (the measurements: ``docs/jamming.md``)."""
RESOLUTION = 1e-9
"""The smallest ``epsilon`` (packing fraction) the protocol accepts: the jamming threshold
(:func:`energy_threshold`) is the energy of a packing ``RESOLUTION / 10`` above jamming, whose
overlaps (~1e-13 of the cell's side at N = 10^5) are still resolved by float64 coordinates.
Packings that close to jamming balance their forces only to the round-off floor
(``docs/jamming.md``)."""
PHI_INIT = {2: 0.8, 3: 0.6}
"""Default start fraction by dimension: unjammed after relaxation (phi_c ~ 0.84 in 2D and
~0.64 in 3D for the bidisperse 1:1, 1.4 mixture)."""
PHI_INIT_WALLS = {2: 0.7, 3: 0.5}
"""Default start fraction between walls: the particles' centres keep a radius from a wall, so a
packing between walls jams at a lower phi than a periodic one, the lower the fewer particles
span the cell (measured below :data:`PHI_INIT` in 3D: ``docs/commands.md``, ``jam``)."""
JAMMED_PHI = {2: 0.9, 3: 0.7}
"""A packing fraction above jamming by dimension: the growth must have a step between it and
phi = 1 (:func:`check_growth`)."""
TRIAL_RTOL = 1e-6
"""Default force tolerance of the trial steps, relative to the mean contact force at a step's
start."""
FINAL_RTOL = 1e-10
"""Default force tolerance of the final step, relative to the packing's own mean contact force."""
RESTART = 4.0
"""First growth increment after the bracket reopens, in units of ``epsilon``."""
DECOMPRESSION = 3.0
""":func:`check_jammed` decompresses by this many ``epsilon``."""
ISOSTATIC_SLACK = 4
"""Contacts above isostatic, ``N_c - N_iso``, that :func:`check_jammed` accepts on top of those
the packing's own overlap implies (:func:`isostatic_allowance`)."""
ISOSTATIC_SPREAD = 2.0
""":func:`isostatic_allowance` accepts this many times the mean extra contacts of the overlap:
single packings scatter about the mean by about the mean (measured: ``docs/decisions.md``,
section "Protocol constants")."""
Z_SLOPE = {2: 3.5, 3: 7.7}
"""``z - z_iso ~ Z_SLOPE sqrt(Delta phi)`` above jamming, by dimension (the measured slopes, in
3D the largest: ``docs/decisions.md``, section "Protocol constants")."""
OVERLAP_SLACK = 2.0
"""Largest mean overlap, as a packing-fraction distance over ``epsilon``, that
:func:`check_jammed` accepts."""

Phase = Literal["start", "increment", "bisection", "final"]


def energy_threshold(dim: int, alpha: float) -> float:
    """The jamming threshold on ``E / N`` in units of ``k <r>^alpha``:
    ``(RESOLUTION / (10 d))^alpha``. A packing jammed by ``Delta phi`` has overlaps
    ``delta ~ <r> Delta phi / (d phi)`` and ``E / N ~ k <r>^alpha (Delta phi / (d phi))^alpha``,
    so states jammed by more than ~``RESOLUTION / 10`` lie above it."""
    return float(power(RESOLUTION / (10.0 * dim), alpha))


def start_fraction(dim: int, walls: bool) -> float:
    """The default start packing fraction in ``dim`` dimensions, periodic or between walls."""
    return (PHI_INIT_WALLS if walls else PHI_INIT)[dim]


def check_growth(phi_init: float, dphi: float, dim: int) -> None:
    """:class:`InputError` when growth by ``dphi`` from ``phi_init`` has no step between
    :data:`JAMMED_PHI` and phi = 1, where every packing of ``dim`` dimensions has jammed."""
    last = phi_init + (math.ceil((1.0 - phi_init) / dphi) - 1) * dphi  # the last below 1
    if last >= 1.0:  # (the quotient's round-off)
        last -= dphi
    if last < JAMMED_PHI[dim]:
        raise InputError(
            f"dphi: growth by {dphi:g} from phi {phi_init:g} has no step between "
            f"{JAMMED_PHI[dim]:g} (where packings have jammed) and 1; take a smaller increment"
        )


def check_epsilon(epsilon: float) -> float:
    """``epsilon`` if it is at least :data:`RESOLUTION`; :class:`InputError` otherwise."""
    epsilon = positive_scalar(epsilon, "epsilon")
    if epsilon < RESOLUTION:
        raise InputError(
            f"epsilon: must be >= {RESOLUTION:g} (the resolution of the jammed/unjammed "
            f"verdict), got {epsilon:g}"
        )
    return epsilon


@dataclass(frozen=True, eq=False)
class JammingStep:
    """One relaxation of the jamming protocol.

    ``phase`` is ``start`` (the start packing relaxed), ``increment``, ``bisection`` or
    ``final``; ``origin`` the index of the step whose relaxed packing this one started from
    (-1 for the start); ``saddles`` how many saddles the final relaxation left along their
    negative modes (it alone is checked to be a minimum); ``phi_low`` / ``phi_high`` bracket
    the jamming point after this step (``phi_high`` is ``inf`` while no jammed bound is known).
    ``packing`` is the relaxed configuration at ``phi`` (caller's particle order). Energy in
    ``k`` x length^alpha, pressure in energy / volume.
    """

    index: int
    phase: Phase
    origin: int
    phi: float
    jammed: bool
    energy: float
    pressure: float
    contacts: int
    iterations: int
    evaluations: int
    saddles: int
    seconds: float
    phi_low: float
    phi_high: float
    packing: Packing

    def row(self) -> dict[str, Value]:
        """The step's numbers (no packing), for tables and checkpoints."""
        return as_row(self)

    @property
    def bracket(self) -> float:
        """Width ``phi_high - phi_low`` of the bracket (``inf`` while it is open)."""
        return self.phi_high - self.phi_low


@dataclass(frozen=True)
class JammingCheck:
    """A referee's checks of a jammed packing (:func:`check_jammed`).

    Attributes
    ----------
    decompression : packing-fraction step of the decompression test (``DECOMPRESSION`` x
        ``epsilon``).
    decompressed_energy : ``E / N`` after decompressing and relaxing, in ``k <r>^alpha``.
    unjams : that energy is at most the jamming threshold (the packing unjams).
    excess_contacts : ``N_c - N_iso`` among the non-rattlers, ``N_iso = d N' - t + 1``
        (:func:`~athermal.analysis.observables.isostatic_contacts`, ``t`` the periodic axes: ``d``
        unless the cell has walls, whose contacts count in ``N_c``).
    allowed_excess : the most ``excess_contacts`` accepted (:func:`isostatic_allowance`).
    overlap_dphi : ``d phi <delta / (r_i + r_j)>``, the mean overlap as a distance in packing
        fraction (a packing jammed by ``Delta phi`` has about ``Delta phi`` or less).
    epsilon : the accuracy the packing was jammed to.
    stable : a local minimum (:func:`~athermal.analysis.moduli.stability`).
    """

    decompression: float
    decompressed_energy: float
    unjams: bool
    excess_contacts: int
    allowed_excess: float
    overlap_dphi: float
    epsilon: float
    stable: bool

    def problems(self) -> list[str]:
        """What failed, one phrase each (empty when every check passed)."""
        out = []
        if not self.unjams:
            out.append(
                f"still jammed when decompressed by {self.decompression:.1e} "
                f"(E/N = {self.decompressed_energy:.2e} k<r>^alpha)"
            )
        if not 0 <= self.excess_contacts <= self.allowed_excess:
            out.append(
                f"N_c - N_iso = {self.excess_contacts} (isostatic at this overlap: 0 ... "
                f"{self.allowed_excess:.1f})"
            )
        if self.overlap_dphi > OVERLAP_SLACK * self.epsilon:
            out.append(
                f"mean overlap of a packing {self.overlap_dphi:.1e} above jamming "
                f"(epsilon {self.epsilon:.0e})"
            )
        if not self.stable:
            out.append("not a local minimum (the Hessian has a negative eigenvalue)")
        return out

    @property
    def passed(self) -> bool:
        """Every check passed."""
        return not self.problems()


@dataclass(frozen=True, eq=False)
class JammingResult:
    """Outcome of :func:`jam`: the jamming fraction and the jammed packing.

    ``phi_c`` is ``phi_high``, the jammed fraction, within ``epsilon`` above ``phi_low``, the
    unjammed configuration it was grown from; ``packing`` the relaxed jammed configuration at
    ``phi_c`` and ``observables`` its measurements (z with rattlers removed); ``check`` the
    referee's checks. ``iterations`` and ``evaluations`` sum over all ``steps`` relaxations.
    """

    phi_c: float
    phi_low: float
    packing: Packing
    observables: Observables
    check: JammingCheck
    steps: int
    iterations: int
    evaluations: int
    seconds: float
    history: tuple[JammingStep, ...]


@dataclass(frozen=True, eq=False)
class _Outcome:
    """A relaxed trial: the packing and the numbers a :class:`JammingStep` records (its fields
    of the same names)."""

    packing: Packing
    jammed: bool
    energy: float
    pressure: float
    contacts: int
    iterations: int
    evaluations: int
    saddles: int


class _Trials:
    """The relaxation of one jamming trial at a given ``phi`` from a given configuration."""

    def __init__(
        self,
        start: Packing,
        model: ContactModel,
        minimizer: Minimizer,
        energy_tol: float,
        rtol: float,
        final_rtol: float,
    ) -> None:
        self.start, self.model, self.minimizer = start, model, minimizer
        self.energy_tol, self.rtol, self.final_rtol = energy_tol, rtol, final_rtol
        self.largest = 0.5 * float(start.cell.narrowest_width)

    def radii(self, phi: float) -> np.ndarray:
        """Radii at ``phi``: the start radii scaled uniformly."""
        return self.start.radii_at(phi)

    def threshold(self, radii: np.ndarray) -> float:
        """The jamming threshold on the total energy (energy units)."""
        return self.energy_tol * self.start.n * energy_scale(radii, self.model)

    def relax(self, phi: float, origin: Packing, tight: bool, what: str) -> _Outcome:
        """Relax ``origin`` grown to ``phi`` (to force balance when ``tight``)."""
        radii = self.radii(phi)
        if radii.max() >= self.largest:
            raise InputError(f"phi: at {phi:.6g} the largest particle no longer fits the cell")
        grown = Packing(origin.positions, radii, self.start.cell)
        objective = Objective(grown, self.model)
        e_min = self.threshold(radii)
        relaxer = Relaxer(objective, self.minimizer)
        if tight:  # the packing the protocol reports: a minimum, not a saddle
            result, saddles = relaxer.relax_to_minimum(
                objective.x0,
                gtol=force_tolerance(grown, self.model, self.final_rtol),
                etol=e_min,
                what=what,
            )
        else:  # balanced relative to its own forces (module docstring)
            result = relaxer.relax_balanced(
                objective.x0,
                gtol=force_tolerance(grown, self.model, self.rtol),
                rtol=self.rtol,
                etol=e_min,
                what=what,
            )
            saddles = 0
        contacts = find_contacts(result.packing, self.model)
        p = pressure(stress(contacts, self.start.cell))
        return _Outcome(
            packing=result.packing,
            jammed=bool(result.energy > e_min and p > 0.0),
            energy=result.energy,
            pressure=p,
            contacts=int(contacts.i.size),
            iterations=result.iterations,
            evaluations=result.evaluations,
            saddles=saddles,
        )


def _next_trial(
    history: Sequence[JammingStep], dphi: float, epsilon: float, protocol: JamProtocol
) -> tuple[Phase, float, int] | None:
    """What ``protocol`` does after ``history``: ``(phase, phi, origin index)``, or None when the
    last step is the jammed ``final`` one (module docstring)."""
    last = history[-1]
    if last.phase == "final" and last.jammed:
        return None
    low, high = last.phi_low, last.phi_high
    if np.isinf(high):
        reopened = [
            k
            for k in range(1, len(history))
            if np.isinf(history[k].phi_high) and np.isfinite(history[k - 1].phi_high)
        ]
        if reopened:
            grown = len(history) - 1 - reopened[-1]
            step = min(dphi, RESTART * epsilon * 2.0**grown)
        else:
            step = dphi
        return "increment", low + step, last.index
    low_step = next(s for s in reversed(history) if not s.jammed and s.phi == low)
    high_step = next(s for s in reversed(history) if s.jammed and s.phi == high)
    if high - low > epsilon:
        origin = low_step.index if protocol == "seed" else last.index
        return "bisection", 0.5 * (low + high), origin
    if high_step.origin == low_step.index:
        return "final", high, high_step.index
    return "bisection", high, low_step.index


def jamming_steps(
    start: Packing,
    model: ContactModel,
    *,
    dphi: float = DPHI,
    epsilon: float = EPSILON,
    protocol: JamProtocol = JAM_PROTOCOL,
    minimizer: Minimizer | None = None,
    energy_tol: float | None = None,
    rtol: float = TRIAL_RTOL,
    final_rtol: float = FINAL_RTOL,
    resume: Sequence[JammingStep] = (),
) -> Iterator[JammingStep]:
    """Run the jamming protocol from ``start``, yielding every relaxed step.

    The last step (phase ``final``) is the jammed packing at ``phi_high``, relaxed to force
    balance: the relaxation of the unjammed configuration at ``phi_low`` grown by at most
    ``epsilon`` (module docstring).

    Parameters
    ----------
    start : packing at ``phi_init`` (below jamming; e.g. :func:`~athermal.random_packing`).
    model : contact law.
    dphi : growth increment in packing fraction (> 0).
    epsilon : the bracket the run ends on is at most this wide (>= :data:`RESOLUTION`).
    protocol : ``seed`` (each bisection trial from the last unjammed configuration) or
        ``ohern`` (from the previous trial); module docstring.
    minimizer : how each step is relaxed (default :data:`JAMMING_MINIMIZER`, P-L-BFGS).
    energy_tol : jamming threshold on ``E / N`` in units of ``k <r>^alpha``; default
        :func:`energy_threshold` (module docstring).
    rtol : force tolerance of the trial steps, relative to the packing's own mean contact
        force (module docstring).
    final_rtol : force tolerance of the final step, relative to the packing's own mean contact
        force (floored at round-off).
    resume : the steps already done by an interrupted run with the same arguments (as read
        back from its trajectory); the run continues after the last of them and yields the
        same steps, bit for bit, as an uninterrupted run.

    Raises
    ------
    InputError : bad parameters, a start packing that is already jammed, or ``resume`` steps
        that do not belong to this run.
    ConvergenceError : a relaxation reached its iteration limit, or no jamming below phi = 1.
    """
    dphi = positive_scalar(dphi, "dphi")
    check_growth(start.phi, dphi, start.dim)
    epsilon = check_epsilon(epsilon)
    choice(protocol, "protocol", JAM_PROTOCOLS)
    if energy_tol is None:
        energy_tol = energy_threshold(start.dim, model.alpha)
    trials = _Trials(
        start,
        model,
        minimizer or JAMMING_MINIMIZER,
        positive_scalar(energy_tol, "energy_tol"),
        positive_scalar(rtol, "rtol"),
        positive_scalar(final_rtol, "final_rtol"),
    )

    def step(
        index: int, phase: Phase, phi: float, origin: int, previous: JammingStep | None
    ) -> JammingStep:
        t0 = time.perf_counter()
        source = start if previous is None else history[origin].packing
        out = trials.relax(
            phi, source, phase == "final", f"jamming step {index} at phi = {phi:.9g}"
        )
        low, high = (0.0, np.inf) if previous is None else (previous.phi_low, previous.phi_high)
        if out.jammed:
            high = min(high, phi)
        else:
            low = max(low, phi)
            if low >= high:  # the jammed bound belonged to another basin: reopen
                high = np.inf
        return JammingStep(
            index=index,
            phase=phase,
            origin=origin,
            phi=phi,
            seconds=time.perf_counter() - t0,
            phi_low=low,
            phi_high=high,
            **vars(out),
        )

    history: list[JammingStep] = list(resume)
    if history:
        _check_resume(history, start)
    else:
        first = step(0, "start", start.phi, -1, None)
        if first.jammed:
            raise InputError(
                f"phi_init: the start packing is jammed after relaxation at phi = "
                f"{start.phi:.6g} (E = {first.energy:.3e}); start from a lower packing fraction"
            )
        history.append(first)
        yield first
    while (trial := _next_trial(history, dphi, epsilon, protocol)) is not None:
        phase, phi, origin = trial
        if phi >= 1.0:
            raise ConvergenceError(f"no jammed state found below phi = 1 (last {phi:.6g})")
        new = step(len(history), phase, phi, origin, history[-1])
        history.append(new)
        yield new


def _check_resume(steps: Sequence[JammingStep], start: Packing) -> None:
    """Resumed steps must start with the relaxed start packing and be numbered 0, 1, ..."""
    if [s.index for s in steps] != list(range(len(steps))) or steps[0].phase != "start":
        raise InputError("resume: steps must be this run's steps 0, 1, ... in order")
    if steps[0].packing.n != start.n or not np.isclose(steps[0].phi, start.phi, rtol=1e-12):
        raise InputError("resume: the steps belong to another start packing")


def overlap_distance(contacts: Contacts, packing: Packing) -> float:
    """``d phi <delta / (r_i + r_j)>``: the mean overlap as a distance above jamming in packing
    fraction (radii grown by ``1 + s`` raise ``phi`` by ``d phi s``; what packings jammed by
    :func:`jamming_steps` have: ``docs/decisions.md``, section "Protocol constants")."""
    if contacts.i.size == 0:
        return 0.0
    radii_sum = packing.radii[contacts.i] + packing.radii[contacts.j]
    return packing.dim * packing.phi * float(np.mean(contacts.overlap / radii_sum))


def isostatic_allowance(nonrattlers: int, dim: int, overlap_dphi: float) -> float:
    """The most ``N_c - N_iso`` a packing of ``nonrattlers`` particles whose mean overlap is
    ``overlap_dphi`` (as a packing-fraction distance) may have and count as isostatic:
    ``ISOSTATIC_SLACK + ISOSTATIC_SPREAD N' Z_SLOPE[dim] sqrt(overlap_dphi) / 2``."""
    mean = nonrattlers * Z_SLOPE[dim] * float(np.sqrt(max(overlap_dphi, 0.0))) / 2
    return ISOSTATIC_SLACK + ISOSTATIC_SPREAD * mean


def check_jammed(
    packing: Packing,
    model: ContactModel,
    *,
    epsilon: float = EPSILON,
    minimizer: Minimizer | None = None,
    energy_tol: float | None = None,
) -> JammingCheck:
    """The referee's checks of a packing said to be jammed within ``epsilon`` (module
    docstring): decompression by ``DECOMPRESSION`` x ``epsilon`` unjams it, it is isostatic,
    its overlaps are those of a packing at most ~``epsilon`` above jamming, and it is a minimum.

    ``energy_tol`` is the jamming threshold (default as in :func:`jamming_steps`).
    """
    epsilon = check_epsilon(epsilon)
    if energy_tol is None:
        energy_tol = energy_threshold(packing.dim, model.alpha)
    trials = _Trials(
        packing, model, minimizer or JAMMING_MINIMIZER, energy_tol, TRIAL_RTOL, FINAL_RTOL
    )
    delta = DECOMPRESSION * epsilon
    below = trials.relax(packing.phi - delta, packing, False, "decompression check")
    contacts = find_contacts(packing, model)
    rattler = rattlers(contacts, packing.n, packing.dim)
    _, c_live = coordination(contacts, rattler)
    n_live = int((~rattler).sum())
    overlap = overlap_distance(contacts, packing)
    return JammingCheck(
        decompression=delta,
        decompressed_energy=below.energy / (packing.n * energy_scale(below.packing.radii, model)),
        unjams=not below.jammed,
        excess_contacts=c_live
        - isostatic_contacts(n_live, packing.dim, packing.cell.periodic_axes),
        allowed_excess=isostatic_allowance(n_live, packing.dim, overlap),
        overlap_dphi=overlap,
        epsilon=epsilon,
        stable=stability(packing, model).stable,
    )


def jam(
    start: Packing,
    model: ContactModel,
    *,
    dphi: float = DPHI,
    epsilon: float = EPSILON,
    protocol: JamProtocol = JAM_PROTOCOL,
    minimizer: Minimizer | None = None,
    energy_tol: float | None = None,
    rtol: float = TRIAL_RTOL,
    final_rtol: float = FINAL_RTOL,
    resume: Sequence[JammingStep] = (),
    on_step: Callable[[JammingStep], None] | None = None,
) -> JammingResult:
    """Run :func:`jamming_steps` to the end, check the jammed packing (:func:`check_jammed`;
    a ``UserWarning`` names any check that fails) and return it.

    ``resume`` continues an interrupted run from its completed steps (as in
    :func:`jamming_steps`); ``on_step`` sees each newly completed step (e.g. to append it to a
    trajectory) before the next begins.

    Examples
    --------
    >>> from athermal import ContactModel, random_packing
    >>> result = jam(random_packing(64, 0.8, seed=3), ContactModel(2.0), epsilon=1e-4)
    >>> bool(0.75 < result.phi_c < 0.9 and result.check.unjams)
    True
    """
    t0 = time.perf_counter()
    history = list(resume)
    for step in jamming_steps(
        start,
        model,
        dphi=dphi,
        epsilon=epsilon,
        protocol=protocol,
        minimizer=minimizer,
        energy_tol=energy_tol,
        rtol=rtol,
        final_rtol=final_rtol,
        resume=resume,
    ):
        history.append(step)  # the resumed steps are not yielded again
        if on_step is not None:
            on_step(step)
    final = history[-1]
    check = check_jammed(
        final.packing, model, epsilon=epsilon, minimizer=minimizer, energy_tol=energy_tol
    )
    if not check.passed:
        warnings.warn(
            f"jam: the packing at phi_c = {final.phi:.9f} fails: {'; '.join(check.problems())}",
            UserWarning,
            stacklevel=2,
        )
    return JammingResult(
        phi_c=final.phi,
        phi_low=final.phi_low,
        packing=final.packing,
        observables=measure(final.packing, model),
        check=check,
        steps=len(history),
        iterations=sum(s.iterations for s in history),
        evaluations=sum(s.evaluations for s in history),
        seconds=time.perf_counter() - t0,
        history=tuple(history),
    )
