"""What the compiled iteration loops of L-BFGS (:mod:`.lbfgs`) and CG (:mod:`.cg`) share: the
line search from an iterate, the preconditioner's solve at the accepted point, the record of an
iterate, the codes a loop stops at, and :class:`CompiledLoop`, the buffers a loop runs in with
its hand-over to Python.

A loop runs on a :class:`~._step.CompiledProblem` (an :class:`~athermal.objective.Objective`)
with no preconditioner or one solved in compiled code (the Exp preconditioner's incomplete
factor). It stops where compiled code cannot go on, and Python takes over the rest of that
iteration: a search that failed or reached a trial point beyond the Verlet skin
(:data:`SEARCH`), a preconditioner to rebuild at the accepted point (:data:`TAIL`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import _kernels
from .._kernels import _jit
from .._wolfe import STATE_SIZE, begin, energy_search
from ._step import is_compiled
from .linesearch import C1, EPS, MAX_EVALUATIONS
from .result import Preconditioner, Problem, Tracker

CONVERGED, LIMIT, FULL, HEAD, SEARCH, TAIL = range(6)
"""What a compiled loop stopped at: convergence, the iteration limit, a full history, a
direction that does not descend (nothing done), a search Python goes on with (its direction and
state kept), a preconditioner to rebuild at the accepted point (in ``trial``, ``trial_grad``)."""

HISTORY = 4096
"""Iterates a compiled loop records before it hands its history to the tracker."""


@_jit
def search_from(  # type: ignore[no-untyped-def]
    state, x, direction, trial, trial_grad, energy, slope, step, c2, constants, energy_args
):
    """The strong-Wolfe search along ``direction`` from ``x`` (``energy``, ``slope``), from the
    first trial ``step`` capped as :meth:`~athermal.objective.Objective.step_limit` caps it,
    as :func:`~._step.advance` begins it; ``constants`` and ``energy_args`` as
    :func:`~athermal.minimize.lbfgs._iterate` takes them. Returns
    :func:`~athermal._wolfe.energy_search`'s values."""
    dim, max_step, noise_scale, alpha = constants
    cap = _kernels.step_limit(max_step, direction, dim)
    noise = _kernels.energy_noise(noise_scale, alpha, energy)
    code = begin(state, energy, slope, step, C1, c2, cap, EPS, noise, MAX_EVALUATIONS)
    return energy_search(state, code, x, direction, trial, trial_grad, *energy_args)


@_jit
def solve_at(solver, point, grad, out, dim):  # type: ignore[no-untyped-def]
    """``out = P^-1 grad`` by the incomplete factor ``solver`` (its arrays, the positions of its
    build and its reach), unless ``point`` has moved beyond that reach (the preconditioner is
    due a rebuild): then False, nothing done."""
    arrays, reference, reach_sq = solver
    n = reference.shape[0]
    if _kernels.max_displacement_sq(point.reshape(n, dim), reference) > reach_sq:
        return False
    _kernels.cholesky_solve_columns(*arrays, grad.reshape(n, dim), out.reshape(n, dim))
    return True


@_jit
def record(history, recorded, energy, grad, dim):  # type: ignore[no-untyped-def]
    """Log the iterate's energy and largest gradient in column ``recorded`` of ``history``;
    returns that gradient."""
    gmax = _kernels.max_row_norm(grad, dim)
    history[0, recorded] = energy
    history[1, recorded] = gmax
    return gmax


@_jit
def _swap_contents(a, b):  # type: ignore[no-untyped-def]
    """Exchange the values of the flat arrays ``a`` and ``b`` (same size)."""
    for p in range(a.size):
        a[p], b[p] = b[p], a[p]


@_jit
def accept(x, trial, grad, trial_grad, z, z_new, preconditioned):  # type: ignore[no-untyped-def]
    """The accepted point (``trial``, ``trial_grad``, ``z_new``) becomes the iterate: the
    buffers swap roles, nothing is copied. Returns ``x, trial, grad, trial_grad, z, z_new``;
    without a preconditioner ``z`` is the new ``grad``."""
    if preconditioned:
        return trial, x, trial_grad, grad, z_new, z
    return trial, x, trial_grad, grad, trial_grad, z_new


@_jit
def hand_back(x, trial, grad, trial_grad, z, z_new, preconditioned, swapped, last_in_x):  # type: ignore[no-untyped-def]
    """At the end of a run, leave the iterate in the caller's ``x``, ``grad``, ``z`` buffers and
    the last point evaluated in its ``trial``, ``trial_grad``: the values swap back after an
    odd number of :func:`accept` (``swapped``), and the iterate is copied into ``trial`` when it
    was the last point evaluated (``last_in_x``)."""
    if swapped:
        _swap_contents(x, trial)
        _swap_contents(grad, trial_grad)
        if preconditioned:
            _swap_contents(z, z_new)
        x, trial, grad, trial_grad = trial, x, trial_grad, grad
    if last_in_x:
        trial[:] = x
        trial_grad[:] = grad


class CompiledLoop:
    """The buffers a compiled loop runs in (``x``, ``grad``, ``z`` = ``P^-1 grad``, ``z_new``,
    ``direction``, the search's ``trial``, ``trial_grad`` and ``state``, the ``history`` and
    ``counts`` ``[iterations, maxiter, recorded, evaluations, solves]``), and the hand-over to
    Python around a run."""

    def __init__(self, problem: Problem, precon: Preconditioner | None) -> None:
        n = problem.n_dof
        self.problem, self.precon = problem, precon
        self.x, self.grad, self.z = np.empty(n), np.empty(n), np.empty(n)
        self.z_new, self.direction = np.empty(n), np.empty(n)
        self.trial, self.trial_grad = np.empty(n), np.empty(n)
        self.state = np.empty(STATE_SIZE)
        self.history = np.empty((2, HISTORY))
        self.counts = np.zeros(5, dtype=np.int64)

    @staticmethod
    def possible(problem: Problem, precon: Preconditioner | None) -> bool:
        """Whether the problem searches in compiled code and the preconditioner, if any (built),
        is solved there."""
        if not is_compiled(problem):
            return False
        solver = getattr(precon, "compiled_solver", None)
        return precon is None or (callable(solver) and solver() is not None)

    def load(
        self,
        x: NDArray[np.float64],
        grad: NDArray[np.float64],
        z: NDArray[np.float64],
        tracker: Tracker,
    ) -> tuple[NDArray[np.float64], Any, Any, Any]:
        """Copy the iterate in; returns the ``z`` buffer (``grad`` itself without a
        preconditioner), the solver's arrays (or None), the problem's search constants and its
        search arguments, all fetched anew (Python may have rebuilt either)."""
        self.x[:] = x
        self.grad[:] = grad
        solver = None
        if self.precon is not None:
            self.z[:] = z
            solver = self.precon.compiled_solver()  # type: ignore[attr-defined]
        self.counts[:] = (tracker.iterations, tracker.maxiter, 0, 0, 0)
        problem = self.problem
        return (
            self.grad if self.precon is None else self.z,
            solver,
            problem.search_constants(),  # type: ignore[attr-defined]
            problem.search_arguments(x),  # type: ignore[attr-defined]
        )

    def unload(self, tracker: Tracker, last_energy: float, contacts: int) -> None:
        """Hand the run's iterates to ``tracker``, its evaluations (the last, at ``trial``, with
        ``last_energy`` and ``contacts``) to the problem and its solves to the
        preconditioner."""
        recorded, evaluations, solves = (int(v) for v in self.counts[2:])
        tracker.extend(self.history[0, :recorded], self.history[1, :recorded])
        if evaluations:
            self.problem.took(  # type: ignore[attr-defined]
                self.trial.copy(), last_energy, self.trial_grad.copy(), contacts, evaluations
            )
        if self.precon is not None and solves:
            self.precon.n_solves += solves  # type: ignore[attr-defined]
