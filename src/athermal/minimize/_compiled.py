"""The compiled iterations of L-BFGS (:mod:`.lbfgs`) and nonlinear CG (:mod:`.cg`): one loop
for both, on a function that brings its own compiled line search.

A loop runs on a :class:`~.result.Problem` whose :meth:`~.result.Problem.compiled_search` is a
:class:`~.result.CompiledSearch` (the function's energy in compiled code, taken as a
first-class function: the loop is compiled once per signature, whatever the function), with no
preconditioner or one solved in compiled code (an incomplete factor). It stops where compiled
code cannot go on, and Python takes over the rest of that iteration: a search that failed or
reached a trial point the function cannot evaluate there (:data:`SEARCH`), a preconditioner to
rebuild at the accepted point (:data:`TAIL`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .. import _blocks
from .._jit import _jit
from .._portable import dot
from ..linalg import cholesky_solve_columns
from ._conjugate import RESTARTED, SLOPE, STEP_GUESS, YG, beta_of, next_direction
from ._memory import Memory, direction_into, store_pair
from ._wolfe import ACCEPTED, STATE_SIZE, STEP, begin
from .hooks import round_off
from .linesearch import C1, EPS, MAX_EVALUATIONS
from .result import Preconditioner, Problem, Tracker

CONVERGED, LIMIT, FULL, HEAD, SEARCH, TAIL = range(6)
"""What a compiled loop stopped at: convergence, the iteration limit, a full history, a
direction that does not descend (nothing done), a search Python goes on with (its direction and
state kept), a preconditioner to rebuild at the accepted point (in ``trial``, ``trial_grad``)."""

HISTORY = 4096
"""Iterates a compiled loop records before it hands its history to the tracker."""


@_jit
def search_from(
    state, x, direction, trial, trial_grad, energy, slope, step, c2, constants, search, arguments
):
    """The strong-Wolfe search along ``direction`` from ``x`` (``energy``, ``slope``), from the
    first trial ``step`` capped as :meth:`~.hooks.Hooks.step_limit` caps it, with the
    round-off of :meth:`~.hooks.Hooks.energy_noise` (``constants`` are
    :meth:`~.hooks.Hooks.constants`), as :func:`~._step.advance` begins it, run by the
    function's compiled ``search`` on ``arguments``. Returns ``search``'s values."""
    block, max_step, scale, factor, power = constants
    cap = _blocks.step_limit(max_step, direction, block)
    noise = round_off(scale, factor, power, energy)
    code = begin(state, energy, slope, step, C1, c2, cap, EPS, noise, MAX_EVALUATIONS)
    return search(state, code, x, direction, trial, trial_grad, arguments)


@_jit
def solve_at(solver, point, grad, out, block):
    """``out = P^-1 grad`` by the incomplete factor ``solver`` (its arrays, the point of its
    build ``(n, block)`` and its reach), unless ``point`` has moved beyond that reach (the
    preconditioner is due a rebuild): then False, nothing done."""
    arrays, reference, reach_sq = solver
    n = reference.shape[0]
    if _blocks.max_displacement_sq(point.reshape(n, block), reference) > reach_sq:
        return False
    cholesky_solve_columns(*arrays, grad.reshape(n, block), out.reshape(n, block))
    return True


@_jit
def record(history, recorded, energy, grad, block):
    """Log the iterate's energy and largest gradient in column ``recorded`` of ``history``;
    returns that gradient."""
    gmax = _blocks.max_row_norm(grad, block)
    history[0, recorded] = energy
    history[1, recorded] = gmax
    return gmax


@_jit
def _swap_contents(a, b):
    """Exchange the values of the flat arrays ``a`` and ``b`` (same size)."""
    for p in range(a.size):
        a[p], b[p] = b[p], a[p]


@_jit
def accept(x, trial, grad, trial_grad, z, z_new, preconditioned):
    """The accepted point (``trial``, ``trial_grad``, ``z_new``) becomes the iterate: the
    buffers swap roles, nothing is copied. Returns ``x, trial, grad, trial_grad, z, z_new``;
    without a preconditioner ``z`` is the new ``grad``."""
    if preconditioned:
        return trial, x, trial_grad, grad, z_new, z
    return trial, x, trial_grad, grad, trial_grad, z_new


@_jit
def hand_back(x, trial, grad, trial_grad, z, z_new, preconditioned, swapped, last_in_x):
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


@_jit
def iterate(
    x,
    grad,
    z,
    z_new,
    direction,
    trial,
    trial_grad,
    state,
    energy,
    lbfgs,
    memory,
    scalars,
    polak,
    c2,
    history,
    counts,
    tolerances,
    constants,
    search,
    arguments,
    solver,
):
    """L-BFGS (``lbfgs``) or CG iterations in compiled code, the same as :func:`~.lbfgs.lbfgs`'s
    and :func:`~.cg.cg`'s, from ``x``, ``grad``, ``z`` (``P^-1 grad``, or ``grad`` itself
    without a preconditioner) and ``energy``, all updated in place.

    L-BFGS forms each direction from ``memory`` (:meth:`~._memory.Memory.arrays`) and keeps
    each pair there; CG goes on from ``direction`` and ``scalars`` (:data:`~._conjugate.YG`,
    ...) with Fletcher-Reeves or, with ``polak``, Polak-Ribiere+. ``c2`` is the line search's
    curvature constant; ``history`` ``(2, K)`` receives each iterate's energy and largest
    gradient; ``counts`` is ``[iterations, maxiter, recorded, evaluations, solves]``;
    ``tolerances`` ``(gtol, etol)``; ``constants`` the hooks' (:meth:`~.hooks.Hooks.constants`);
    ``search`` and ``arguments`` the function's compiled line search
    (:class:`~.result.CompiledSearch`); ``solver`` the incomplete factor's arrays with the
    point of its build and its reach, or None for no preconditioner. Runs until convergence,
    the iteration limit or a full history, or until the iteration under way needs Python
    (:data:`HEAD` here is an L-BFGS direction that does not descend). Returns the code, the
    energy of the last point evaluated (always in ``trial``, ``trial_grad``), its tag, and the
    energy of the accepted point when stopping at :data:`TAIL`."""
    s, y, py, sy, ypy, gamma, work, rows, ring = memory
    block = constants[0]
    gtol, etol = tolerances
    yg, step, restarted = scalars[YG], scalars[STEP_GUESS], scalars[RESTARTED] != 0.0
    slope = scalars[SLOPE]
    iterations, maxiter, recorded = counts[0], counts[1], counts[2]
    evaluations = 0
    solves = 0
    last_energy = energy
    tag = -1
    accepted = energy
    stop = LIMIT
    swapped = False  # the buffers x, grad, z hold the caller's trial, trial_grad, z_new
    last_in_x = False  # the last point evaluated is the iterate (trial holds an older one)
    while iterations < maxiter:
        if recorded >= history.shape[1]:
            stop = FULL
            break
        if lbfgs:
            direction_into(grad, z, s, y, py, sy, ypy, gamma, work, rows, ring, direction)
            slope = dot(grad, direction)
            step = 1.0
            if not slope < 0.0:
                stop = HEAD
                break
        elif not slope < 0.0:
            for p in range(direction.size):
                direction[p] = -z[p]
            slope, restarted = -yg, True
        code, n_eval, f, n_tag, stale = search_from(
            state,
            x,
            direction,
            trial,
            trial_grad,
            energy,
            slope,
            step,
            c2,
            constants,
            search,
            arguments,
        )
        if n_eval:
            evaluations += n_eval
            last_energy = f
            tag = n_tag
            last_in_x = False
        if stale or code != ACCEPTED:
            stop = SEARCH
            break
        accepted = f
        if solver is None:
            fresh_z = trial_grad
        else:
            if not solve_at(solver, trial, trial_grad, z_new, block):
                stop = TAIL
                break
            solves += 1
            fresh_z = z_new
        if lbfgs:
            store_pair(
                x, trial, grad, trial_grad, z, fresh_z, s, y, py, sy, ypy, gamma, work, rows, ring
            )
        else:
            beta, yg = beta_of(fresh_z, trial_grad, grad, yg, polak)
            step, slope = next_direction(state[STEP], slope, beta, direction, fresh_z, trial_grad)
        x, trial, grad, trial_grad, z, z_new = accept(
            x, trial, grad, trial_grad, z, z_new, solver is not None
        )
        swapped = not swapped
        last_in_x = True
        restarted = False
        energy = f
        gmax = record(history, recorded, energy, grad, block)
        recorded += 1
        iterations += 1
        if gmax <= gtol or energy <= etol:
            stop = CONVERGED
            break
    hand_back(x, trial, grad, trial_grad, z, z_new, solver is not None, swapped, last_in_x)
    scalars[YG], scalars[STEP_GUESS] = yg, step
    scalars[RESTARTED] = 1.0 if restarted else 0.0
    scalars[SLOPE] = slope
    counts[0], counts[2], counts[3], counts[4] = iterations, recorded, evaluations, solves
    return stop, last_energy, tag, accepted


class CompiledLoop:
    """The buffers a compiled loop runs in (``x``, ``grad``, ``z`` = ``P^-1 grad``, ``z_new``,
    ``direction``, the search's ``trial``, ``trial_grad`` and ``state``, CG's ``scalars``, the
    ``history`` and ``counts`` ``[iterations, maxiter, recorded, evaluations, solves]``), and
    the hand-over to Python around a run of :func:`iterate`: L-BFGS with ``memory``, else CG
    (``polak``: Polak-Ribiere+) with the curvature constant ``c2``."""

    def __init__(
        self,
        problem: Problem,
        precon: Preconditioner | None,
        c2: float,
        memory: Memory | None = None,
        polak: bool = False,
    ) -> None:
        n = problem.n_dof
        self.problem, self.precon = problem, precon
        self.c2, self.polak = float(c2), bool(polak)
        self.memory = memory if memory is not None else Memory(1, 1, None)
        self.lbfgs = memory is not None
        self.x, self.grad, self.z = np.empty(n), np.empty(n), np.empty(n)
        self.z_new, self.direction = np.empty(n), np.empty(n)
        self.trial, self.trial_grad = np.empty(n), np.empty(n)
        self.state = np.empty(STATE_SIZE)
        self.scalars = np.zeros(4)
        self.history = np.empty((2, HISTORY))
        self.counts = np.zeros(5, dtype=np.int64)

    @staticmethod
    def possible(problem: Problem, precon: Preconditioner | None) -> bool:
        """Whether the problem has a compiled line search and the preconditioner, if any
        (built), is solved in compiled code."""
        return problem.compiled_search() is not None and (
            precon is None or precon.compiled_solver() is not None
        )

    def run(
        self,
        x: NDArray[np.float64],
        grad: NDArray[np.float64],
        z: NDArray[np.float64],
        energy: float,
        tracker: Tracker,
        constants: tuple[int, float, float, float, float],
    ) -> tuple[int, float]:
        """Iterate from ``x``, ``grad``, ``z``, ``energy`` (copied in; for CG also
        :attr:`direction` and :attr:`scalars`, set by the caller); the results stay in the
        buffers, the iterates go to ``tracker``, the evaluations to the problem, the solves to
        the preconditioner. Returns :func:`iterate`'s code and the accepted energy of a
        :data:`TAIL` stop."""
        compiled = self.problem.compiled_search()
        assert compiled is not None  # :meth:`possible`
        self.x[:] = x
        self.grad[:] = grad
        solver = None
        if self.precon is not None:
            self.z[:] = z
            solver = self.precon.compiled_solver()
        self.counts[:] = (tracker.iterations, tracker.maxiter, 0, 0, 0)
        stop, last_energy, tag, accepted = iterate(
            self.x,
            self.grad,
            self.grad if self.precon is None else self.z,
            self.z_new,
            self.direction,
            self.trial,
            self.trial_grad,
            self.state,
            energy,
            self.lbfgs,
            self.memory.arrays(),
            self.scalars,
            self.polak,
            self.c2,
            self.history,
            self.counts,
            (tracker.gtol, tracker.etol),
            constants,
            compiled.search,
            compiled.arguments(x),
            solver,
        )
        recorded, evaluations, solves = (int(v) for v in self.counts[2:])
        tracker.extend(self.history[0, :recorded], self.history[1, :recorded], self.grad.copy())
        if evaluations:
            compiled.took(
                self.trial.copy(), float(last_energy), self.trial_grad.copy(), int(tag), evaluations
            )
        if self.precon is not None and solves:
            self.precon.n_solves += solves
        return int(stop), float(accepted)
