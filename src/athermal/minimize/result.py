"""What every minimizer is given and returns, and the bookkeeping they share.

The minimizers know a :class:`Problem`: ``f`` and ``grad f`` of a flat vector ``x``, a norm
of the gradient, the longest step allowed along a direction and the round-off of ``f``. An
:class:`~athermal.objective.Objective` is one; the packing-aware parts (the ``rtol`` of the
mean contact force, the per-particle step cap, FIRE's curvature bound) live there.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..packing import Packing


class Problem(Protocol):
    """A function to minimize, as the minimizers see it (:class:`~athermal.objective.Objective`
    is one; a test may pass any object with these members)."""

    n_evaluations: int
    n_rebuilds: int

    @property
    def n_dof(self) -> int:
        """Length of ``x``."""
        ...

    def __call__(self, x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        """``f(x)`` and ``grad f(x)`` ``(n_dof,)``."""
        ...

    def max_gradient(self, grad: NDArray[np.float64]) -> float:
        """The norm the tolerance is stated in (``max_i |grad_i|``)."""
        ...

    def step_limit(self, direction: NDArray[np.float64]) -> float:
        """Largest step ``a`` allowed along ``direction`` in one iteration."""
        ...

    def energy_noise(self, energy: float) -> float:
        """Absolute round-off of ``f`` near ``energy``."""
        ...

    def packing(self, x: NDArray[np.float64], *, internal: bool = False) -> Packing | None:
        """The configuration at ``x`` for the result (``None`` for a plain function)."""
        ...


class Status(StrEnum):
    """Why a minimization stopped (the protocols test this, never the message text)."""

    CONVERGED = "converged"
    """``max_gradient <= gtol``, or the energy reached ``etol``."""
    ITERATION_LIMIT = "iteration limit"
    LINE_SEARCH_FAILED = "line search failed"
    """No step met the Wolfe conditions, even along the (preconditioned) gradient."""
    NOT_FINITE = "not finite"
    """The energy, gradient or step became NaN or infinite."""


class Preconditioner(Protocol):
    """A symmetric positive definite ``P`` ``(N d, N d)`` approximating the Hessian.

    ``update`` is called at every iterate and rebuilds ``P`` only when its own rule says so;
    ``solve`` returns ``P^-1 g`` with a factorization reused until the next rebuild.
    """

    name: str
    n_builds: int

    def update(self, x: NDArray[np.float64]) -> None: ...

    def solve(self, g: NDArray[np.float64]) -> NDArray[np.float64]: ...

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]: ...


class Counted(Protocol):
    """What a result reports of the linear operator a method used: its name and builds."""

    name: str
    n_builds: int


@dataclass(frozen=True, eq=False)
class MinimizeResult:
    """Outcome of one minimization.

    ``x`` is the final flat vector (the objective's internal order) and ``packing`` the final
    configuration in the caller's order; ``status`` says why the run stopped (``converged`` is
    ``status is Status.CONVERGED``). ``history_energy`` and ``history_max_gradient`` have one
    entry per iteration plus the start (index 0). ``max_gradient`` is ``max_i |grad_i|``
    (Euclidean norm per particle); ``gtol`` the absolute tolerance on it that was used.
    ``precon_builds`` counts preconditioner builds (Hessian factorizations for ``newton``),
    ``linear_iterations`` the inner CG iterations of ``newton`` (0 for the other methods).
    """

    x: NDArray[np.float64]
    packing: Packing
    converged: bool
    status: Status
    message: str
    method: str
    precon: str
    iterations: int
    evaluations: int
    seconds: float
    energy: float
    max_gradient: float
    gtol: float
    history_energy: NDArray[np.float64]
    history_max_gradient: NDArray[np.float64]
    neighbor_rebuilds: int
    precon_builds: int
    linear_iterations: int = 0


@dataclass
class Tracker:
    """Shared bookkeeping of a minimizer run: tolerance, history, timing, final result."""

    objective: Problem
    method: str
    precon: Counted | None
    gtol: float
    maxiter: int
    etol: float = 0.0
    energies: list[float] = field(default_factory=list)
    gradients: list[float] = field(default_factory=list)
    start_time: float = field(default_factory=time.perf_counter)
    start_evaluations: int = 0
    start_rebuilds: int = 0
    linear_iterations: int = 0

    @classmethod
    def start(
        cls,
        objective: Problem,
        method: str,
        precon: Counted | None,
        gtol: float,
        maxiter: int,
        etol: float = 0.0,
    ) -> Tracker:
        """Check the absolute tolerance ``gtol`` on :meth:`Problem.max_gradient`, ``maxiter``
        and ``etol``, the energy at or below which the run also stops, converged."""
        if not np.isfinite(gtol) or gtol < 0.0:
            raise InputError(f"gtol: tolerance must be finite and >= 0, got {gtol}")
        if maxiter < 0:
            raise InputError(f"maxiter: must be >= 0, got {maxiter}")
        if not np.isfinite(etol) or etol < 0.0:
            raise InputError(f"etol: energy tolerance must be finite and >= 0, got {etol}")
        return cls(
            objective,
            method,
            precon,
            float(gtol),
            int(maxiter),
            float(etol),
            start_evaluations=objective.n_evaluations,
            start_rebuilds=objective.n_rebuilds,
        )

    def record(self, energy: float, grad: NDArray[np.float64]) -> bool:
        """Log an iterate; True when it meets the tolerance or its energy is ``<= etol``."""
        gmax = self.objective.max_gradient(grad)
        self.energies.append(energy)
        self.gradients.append(gmax)
        return gmax <= self.gtol or energy <= self.etol

    def extend(self, energies: NDArray[np.float64], gradients: NDArray[np.float64]) -> None:
        """Log iterates recorded elsewhere (compiled code): their energies and largest
        gradients ``(k,)``."""
        self.energies.extend(energies.tolist())
        self.gradients.extend(gradients.tolist())

    @property
    def iterations(self) -> int:
        """Iterations done so far (recorded iterates minus the start)."""
        return len(self.energies) - 1

    def finish(self, x: NDArray[np.float64], status: Status, message: str) -> MinimizeResult:
        """The result at ``x`` (which must be the last recorded iterate)."""
        obj = self.objective
        return MinimizeResult(
            x=x,
            packing=obj.packing(x),  # type: ignore[arg-type]
            converged=status is Status.CONVERGED,
            status=status,
            message=message,
            method=self.method,
            precon=self.precon.name if self.precon is not None else "none",
            iterations=self.iterations,
            evaluations=obj.n_evaluations - self.start_evaluations,
            seconds=time.perf_counter() - self.start_time,
            energy=self.energies[-1],
            max_gradient=self.gradients[-1],
            gtol=self.gtol,
            history_energy=np.array(self.energies),
            history_max_gradient=np.array(self.gradients),
            neighbor_rebuilds=obj.n_rebuilds - self.start_rebuilds,
            precon_builds=self.precon.n_builds if self.precon is not None else 0,
            linear_iterations=self.linear_iterations,
        )
