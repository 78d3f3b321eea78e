"""What every minimizer is given and returns, and the bookkeeping they share.

The minimizers know a :class:`Problem`: ``f`` and ``grad f`` of a flat vector ``x``, its
:class:`~.hooks.Hooks` (the norm of the gradient, the longest step allowed along a direction,
the round-off of ``f``) and, optionally, a line search of ``f`` in compiled code
(:class:`CompiledSearch`).
Nothing here knows particles: the physics builds its problems above this package.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from .hooks import Hooks


@dataclass(frozen=True)
class CompiledSearch:
    """A function's line search in compiled code, for the minimizers' compiled iterations.

    ``function`` is a numba ``njit`` function ``function(state, code, x, direction, trial,
    grad, arguments) -> (code, evaluations, f, tag, stale)`` (called so from Python) and
    ``search`` the same as a compiled first-class function
    (:func:`~.function.compiled_function`, passed to the compiled loops): it feeds the line
    search ``state`` (:mod:`._wolfe`, last code ``code``) the values ``phi(a) = f(x + a
    direction)`` and ``phi'(a)``, writing each trial point into
    ``trial`` and its gradient into ``grad``, until the search ends or a trial point is one it
    cannot evaluate in compiled code (``stale``; ``trial`` then holds the last point evaluated,
    or that point when none was). ``tag`` is an integer the function keeps of its last
    evaluation (the physics: its contact count). ``arguments(x)`` gives the last argument,
    valid near ``x``; ``took(x, f, grad, tag, evaluations)`` takes back what compiled code
    evaluated, the last at ``x``."""

    function: Any
    search: Any
    arguments: Callable[[NDArray[np.float64]], tuple[Any, ...]]
    took: Callable[[NDArray[np.float64], float, NDArray[np.float64], int, int], None]


@runtime_checkable
class Problem(Protocol):
    """A function to minimize, as the minimizers see it: :func:`~athermal.minimize.minimize`
    wraps a plain callable in one (:class:`~athermal.minimize.function.Function`); a caller
    may pass its own (the physics' :class:`~athermal.model.objective.Objective` is one)."""

    n_evaluations: int

    @property
    def n_dof(self) -> int:
        """Length of ``x``."""
        ...

    @property
    def hooks(self) -> Hooks:
        """The stop rule's norm, the step cap and the round-off of ``f``."""
        ...

    def compiled_search(self) -> CompiledSearch | None:
        """The function's own compiled line search, or None (every evaluation from Python)."""
        ...

    def __call__(self, x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        """``f(x)`` and ``grad f(x)`` ``(n_dof,)``."""
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
    n_solves: int

    def update(self, x: NDArray[np.float64]) -> None: ...

    def solve(self, g: NDArray[np.float64]) -> NDArray[np.float64]: ...

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]: ...

    def compiled_solver(self) -> tuple[Any, ...] | None:
        """The factor as compiled code applies it (:func:`~._compiled.solve_at`: the incomplete
        Cholesky factor's arrays, the point it was built at ``(n, d)`` and the squared
        distance within which it holds), or None: solved from Python."""
        ...


class Counted(Protocol):
    """What a result reports of the linear operator a method used: its name and builds."""

    name: str
    n_builds: int


@dataclass(frozen=True, eq=False)
class MinimizeResult:
    """Outcome of one minimization.

    ``x`` is the final flat vector, ``jac`` the gradient there; ``status`` says why the run
    stopped (``converged`` is ``status is Status.CONVERGED``). scipy's names ``fun``, ``nit``,
    ``nfev`` and ``success`` read ``energy``, ``iterations``, ``evaluations`` and
    ``converged``. ``history_energy`` and ``history_max_gradient`` have one
    entry per iteration plus the start (index 0). ``max_gradient`` is ``max_i |grad_i|``
    (Euclidean norm per block of coordinates); ``gtol`` the absolute tolerance on it that was
    used.
    ``precon_builds`` counts preconditioner builds (Hessian factorizations for ``newton``),
    ``linear_iterations`` the inner CG iterations of ``newton`` (0 for the other methods).
    """

    x: NDArray[np.float64]
    jac: NDArray[np.float64]
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
    precon_builds: int
    linear_iterations: int = 0

    @property
    def fun(self) -> float:
        """scipy's name of :attr:`energy`."""
        return self.energy

    @property
    def nit(self) -> int:
        """scipy's name of :attr:`iterations`."""
        return self.iterations

    @property
    def nfev(self) -> int:
        """scipy's name of :attr:`evaluations`."""
        return self.evaluations

    @property
    def success(self) -> bool:
        """scipy's name of :attr:`converged`."""
        return self.converged


@dataclass
class Tracker:
    """Shared bookkeeping of a minimizer run: tolerance, history, timing, final result."""

    objective: Problem
    method: str
    precon: Counted | None
    gtol: float
    maxiter: int
    etol: float = -np.inf
    energies: list[float] = field(default_factory=list)
    gradients: list[float] = field(default_factory=list)
    start_time: float = field(default_factory=time.perf_counter)
    start_evaluations: int = 0
    linear_iterations: int = 0
    last_gradient: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def start(
        cls,
        objective: Problem,
        method: str,
        precon: Counted | None,
        gtol: float,
        maxiter: int,
        etol: float = -np.inf,
    ) -> Tracker:
        """Check the absolute tolerance ``gtol`` on :meth:`~.hooks.Hooks.max_gradient`,
        ``maxiter`` and ``etol``, the energy at or below which the run also stops, converged."""
        if not np.isfinite(gtol) or gtol < 0.0:
            raise InputError(f"gtol: tolerance must be finite and >= 0, got {gtol}")
        if maxiter < 0:
            raise InputError(f"maxiter: must be >= 0, got {maxiter}")
        if np.isnan(etol) or etol == np.inf:
            raise InputError(f"etol: must be a number below inf (-inf: no energy stop), got {etol}")
        return cls(
            objective,
            method,
            precon,
            float(gtol),
            int(maxiter),
            float(etol),
            start_evaluations=objective.n_evaluations,
        )

    def record(self, energy: float, grad: NDArray[np.float64]) -> bool:
        """Log an iterate; True when it meets the tolerance or its energy is ``<= etol``."""
        gmax = self.objective.hooks.max_gradient(grad)
        self.last_gradient = grad
        self.energies.append(energy)
        self.gradients.append(gmax)
        return gmax <= self.gtol or energy <= self.etol

    def extend(
        self,
        energies: NDArray[np.float64],
        gradients: NDArray[np.float64],
        grad: NDArray[np.float64],
    ) -> None:
        """Log iterates recorded elsewhere (compiled code): their energies and largest
        gradients ``(k,)``, and the gradient ``grad`` of the last."""
        if energies.size:
            self.last_gradient = grad
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
            jac=self.last_gradient,
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
            precon_builds=self.precon.n_builds if self.precon is not None else 0,
            linear_iterations=self.linear_iterations,
        )
