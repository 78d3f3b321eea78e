"""Jamming by growth and bisection: the seed's Algorithm 1 (after O'Hern et al. 2003).

From a start packing at ``phi_init`` the radii grow by ``dphi`` (in packing fraction) and the
packing is relaxed, until a relaxed state is jammed; then ``phi`` is bisected between the last
unjammed and the first jammed fraction, each trial relaxed from the last unjammed
configuration, until the bracket is below ``epsilon``. Radii are always
``r0 (phi / phi_init)^(1/d)`` from the start radii, and every step builds its own objective and
preconditioner from its start configuration: a step is a function of that configuration and its
``phi`` alone, which is what lets an interrupted run resume bit for bit (``resume``).

**Jammed** means: the relaxed energy per particle exceeds ``energy_tol`` x ``k <r>^alpha`` and
the pressure is positive. A trial relaxation stops as soon as the energy falls to that
threshold (the packing is unjammed) or when ``max_i |grad_i|`` is below ``rtol`` (1e-6) times
the mean contact force at its start (a mechanically stable state, up to that balance), but never
above a tenth of the force of an overlap that holds the threshold energy, so that a packing far
from balance cannot stop there with an energy above the threshold; the
jammed packing that ends the bisection is then relaxed once more to ``max_i |grad_i| <= gtol``
x ``k <r>^(alpha-1)`` (1e-12), the ``final`` step.

A packing jammed by ``Delta phi`` has overlaps ``delta ~ <r> Delta phi / (d phi)`` and
``E / N ~ k <r>^alpha (Delta phi / (d phi))^alpha``, so the default threshold
``(epsilon / (10 d))^alpha`` separates states jammed by more than ~``epsilon / 10`` from
unjammed ones (2.5e-15 for ``alpha = 2`` and ``epsilon = 1e-6``; a packing jammed by
``epsilon`` has ~3.5e-13) while sparing the slowest part of relaxing an unjammed packing near
``phi_c``, its last orders of magnitude of energy. Both stay far above round-off (energies
~1e-12 relative, forces ~1e-14 of the force scale at N = 4096 in the unit square).
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from .._validate import positive_scalar
from ..contact import ContactModel, find_contacts
from ..errors import ConvergenceError, InputError
from ..objective import Objective
from ..observables import Observables, measure, pressure, stress
from ..packing import Packing
from ._relax import GTOL_FLOOR, Minimizer, Relaxer, energy_scale, force_scale

JAMMING_MINIMIZER = Minimizer("lbfgs", "exp")
"""Default minimizer of the jamming protocol, P-L-BFGS: near jamming the Exp preconditioner pays.
Measured (2D, alpha = 2, one core): N = 1024, seeds 0-2, 12.7 / 32.3 / 12.7 s against L-BFGS's
34.2 / 32.3 / 55.7 s; N = 4096, seed 0, 109 s against 712 s."""
PHI_INIT = {2: 0.8, 3: 0.6}
"""Default start fraction by dimension: unjammed after relaxation (phi_c ~ 0.84 in 2D and
~0.64 in 3D for the bidisperse 1:1, 1.4 mixture)."""
RTOL = 1e-6
"""Default force tolerance of the trial steps, relative to the mean contact force at a step's
start."""
GTOL = 1e-12
"""Default force tolerance of the final step, in units of ``k <r>^(alpha-1)``."""

Phase = Literal["start", "increment", "bisection", "final"]


@dataclass(frozen=True, eq=False)
class JammingStep:
    """One relaxation of the jamming protocol.

    ``phase`` is ``start`` (the start packing relaxed), ``increment`` or ``bisection``;
    ``phi_low`` / ``phi_high`` bracket the jamming point after this step (``phi_high`` is
    ``inf`` until a jammed state is found). ``packing`` is the relaxed configuration at ``phi``
    (caller's particle order). Energy in ``k`` x length^alpha, pressure in energy / volume.
    """

    index: int
    phase: Phase
    phi: float
    jammed: bool
    energy: float
    pressure: float
    contacts: int
    iterations: int
    evaluations: int
    seconds: float
    phi_low: float
    phi_high: float
    packing: Packing

    def row(self) -> dict[str, float | int | str]:
        """The step's numbers (no packing), for tables."""
        return {
            "index": self.index,
            "phase": self.phase,
            "phi": self.phi,
            "jammed": int(self.jammed),
            "energy": self.energy,
            "pressure": self.pressure,
            "contacts": self.contacts,
            "iterations": self.iterations,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "phi_low": self.phi_low,
            "phi_high": self.phi_high,
        }

    @property
    def bracket(self) -> float:
        """Width ``phi_high - phi_low`` of the bracket (``inf`` before the first jammed step)."""
        return self.phi_high - self.phi_low


@dataclass(frozen=True, eq=False)
class JammingResult:
    """Outcome of :func:`jam`: the jamming fraction and the jammed packing.

    ``phi_c`` is the smallest jammed fraction found (within ``epsilon`` above the largest
    unjammed one); ``packing`` the relaxed jammed configuration at ``phi_c`` and
    ``observables`` its measurements (z with rattlers removed). ``iterations`` and
    ``evaluations`` sum over all ``steps`` relaxations.
    """

    phi_c: float
    packing: Packing
    observables: Observables
    steps: int
    iterations: int
    evaluations: int
    seconds: float
    history: tuple[JammingStep, ...]


def jamming_steps(
    start: Packing,
    model: ContactModel,
    *,
    dphi: float = 1e-3,
    epsilon: float = 1e-6,
    minimizer: Minimizer | None = None,
    energy_tol: float | None = None,
    rtol: float = RTOL,
    gtol: float = GTOL,
    resume: Sequence[JammingStep] = (),
) -> Iterator[JammingStep]:
    """Run the jamming protocol from ``start``, yielding every relaxed step.

    The last step (phase ``final``) relaxes the jammed packing at the top of the final bracket
    to the tight tolerance ``gtol``; it is the protocol's result. Should that packing unjam when
    relaxed further (it was jammed only at the trial tolerance), the ``final`` step is reported
    unjammed, becomes the bottom of an open bracket, and growth and bisection go on from it.

    Parameters
    ----------
    start : packing at ``phi_init`` (below jamming; e.g. :func:`~athermal.random_packing`).
    model : contact law.
    dphi : growth increment in packing fraction (> 0).
    epsilon : bisection stops when the bracket is at most this wide (> 0).
    minimizer : how each step is relaxed (default :data:`JAMMING_MINIMIZER`, P-L-BFGS).
    energy_tol : jamming threshold on ``E / N`` in units of ``k <r>^alpha``; default
        ``(epsilon / (10 d))^alpha`` (module docstring).
    rtol : force tolerance of the trial steps, relative to the mean contact force at the
        step's start (module docstring).
    gtol : force tolerance of the final step in units of ``k <r>^(alpha-1)``.
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
    epsilon = positive_scalar(epsilon, "epsilon")
    if energy_tol is None:
        energy_tol = (epsilon / (10.0 * start.dim)) ** model.alpha
    energy_tol = positive_scalar(energy_tol, "energy_tol")
    rtol = positive_scalar(rtol, "rtol")
    gtol = positive_scalar(gtol, "gtol")
    config = minimizer or JAMMING_MINIMIZER
    phi_init, base = start.phi, start.radii
    largest = 0.5 * float(start.cell.widths.min())

    def relax(
        phi: float, origin: Packing, index: int, phase: Phase, low: float, high: float
    ) -> JammingStep:
        t0 = time.perf_counter()
        radii = base * (phi / phi_init) ** (1.0 / start.dim)
        if radii.max() >= largest:
            raise InputError(f"phi: at {phi:.6g} the largest particle no longer fits the cell")
        objective = Objective(Packing(origin.positions, radii, start.cell), model)
        e_min = energy_tol * start.n * energy_scale(radii, model)
        # a tenth of the force of one overlap holding the threshold energy per particle
        f_cap = (
            0.1
            * force_scale(radii, model)
            * (model.alpha * energy_tol) ** (1.0 - 1.0 / model.alpha)
        )
        floor = GTOL_FLOOR * force_scale(radii, model)
        if phase == "final":
            tol = max(gtol * force_scale(radii, model), floor)
        else:
            tol = max(min(rtol * objective.mean_contact_force(objective.x0), f_cap), floor)
        result = Relaxer(objective, config).relax(
            objective.x0, gtol=tol, etol=e_min, what=f"jamming step {index} at phi = {phi:.9g}"
        )
        contacts = find_contacts(result.packing, model)
        p = pressure(stress(contacts, start.cell))
        jammed = result.energy > e_min and p > 0.0
        if jammed:
            high = min(high, phi)
        else:
            low = max(low, phi)
        return JammingStep(
            index=index,
            phase=phase,
            phi=phi,
            jammed=jammed,
            energy=result.energy,
            pressure=p,
            contacts=int(contacts.i.size),
            iterations=result.iterations,
            evaluations=result.evaluations,
            seconds=time.perf_counter() - t0,
            phi_low=low,
            phi_high=high,
            packing=result.packing,
        )

    if resume:
        _check_resume(resume, start)
        last = resume[-1]
        if last.phase == "final" and last.jammed:
            return
        index, low, high = last.index + 1, last.phi_low, last.phi_high
        low_step = next(s for s in reversed(resume) if not s.jammed and s.phi == low)
        high_step = next((s for s in reversed(resume) if s.jammed and s.phi == high), None)
    else:
        low_step = relax(phi_init, start, 0, "start", 0.0, np.inf)
        if low_step.jammed:
            raise InputError(
                f"phi_init: the start packing is jammed after relaxation at phi = "
                f"{phi_init:.6g} (E = {low_step.energy:.3e}); start from a lower packing "
                "fraction"
            )
        yield low_step
        index, low, high, high_step = 1, phi_init, np.inf, None
    while True:
        if high_step is not None and high - low <= epsilon:
            step = relax(high, high_step.packing, index, "final", low, high)
            if step.jammed:
                yield step
                return
            # jammed only at the trial tolerance: it unjams when relaxed further, so it is the
            # new bottom of an open bracket and the growth goes on from it
            step = replace(step, phi_high=np.inf)
        elif np.isinf(high):
            phi = low + dphi
            if phi >= 1.0:
                raise ConvergenceError(f"no jammed state found below phi = 1 (last {low:.6g})")
            step = relax(phi, low_step.packing, index, "increment", low, high)
        else:
            step = relax(0.5 * (low + high), low_step.packing, index, "bisection", low, high)
        low, high, index = step.phi_low, step.phi_high, index + 1
        if step.jammed:
            high_step = step
        else:
            low_step = step
        yield step


def _check_resume(steps: Sequence[JammingStep], start: Packing) -> None:
    """Resumed steps must start with the relaxed start packing and be numbered 0, 1, ..."""
    if [s.index for s in steps] != list(range(len(steps))) or steps[0].phase != "start":
        raise InputError("resume: steps must be this run's steps 0, 1, ... in order")
    if steps[0].packing.n != start.n or not np.isclose(steps[0].phi, start.phi, rtol=1e-12):
        raise InputError("resume: the steps belong to another start packing")


def jam(
    start: Packing,
    model: ContactModel,
    *,
    dphi: float = 1e-3,
    epsilon: float = 1e-6,
    minimizer: Minimizer | None = None,
    energy_tol: float | None = None,
    rtol: float = RTOL,
    gtol: float = GTOL,
) -> JammingResult:
    """Run :func:`jamming_steps` to the end and return the jammed packing (its final step).

    Examples
    --------
    >>> from athermal import ContactModel, random_packing
    >>> result = jam(random_packing(64, 0.8, seed=3), ContactModel(2.0), epsilon=1e-4)
    >>> 0.75 < result.phi_c < 0.9 and result.observables.energy > 0.0
    True
    """
    t0 = time.perf_counter()
    history = tuple(
        jamming_steps(
            start,
            model,
            dphi=dphi,
            epsilon=epsilon,
            minimizer=minimizer,
            energy_tol=energy_tol,
            rtol=rtol,
            gtol=gtol,
        )
    )
    final = history[-1]
    return JammingResult(
        phi_c=final.phi,
        packing=final.packing,
        observables=measure(final.packing, model),
        steps=len(history),
        iterations=sum(s.iterations for s in history),
        evaluations=sum(s.evaluations for s in history),
        seconds=time.perf_counter() - t0,
        history=history,
    )
