"""Packings at a target pressure: jam a packing, then find the packing fraction at which its
relaxed pressure is ``P`` (:func:`jam_to_pressure`, :func:`pressure_search`).

Near jamming ``p ~ (phi - phi_c)^(alpha - 1)``, so ``y = p^(1/(alpha-1))`` is nearly linear in
``phi``: the search runs on ``y``. From the jammed packing (``y = 0`` at ``phi_low``, the
unjammed state below it) it extrapolates linearly, each trial at most ``STEP`` times further
from ``phi_low`` than the last (4 per decade, as the compression protocol), until a trial's
pressure exceeds ``P``; then it closes the bracket by the Illinois variant of regula falsi until
``|p / P - 1| <= rtol``. Every trial scales the radii of the relaxed state at the bracket's low
end and relaxes it to a local minimum
(:meth:`~athermal.relaxation.Relaxer.relax_to_minimum`): the packing is only ever
compressed quasi-statically from below ``P`` (never decompressed from an overshoot, which would
move its jamming point), and the packings of several pressures from one start follow one branch
of states. A target below the jammed packing's own pressure is reached by decompressing it,
and so is one that ``p`` jumps across at a rearrangement (no state at ``P`` on the branch from
below): the search then decompresses the state above the jump along its own branch.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from .._validate import positive_scalar
from ..analysis.observables import Observables, measure
from ..errors import ConvergenceError, InputError
from ..model.contact import ContactModel
from ..model.objective import Objective
from ..model.packing import Packing
from ..relaxation import RTOL, Minimizer, Relaxer, force_tolerance
from .jamming import DPHI, EPSILON, JAMMING_MINIMIZER, JammingResult, JammingStep, jam

PRESSURE_RTOL = 1e-3
"""Default relative accuracy of the pressure reached."""
MAX_TRIALS = 80
"""Most relaxations a search may take."""
STEP = 10.0**0.25
"""Largest factor by which a trial may be further from ``phi_low`` than the state it compresses
(4 per decade, as the compression protocol's steps)."""
MAX_PHI = 0.9999
"""The search does not go beyond this packing fraction (the pressures it bounds:
``docs/decisions.md``, "Measured behind the code")."""
REACH_RTOL = 1e-6
"""Force tolerance of :func:`check_reachable`'s relaxation, x the mean contact force."""
NEAR_JAMMING = 10.0
"""A ``UserWarning`` says when ``phi - phi_c`` is below this many ``epsilon`` of the jamming
run: ``phi_c`` is then too coarse to measure the distance from jamming."""


@dataclass(frozen=True)
class PressureTrial:
    """One relaxation of the search: its packing fraction, relaxed pressure and iterations."""

    phi: float
    pressure: float
    iterations: int


@dataclass(frozen=True, eq=False)
class PressureResult:
    """The relaxed packing at the target pressure.

    Attributes
    ----------
    packing : the relaxed packing, a local minimum at ``phi``.
    target, pressure : the pressure asked for and reached (``k l^(alpha-d)``).
    phi, phi_c : its packing fraction and the jamming point of its start.
    observables : :func:`~athermal.analysis.observables.measure` of ``packing``.
    trials : every relaxation of the search, in order.
    jamming : the jamming run it started from (None for :func:`pressure_search` alone).
    iterations, seconds : summed over the trials (and the jamming run).
    """

    packing: Packing
    target: float
    pressure: float
    phi: float
    phi_c: float
    observables: Observables
    trials: tuple[PressureTrial, ...]
    jamming: JammingResult | None
    iterations: int
    seconds: float

    @property
    def delta_phi(self) -> float:
        """``phi - phi_c``."""
        return self.phi - self.phi_c

    @property
    def pressure_drops(self) -> int:
        """Trials whose pressure fell below the last one's although ``phi`` rose: plastic
        rearrangements on the way (how often: ``docs/decisions.md``, "Measured behind the code")."""
        pairs = zip(self.trials, self.trials[1:], strict=False)
        return sum(1 for a, b in pairs if b.phi > a.phi and b.pressure < a.pressure)


def pressure_search(
    jammed: Packing,
    model: ContactModel,
    target: float,
    *,
    phi_low: float,
    phi_c: float | None = None,
    rtol: float = PRESSURE_RTOL,
    minimizer: Minimizer | None = None,
    force_rtol: float = RTOL,
) -> PressureResult:
    """The relaxed packing at pressure ``target`` reached from ``jammed`` by scaling its radii.

    Parameters
    ----------
    jammed : a relaxed packing at or above jamming (e.g. :func:`jam`'s, or the result of an
        earlier search at a lower pressure).
    model : contact law.
    target : the pressure ``P > 0``.
    phi_low : a packing fraction below jamming for the same configuration (``p = 0`` there),
        e.g. :func:`jam`'s ``phi_low``; the search's lower anchor.
    phi_c : the jamming point ``phi - phi_c`` is reported against (default ``phi_low``).
    rtol : relative accuracy of the pressure.
    minimizer : how each trial is relaxed (default L-BFGS).
    force_rtol : force tolerance of each trial, relative to its mean contact force.
    """
    target = positive_scalar(target, "pressure")
    rtol = positive_scalar(rtol, "rtol")
    if not 0.0 < phi_low < jammed.phi:
        raise InputError(f"phi_low: must lie in (0, {jammed.phi:.9g}), got {phi_low!r}")
    t0 = time.perf_counter()
    config = minimizer or Minimizer()
    exponent = 1.0 / (model.alpha - 1.0)
    phi0 = jammed.phi
    trials: list[PressureTrial] = []

    def relax(start: Packing, phi: float) -> tuple[Packing, float]:
        if len(trials) == MAX_TRIALS:
            raise ConvergenceError(
                f"pressure {target:.3e}: not reached to {rtol:.0e} in {MAX_TRIALS} relaxations "
                f"(last p = {trials[-1].pressure:.6e} at phi {trials[-1].phi:.12f}; a "
                "rearrangement may make p jump across the target)"
            )
        grown = Packing(start.positions, jammed.radii_at(phi), jammed.cell)
        objective = Objective(grown, model)
        result, _ = Relaxer(objective, config).relax_to_minimum(
            objective.x0,
            gtol=force_tolerance(grown, model, force_rtol),
            what=f"pressure trial {len(trials)} (phi {phi:.12g})",
        )
        p = max(measure(result.packing, model).pressure, 0.0)
        trials.append(PressureTrial(phi, p, result.iterations))
        return result.packing, p

    current, p = relax(jammed, phi0)
    y_target = target**exponent
    # bracket ends (phi, y - y_target); "previous" is the other point of an extrapolation;
    # "below" the relaxed state of the low end, from which every trial compresses
    low: tuple[float, float] = (phi_low, -y_target)  # unjammed: p = 0
    high: tuple[float, float] | None = None
    previous, below, above = low, None, current
    switched = False  # decompressing from above after p jumped across the target
    if p**exponent >= y_target:
        high = (phi0, p**exponent - y_target)
    else:
        low, below = (phi0, p**exponent - y_target), current
    last = 0  # which end the last trial replaced: -1 low, +1 high
    while abs(p / target - 1.0) > rtol:
        if high is None:
            (pa, fa), (pb, fb) = previous, low
            if pb >= MAX_PHI:
                raise ConvergenceError(
                    f"pressure {target:.3e}: out of reach below phi = {MAX_PHI} (p = "
                    f"{trials[-1].pressure:.4e} there)"
                )
            slope = (fb - fa) / (pb - pa)
            reach = (STEP - 1.0) * (pb - phi_low)
            phi = min(pb + (min(-fb / slope, reach) if slope > 0.0 else reach), MAX_PHI)
        else:
            (pa, fa), (pb, fb) = low, high
            if pb - pa <= 1e-12 * pb:
                if switched:
                    raise ConvergenceError(
                        f"pressure {target:.3e}: p jumps across it at phi {pa:.15f} on the way "
                        "up and down; a rearrangement: try another start"
                    )
                # p jumps across the target at a rearrangement: no state at P on this branch;
                # decompress the state above the jump along its own branch instead
                switched, below, last = True, None, 0
                low, (pa, fa) = (phi_low, -y_target), (phi_low, -y_target)
            phi = pa - fa * (pb - pa) / (fb - fa)
        current, p = relax(above if switched else (current if below is None else below), phi)
        value = p**exponent - y_target
        if value >= 0.0:
            if high is not None and last == 1:  # Illinois: the kept end's value halves
                low = (low[0], low[1] / 2.0)
            high, last, above = (phi, value), 1, current
        else:
            if high is None:
                previous = low
            elif last == -1:
                high = (high[0], high[1] / 2.0)
            low, last, below = (phi, value), -1, current
    reference = phi_low if phi_c is None else float(phi_c)
    return PressureResult(
        packing=current,
        target=target,
        pressure=p,
        phi=current.phi,
        phi_c=reference,
        observables=measure(current, model),
        trials=tuple(trials),
        jamming=None,
        iterations=sum(t.iterations for t in trials),
        seconds=time.perf_counter() - t0,
    )


def check_reachable(
    start: Packing, model: ContactModel, target: float, minimizer: Minimizer | None = None
) -> None:
    """:class:`InputError` when the particles of ``start`` cannot reach pressure ``target``
    below :data:`MAX_PHI`: ``start`` grown to :data:`MAX_PHI` and relaxed sets the reach, before
    any jamming. Configurations that far above jamming differ a little in pressure, so a target
    just below the reach may still be out of the search's reach (measured: ``docs/commands.md``,
    "Every command")."""
    grown = Packing(start.positions, start.radii_at(MAX_PHI), start.cell)
    objective = Objective(grown, model)
    result, _ = Relaxer(objective, minimizer or JAMMING_MINIMIZER).relax_to_minimum(
        objective.x0,
        gtol=force_tolerance(grown, model, REACH_RTOL),
        what=f"the pressure reach at phi {MAX_PHI}",
    )
    reach = measure(result.packing, model).pressure
    if target > reach:
        raise InputError(
            f"pressure: {target:g} is out of reach; these particles reach p = {reach:.3g} at "
            f"phi = {MAX_PHI} (the contact stiffness sets the scale)"
        )


def jam_to_pressure(
    start: Packing,
    model: ContactModel,
    pressure: float,
    *,
    dphi: float = DPHI,
    epsilon: float = EPSILON,
    rtol: float = PRESSURE_RTOL,
    minimizer: Minimizer | None = None,
    resume: Sequence[JammingStep] = (),
    on_step: Callable[[JammingStep], None] | None = None,
) -> PressureResult:
    """Jam ``start`` (:func:`~athermal.protocols.jam`, ``dphi``, ``epsilon``, ``minimizer``,
    ``resume``, ``on_step`` as there), then :func:`pressure_search` from the jammed packing to
    ``pressure`` (within ``rtol``), relaxed by the same minimizer; ``phi_c`` is the jamming
    run's. A ``UserWarning`` says when the packing ends within :data:`NEAR_JAMMING` x
    ``epsilon`` of ``phi_c`` (jam with a smaller ``epsilon``).

    Examples
    --------
    >>> from athermal import ContactModel, random_packing
    >>> r = jam_to_pressure(random_packing(64, 0.8, seed=3), ContactModel(), 1e-3,
    ...                     epsilon=1e-5)
    >>> abs(r.pressure / 1e-3 - 1) <= 1e-3, r.delta_phi > 0
    (True, True)
    """
    target = positive_scalar(pressure, "pressure")
    check_reachable(start, model, target, minimizer)
    jammed = jam(
        start,
        model,
        dphi=dphi,
        epsilon=epsilon,
        minimizer=minimizer,
        resume=resume,
        on_step=on_step,
    )
    found = pressure_search(
        jammed.packing,
        model,
        target,
        phi_low=jammed.phi_low,
        phi_c=jammed.phi_c,
        rtol=rtol,
        minimizer=minimizer or JAMMING_MINIMIZER,
    )
    warn_if_near_jamming(found, epsilon)
    return PressureResult(
        packing=found.packing,
        target=target,
        pressure=found.pressure,
        phi=found.phi,
        phi_c=found.phi_c,
        observables=found.observables,
        trials=found.trials,
        jamming=jammed,
        iterations=jammed.iterations + found.iterations,
        seconds=jammed.seconds + found.seconds,
    )


def warn_if_near_jamming(found: PressureResult, epsilon: float) -> None:
    """A ``UserWarning`` when ``found`` lies within :data:`NEAR_JAMMING` x ``epsilon`` (the
    jamming run's accuracy) of its ``phi_c``."""
    if found.delta_phi < NEAR_JAMMING * epsilon:
        warnings.warn(
            f"pressure {found.target:.3e}: phi - phi_c = {found.delta_phi:.2e} is within "
            f"{NEAR_JAMMING:g} epsilon of the jamming point (epsilon {epsilon:.0e}): jam with a "
            "smaller epsilon to measure it",
            UserWarning,
            stacklevel=3,
        )
