"""What the quasi-static protocols share: how a step is relaxed, and the energy and force scales
their tolerances are stated in."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ..contact import ContactModel
from ..errors import ConvergenceError, InputError
from ..minimize import Method, MinimizeResult, minimize, resolve_method
from ..objective import Objective
from ..precon import PreconName, SolverName, make_preconditioner

GTOL_FLOOR = 1e-13
"""Smallest ``max_i |grad_i|`` a protocol asks for, in units of :func:`force_scale`: gradients
carry round-off of ~1e-16 x the cell size x ``k`` per contact, ~1e-14 of the force scale for
N = 4096 in the unit square."""


@dataclass(frozen=True)
class Minimizer:
    """The energy minimizer a protocol relaxes every step with.

    Parameters
    ----------
    method : ``lbfgs``, ``cg``, ``fire`` or the seed's ``plbfgs`` / ``pcg``.
    precon : ``none``, ``exp`` (the seed's, weights parameter ``A``) or ``contact``.
    A : Exp weight decay (dimensionless, >= 0).
    solver : ``auto``, ``direct`` or ``amg`` for the preconditioner's linear solves.
    maxiter : iteration limit of one relaxation; reaching it stops the protocol with a
        :class:`~athermal.errors.ConvergenceError`.
    """

    method: Method = "lbfgs"
    precon: PreconName = "none"
    A: float = 0.0
    solver: SolverName = "auto"
    maxiter: int = 1_000_000

    def __post_init__(self) -> None:
        resolve_method(self.method, self.precon)
        if int(self.maxiter) != self.maxiter or self.maxiter < 1:
            raise InputError(f"maxiter: must be an integer >= 1, got {self.maxiter!r}")

    @property
    def label(self) -> str:
        """``method`` or ``method+precon``, e.g. ``lbfgs+exp``."""
        base, precon = resolve_method(self.method, self.precon)
        return base if precon == "none" else f"{base}+{precon}"


class Relaxer:
    """An :class:`Objective` with its preconditioner, for the relaxation of one protocol step.

    Each step builds its own (from the step's start configuration), so that a step depends on
    that configuration alone and an interrupted protocol resumes bit for bit; within the step
    the preconditioner rebuilds by its own rule and the Verlet list by the skin. Measured: an
    Exp build costs 35-40 ms at N = 4096: 51 of them, 2 s of a 109 s jamming run. When L-BFGS or CG
    stops because no Wolfe step exists (it happens within a few times ``gtol`` of a minimum
    near jamming, where the energy differences of a step are at round-off), FIRE, which needs
    no line search, finishes the relaxation from there; the result counts both.
    """

    def __init__(self, objective: Objective, minimizer: Minimizer) -> None:
        self.objective = objective
        self.minimizer = minimizer
        self.method, name = resolve_method(minimizer.method, minimizer.precon)
        self.precon = make_preconditioner(name, objective, A=minimizer.A, solver=minimizer.solver)

    def relax(
        self, x: NDArray[np.float64], *, gtol: float, etol: float = 0.0, what: str = "step"
    ) -> MinimizeResult:
        """Minimize from ``x`` ``(N d,)`` (internal order) to ``max_i |grad_i| <= gtol`` or
        energy ``<= etol``; raises :class:`ConvergenceError` naming ``what`` otherwise."""
        self.objective.start_from(x)
        result = minimize(
            self.objective,
            self.method,  # type: ignore[arg-type]
            precon=self.precon if self.precon is not None else "none",
            gtol=gtol,
            etol=etol,
            maxiter=self.minimizer.maxiter,
        )
        if not result.converged and result.message.startswith("line search failed"):
            result = self._finish_with_fire(result, gtol, etol)
        if not result.converged:
            raise ConvergenceError(
                f"{what}: {self.minimizer.label} did not converge ({result.message}; "
                f"max|grad| {result.max_gradient:.3e} > gtol {gtol:.3e}); raise maxiter or "
                "try another method"
            )
        return result

    def _finish_with_fire(self, first: MinimizeResult, gtol: float, etol: float) -> MinimizeResult:
        self.objective.start_from(first.x)
        rest = minimize(
            self.objective,
            "fire",
            precon=self.precon if self.precon is not None else "none",
            gtol=gtol,
            etol=etol,
            maxiter=max(1, self.minimizer.maxiter - first.iterations),
        )
        return replace(
            rest,
            message=f"{rest.message} (FIRE after: {first.message})",
            method=f"{first.method}+fire",
            iterations=first.iterations + rest.iterations,
            evaluations=first.evaluations + rest.evaluations,
            seconds=first.seconds + rest.seconds,
            history_energy=np.concatenate([first.history_energy, rest.history_energy[1:]]),
            history_max_gradient=np.concatenate(
                [first.history_max_gradient, rest.history_max_gradient[1:]]
            ),
            neighbor_rebuilds=first.neighbor_rebuilds + rest.neighbor_rebuilds,
        )


def force_scale(radii: NDArray[np.float64], model: ContactModel) -> float:
    """``k_max <r>^(alpha-1)``: the force of an overlap of one mean radius (force units)."""
    return float(model.kmat.max()) * float(np.mean(radii)) ** (model.alpha - 1.0)


def energy_scale(radii: NDArray[np.float64], model: ContactModel) -> float:
    """``k_max <r>^alpha``: the energy of an overlap of one mean radius (energy units)."""
    return float(model.kmat.max()) * float(np.mean(radii)) ** model.alpha
