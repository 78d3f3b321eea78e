"""Jamming by growth and bisection: the seed's Algorithm 1 (after O'Hern et al. 2003).

From a start packing at ``phi_init`` the radii grow by ``dphi`` (in packing fraction) and the
packing is relaxed, until a relaxed state is jammed; then ``phi`` is bisected between the last
unjammed and the first jammed fraction, each trial relaxed from the last unjammed
configuration, until the bracket is below ``epsilon``. Radii are always
``r0 (phi / phi_init)^(1/d)`` from the start radii, so a step depends on its ``phi`` alone and
not on the path that led there.

**Jammed** means: the relaxed energy per particle exceeds ``energy_tol`` x ``k <r>^alpha`` and
the pressure is positive. Relaxations stop as soon as the energy falls to that threshold (the
packing is unjammed) or when ``max_i |grad_i| <= gtol`` x ``k <r>^(alpha-1)`` (a mechanically
stable state). A packing jammed by ``Delta phi`` has overlaps ``delta ~ <r> Delta phi / (d phi)``
and ``E / N ~ k <r>^alpha (Delta phi / (d phi))^alpha``, so the default threshold
``(epsilon / (10 d))^alpha`` separates states jammed by more than ~``epsilon / 10`` from
unjammed ones (2.5e-15 for ``alpha = 2`` and ``epsilon = 1e-6``; a packing jammed by
``epsilon`` has ~3.5e-13) while sparing the slowest part of relaxing an unjammed packing near
``phi_c``, its last orders of magnitude of energy. Both stay far above round-off (energies
~1e-12 relative, forces ~1e-14 of the force scale at N = 4096 in the unit square).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from .._validate import positive_scalar
from ..contact import ContactModel, find_contacts
from ..errors import ConvergenceError, InputError
from ..objective import Objective
from ..observables import Observables, measure, pressure, stress
from ..packing import Packing
from ._relax import Minimizer, Relaxer, energy_scale, force_scale

GTOL = 1e-12
"""Default tolerance on ``max_i |grad_i|`` in units of ``k <r>^(alpha-1)``."""

Phase = Literal["start", "increment", "bisection"]


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
    gtol: float = GTOL,
) -> Iterator[JammingStep]:
    """Run the jamming protocol from ``start``, yielding every relaxed step.

    Parameters
    ----------
    start : packing at ``phi_init`` (below jamming; e.g. :func:`~athermal.random_packing`).
    model : contact law.
    dphi : growth increment in packing fraction (> 0).
    epsilon : bisection stops when the bracket is at most this wide (> 0).
    minimizer : how each step is relaxed (default L-BFGS); one objective and one
        preconditioner serve all steps.
    energy_tol : jamming threshold on ``E / N`` in units of ``k <r>^alpha``; default
        ``(epsilon / (10 d))^alpha`` (module docstring).
    gtol : force tolerance in units of ``k <r>^(alpha-1)``.

    Raises
    ------
    InputError : bad parameters, or a start packing that is already jammed.
    ConvergenceError : a relaxation reached its iteration limit, or no jamming below phi = 1.
    """
    dphi = positive_scalar(dphi, "dphi")
    epsilon = positive_scalar(epsilon, "epsilon")
    if energy_tol is None:
        energy_tol = (epsilon / (10.0 * start.dim)) ** model.alpha
    energy_tol = positive_scalar(energy_tol, "energy_tol")
    gtol = positive_scalar(gtol, "gtol")
    objective = Objective(start, model)
    relaxer = Relaxer(objective, minimizer or Minimizer())
    phi_init, base = start.phi, start.radii
    largest = 0.5 * float(start.cell.widths.min())

    def relax(
        phi: float, x: NDArray[np.float64], index: int, phase: Phase, low: float, high: float
    ) -> tuple[JammingStep, NDArray[np.float64]]:
        t0 = time.perf_counter()
        radii = base * (phi / phi_init) ** (1.0 / start.dim)
        if radii.max() >= largest:
            raise InputError(f"phi: at {phi:.6g} the largest particle no longer fits the cell")
        objective.set_radii(radii)
        e_min = energy_tol * start.n * energy_scale(radii, model)
        result = relaxer.relax(
            x,
            gtol=gtol * force_scale(radii, model),
            etol=e_min,
            what=f"jamming step {index} at phi = {phi:.9g}",
        )
        contacts = find_contacts(result.packing, model)
        p = pressure(stress(contacts, start.cell))
        jammed = result.energy > e_min and p > 0.0
        if jammed:
            high = min(high, phi)
        else:
            low = max(low, phi)
        step = JammingStep(
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
        return step, result.x

    step, x_low = relax(phi_init, objective.x0, 0, "start", 0.0, np.inf)
    if step.jammed:
        raise InputError(
            f"phi_init: the start packing is jammed after relaxation at phi = {phi_init:.6g} "
            f"(E = {step.energy:.3e}); start from a lower packing fraction"
        )
    yield step
    index, low, high = 1, phi_init, np.inf
    while np.isinf(high):
        phi = low + dphi
        if phi >= 1.0:
            raise ConvergenceError(f"no jammed state found below phi = 1 (last {low:.6g})")
        step, x = relax(phi, x_low, index, "increment", low, high)
        low, high, index = step.phi_low, step.phi_high, index + 1
        if not step.jammed:
            x_low = x
        yield step
    while high - low > epsilon:
        phi = 0.5 * (low + high)
        step, x = relax(phi, x_low, index, "bisection", low, high)
        low, high, index = step.phi_low, step.phi_high, index + 1
        if not step.jammed:
            x_low = x
        yield step


def jam(
    start: Packing,
    model: ContactModel,
    *,
    dphi: float = 1e-3,
    epsilon: float = 1e-6,
    minimizer: Minimizer | None = None,
    energy_tol: float | None = None,
    gtol: float = GTOL,
) -> JammingResult:
    """Run :func:`jamming_steps` to the end and return the jammed packing.

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
            gtol=gtol,
        )
    )
    final = next(s for s in reversed(history) if s.jammed)
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
