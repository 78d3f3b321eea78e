"""Limited-memory BFGS (seed Algorithm 2), optionally preconditioned (seed's boxed step).

The L-BFGS step with memory ``m`` and the initial inverse Hessian ``H0 = gamma P^-1``
(``P = I`` without a preconditioner), ``gamma = s.y / y.P^-1 y`` of the newest pair (Nocedal &
Wright, eq. 7.20, in the metric of ``P``). Steps come from the strong-Wolfe line search of
:mod:`.linesearch` (``c1 = 1e-4``, ``c2 = 0.9``), unit step tried first.

One solve per iteration: the method keeps ``z = P^-1 g`` and, for each pair, ``P^-1 y =
z_{k+1} - z_k``, so ``H0`` applied to the pairs is a combination of stored vectors
(recomputed by ``m`` solves when ``P`` is rebuilt). The seed's unscaled ``H0 = P^-1`` left the
Exp preconditioner too soft, the unit step never accepted; with ``gamma`` it is the accepted one.

The step is the two-loop recursion's (Nocedal & Wright, Algorithm 7.4) in the compact form of
Byrd, Nocedal & Schnabel (1994): two blocked passes over the stored ``s`` and ``P^-1 y`` and
``O(m^2)`` work on their dot products, kept from one iteration to the next (the recursion
streams ``s``, ``y`` and ``P^-1 y`` about five times).

On a problem that searches in compiled code (:class:`~._step.CompiledProblem`, an
:class:`~athermal.objective.Objective`), without a preconditioner or with one solved in compiled
code (the Exp preconditioner's incomplete factor), whole iterations run compiled
(:func:`_iterate`): the direction, the line search with its evaluations, the solve, the pair and
the record. Python takes over, for the rest of that iteration, where compiled code cannot go on:
a trial point beyond the Verlet skin, a failed search or a direction that does not descend, a
preconditioner to rebuild. The same iterations either way. The accepted point's buffers swap
with the iterate's instead of being copied (the loop's shared parts: :mod:`._compiled`), and the
row maxima (step cap, largest gradient, Verlet and preconditioner reach) take four rows at a time.

Measurements (the scaled ``H0``, the compact step, the compiled iterations):
``docs/decisions.md``, section "L-BFGS".
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import _kernels
from .._kernels import _jit
from .._wolfe import ACCEPTED
from ._compiled import (
    CONVERGED,
    FULL,
    HEAD,
    LIMIT,
    SEARCH,
    TAIL,
    CompiledLoop,
    accept,
    hand_back,
    record,
    search_from,
    solve_at,
)
from ._step import advance
from .result import MinimizeResult, Preconditioner, Problem, Status, Tracker

C2 = 0.9
"""The line search's curvature constant (the unit step is always tried first)."""
_COUNT, _FREE, _FRESH = 0, 1, 2
"""Fields of :attr:`_Memory.ring`: pairs kept, the row the next pair goes to, and whether the
newest pair's dot products with the others are still due (0 / 1)."""


class _Memory:
    """The last ``m`` pairs ``s = x_{k+1} - x_k``, ``y = g_{k+1} - g_k`` and ``P^-1 y`` in ring
    buffers of ``m + 1`` rows ``(m + 1, n)`` (a new pair is written into the free row, so a
    rejected pair costs no stored one), with their dot products ``s_a.y_b`` and
    ``y_a.P^-1 y_b`` ``(m + 1, m + 1)`` for the compact form; without a preconditioner
    ``P^-1 y`` is ``y`` (the same buffer). ``rows`` ``(m,)`` lists the rows in use, oldest
    first; ``ring`` holds the counters (:data:`_COUNT`, :data:`_FREE`, :data:`_FRESH`), so that
    compiled code updates them as Python does."""

    def __init__(self, m: int, n: int, precon: Preconditioner | None) -> None:
        self.m = m
        self.s = np.zeros((m + 1, n))
        self.y = np.zeros((m + 1, n))
        self.py = np.zeros((m + 1, n)) if precon is not None else self.y
        self.sy = np.zeros((m + 1, m + 1))
        self.ypy = np.zeros((m + 1, m + 1))
        self.gamma = np.zeros(m + 1)
        self.work = np.zeros((4, m + 1))
        self.rows = np.zeros(m, dtype=np.int64)
        self.ring = np.zeros(3, dtype=np.int64)

    def __len__(self) -> int:
        return int(self.ring[_COUNT])

    @property
    def order(self) -> NDArray[np.int64]:
        """The rows in use, oldest first."""
        return self.rows[: self.ring[_COUNT]]

    @property
    def slots(self) -> list[int]:
        """:attr:`order` as a list."""
        return [int(r) for r in self.order]

    @property
    def fresh(self) -> bool:
        """The newest pair's dot products with the others are still due."""
        return bool(self.ring[_FRESH])

    @fresh.setter
    def fresh(self, value: bool) -> None:
        self.ring[_FRESH] = int(value)

    def arrays(self) -> tuple[NDArray[Any], ...]:
        """The buffers compiled code works on: ``s, y, py, sy, ypy, gamma, work, rows, ring``."""
        return (
            self.s,
            self.y,
            self.py,
            self.sy,
            self.ypy,
            self.gamma,
            self.work,
            self.rows,
            self.ring,
        )

    def clear(self) -> None:
        self.ring[_COUNT] = 0
        self.ring[_FRESH] = 0

    def store(
        self,
        x: NDArray[np.float64],
        x_new: NDArray[np.float64],
        grad: NDArray[np.float64],
        grad_new: NDArray[np.float64],
        z: NDArray[np.float64],
        z_new: NDArray[np.float64],
        precon: Preconditioner | None = None,
    ) -> None:
        """Form and keep the pair of the step ``x -> x_new`` (``z = P^-1 grad``, or ``grad``
        without a preconditioner); ``P^-1 y`` by the solve of ``precon`` when given (``P`` was
        just rebuilt, so ``z_new - z`` mixes two matrices). Kept only when ``s.y > 0`` and
        ``y.P^-1 y > 0``; its dot products with the other pairs are formed by the next
        :meth:`direction`."""
        if precon is None:
            _store_pair(x, x_new, grad, grad_new, z, z_new, *self.arrays())
            return
        _complete_newest(*self.arrays())
        row = int(self.ring[_FREE])
        sy, _ = _kernels.lbfgs_pair(
            x, x_new, grad, grad_new, z, z_new, self.s[row], self.y[row], self.py[row]
        )
        self.py[row] = precon.solve(self.y[row])
        _keep(row, sy, float(self.y[row] @ self.py[row]), *self.arrays())

    def refresh(self, precon: Preconditioner) -> None:
        """Recompute ``P^-1 y``, ``gamma`` and ``y.P^-1 y`` of every stored pair after ``P``
        was rebuilt."""
        for slot in self.slots:
            self.py[slot] = precon.solve(self.y[slot])
            ypy = float(self.y[slot] @ self.py[slot])
            if not ypy > 0.0:  # cannot happen for an SPD P; keep the direction well defined
                self.clear()
                return
            self.gamma[slot] = self.sy[slot, slot] / ypy
        rows = self.order
        products = self.y[rows] @ self.py[rows].T
        self.ypy[np.ix_(rows, rows)] = 0.5 * (products + products.T)

    def direction(self, grad: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.float64]:
        """``-H grad`` by the compiled compact form, with ``z = P^-1 grad``."""
        out = np.empty_like(grad)
        _direction(grad, z, *self.arrays(), out)  # type: ignore[call-arg]
        return out


@_jit
def _complete_newest(s, y, py, sy, ypy, gamma, work, rows, ring):  # type: ignore[no-untyped-def]
    """Form the newest pair's dot products with the others now, if still due (a pair stored
    without a direction after it; the minimizer never does this)."""
    if ring[_FRESH] == 0:
        return
    count = ring[_COUNT]
    newest = rows[count - 1]
    for t in range(count):
        r = rows[t]
        sy[r, newest] = np.dot(s[r], y[newest])
        ypy[r, newest] = ypy[newest, r] = np.dot(py[r], y[newest])
    ring[_FRESH] = 0


@_jit
def _keep(row, sy_row, ypy_row, s, y, py, sy, ypy, gamma, work, rows, ring):  # type: ignore[no-untyped-def]
    """Keep the pair just written into ``row`` (``s.y = sy_row``, ``y.P^-1 y = ypy_row``) when
    both are > 0, dropping the oldest of a full memory."""
    if not (sy_row > 0.0 and ypy_row > 0.0):
        return
    gamma[row] = sy_row / ypy_row
    sy[row, row] = sy_row
    ypy[row, row] = ypy_row
    m = rows.size
    count = ring[_COUNT]
    if count == m:
        for t in range(m - 1):
            rows[t] = rows[t + 1]
        rows[m - 1] = row
    else:
        rows[count] = row
        ring[_COUNT] = count + 1
    ring[_FREE] = (row + 1) % (m + 1)
    ring[_FRESH] = 1


@_jit
def _store_pair(x, x_new, g, g_new, z, z_new, s, y, py, sy, ypy, gamma, work, rows, ring):  # type: ignore[no-untyped-def]
    """:meth:`_Memory.store` without a rebuilt preconditioner."""
    _complete_newest(s, y, py, sy, ypy, gamma, work, rows, ring)
    row = ring[_FREE]
    sy_row, ypy_row = _kernels.lbfgs_pair(x, x_new, g, g_new, z, z_new, s[row], y[row], py[row])
    _keep(row, sy_row, ypy_row, s, y, py, sy, ypy, gamma, work, rows, ring)


@_jit
def _direction(grad, z, s, y, py, sy, ypy, gamma, work, rows, ring, out):  # type: ignore[no-untyped-def]
    """:meth:`_Memory.direction` into ``out``."""
    count = ring[_COUNT]
    newest = y[rows[count - 1]] if count > 0 else grad
    _kernels.lbfgs_direction(
        grad, z, s, py, newest, ring[_FRESH] == 1, sy, ypy, gamma, rows[:count], work, out
    )
    ring[_FRESH] = 0


@_jit
def _iterate(  # type: ignore[no-untyped-def]
    x,
    grad,
    z,
    z_new,
    direction,
    trial,
    trial_grad,
    state,
    energy,
    memory,
    history,
    counts,
    tolerances,
    constants,
    energy_args,
    solver,
):
    """L-BFGS iterations in compiled code, the same as :func:`lbfgs`'s, from ``x``, ``grad``,
    ``z`` (``grad`` itself without a preconditioner) and ``energy``, all updated in place.

    ``memory`` is :meth:`_Memory.arrays`; ``history`` ``(2, K)`` receives each iterate's energy
    and largest gradient; ``counts`` is ``[iterations, maxiter, recorded, evaluations,
    solves]``; ``tolerances`` ``(gtol, etol)``; ``constants`` the problem's ``(d, max_step,
    noise scale, alpha)``; ``energy_args`` the rest of :func:`~athermal._wolfe.energy_search`'s
    arguments; ``solver`` the incomplete factor's arrays with the positions of its build and
    its reach, or None for no preconditioner. Runs until convergence, the iteration limit or a
    full history, or until the iteration under way needs Python (the codes of
    :mod:`._compiled`: :data:`~._compiled.HEAD` here is a direction that does not descend).
    Returns the code, the energy of the last point evaluated (always in ``trial``,
    ``trial_grad``), its contact count, and the energy of the accepted point when stopping at
    :data:`~._compiled.TAIL`."""
    s, y, py, sy, ypy, gamma, work, rows, ring = memory
    dim = constants[0]
    gtol, etol = tolerances
    iterations, maxiter, recorded = counts[0], counts[1], counts[2]
    evaluations = 0
    solves = 0
    last_energy = energy
    contacts = -1
    accepted = energy
    stop = LIMIT
    swapped = False  # the buffers x, grad, z hold the caller's trial, trial_grad, z_new
    last_in_x = False  # the last point evaluated is the iterate (trial holds an older one)
    while iterations < maxiter:
        if recorded >= history.shape[1]:
            stop = FULL
            break
        _direction(grad, z, s, y, py, sy, ypy, gamma, work, rows, ring, direction)
        slope = np.dot(grad, direction)
        if not slope < 0.0:
            stop = HEAD
            break
        code, n_eval, f, n_contacts, stale = search_from(
            state, x, direction, trial, trial_grad, energy, slope, 1.0, C2, constants, energy_args
        )
        if n_eval:
            evaluations += n_eval
            last_energy = f
            contacts = n_contacts
            last_in_x = False
        if stale or code != ACCEPTED:
            stop = SEARCH
            break
        accepted = f
        if solver is None:
            fresh_z = trial_grad
        else:
            if not solve_at(solver, trial, trial_grad, z_new, dim):
                stop = TAIL
                break
            solves += 1
            fresh_z = z_new
        _store_pair(
            x, trial, grad, trial_grad, z, fresh_z, s, y, py, sy, ypy, gamma, work, rows, ring
        )
        x, trial, grad, trial_grad, z, z_new = accept(
            x, trial, grad, trial_grad, z, z_new, solver is not None
        )
        swapped = not swapped
        last_in_x = True
        energy = f
        gmax = record(history, recorded, energy, grad, dim)
        recorded += 1
        iterations += 1
        if gmax <= gtol or energy <= etol:
            stop = CONVERGED
            break
    hand_back(x, trial, grad, trial_grad, z, z_new, solver is not None, swapped, last_in_x)
    counts[0], counts[2], counts[3], counts[4] = iterations, recorded, evaluations, solves
    return stop, last_energy, contacts, accepted


class _Compiled(CompiledLoop):
    """:class:`~._compiled.CompiledLoop` for :func:`_iterate`, with the L-BFGS memory."""

    def __init__(self, problem: Problem, precon: Preconditioner | None, pairs: _Memory) -> None:
        super().__init__(problem, precon)
        self.pairs = pairs

    def run(
        self,
        x: NDArray[np.float64],
        grad: NDArray[np.float64],
        z: NDArray[np.float64],
        energy: float,
        tracker: Tracker,
    ) -> tuple[int, float]:
        """Iterate from ``x``, ``grad``, ``z``, ``energy`` (copied in); the results stay in the
        buffers, the iterates go to ``tracker``. Returns :func:`_iterate`'s code and the
        accepted energy of a :data:`~._compiled.TAIL` stop."""
        z_buffer, solver, constants, arguments = self.load(x, grad, z, tracker)
        stop, last_energy, contacts, accepted = _iterate(
            self.x,
            self.grad,
            z_buffer,
            self.z_new,
            self.direction,
            self.trial,
            self.trial_grad,
            self.state,
            energy,
            self.pairs.arrays(),
            self.history,
            self.counts,
            (tracker.gtol, tracker.etol),
            constants,
            arguments,
            solver,
        )
        self.unload(tracker, last_energy, contacts)
        return int(stop), float(accepted)


def lbfgs(
    problem: Problem,
    x0: NDArray[np.float64],
    *,
    gtol: float,
    maxiter: int = 100_000,
    etol: float = 0.0,
    precon: Preconditioner | None = None,
    memory: int = 10,
) -> MinimizeResult:
    """Minimize ``problem`` from ``x0`` ``(n_dof,)`` by (preconditioned) L-BFGS.

    Stops when ``problem.max_gradient(grad) <= gtol`` or the energy is ``<= etol`` (default:
    exactly zero; status ``CONVERGED``), after ``maxiter`` iterations (``ITERATION_LIMIT``), or
    when no step satisfying the Wolfe conditions exists even along the (preconditioned)
    gradient (``LINE_SEARCH_FAILED``).
    """
    tracker = Tracker.start(problem, "lbfgs", precon, gtol, maxiter, etol)
    x = np.array(x0, dtype=np.float64, copy=True)
    energy, grad = problem(x)
    if precon is not None:
        precon.update(x)
    z = precon.solve(grad) if precon is not None else grad
    builds = precon.n_builds if precon is not None else 0
    pairs = _Memory(memory, problem.n_dof, precon)
    if tracker.record(energy, grad):
        return tracker.finish(x, Status.CONVERGED, "converged")
    compiled = _Compiled(problem, precon, pairs) if CompiledLoop.possible(problem, precon) else None
    while tracker.iterations < maxiter:
        stop, step, resume = HEAD, None, None  # Python's own iteration, from its start
        if compiled is not None:
            stop, accepted = compiled.run(x, grad, z, energy, tracker)
            x, grad = compiled.x.copy(), compiled.grad.copy()
            z = compiled.z.copy() if precon is not None else grad
            energy = tracker.energies[-1]
            if stop == CONVERGED:
                return tracker.finish(x, Status.CONVERGED, "converged")
            if stop in (LIMIT, FULL):
                continue
            if stop == TAIL:  # the step is taken, the preconditioner is Python's
                step = (compiled.trial.copy(), accepted, compiled.trial_grad.copy())
            elif stop == SEARCH:  # the search goes on in Python
                direction, resume = compiled.direction.copy(), compiled.state.copy()
        if step is not None:
            x_new, energy_new, grad_new = step
        else:
            if resume is None:
                direction = pairs.direction(grad, z)
                if not float(grad @ direction) < 0.0:  # curvature pairs gone stale: restart
                    pairs.clear()
                    direction = -z
            ls, x_new, energy_new, grad_new = advance(
                problem, x, energy, grad, direction, 1.0, C2, resume=resume
            )
            if not ls.ok and pairs:
                pairs.clear()  # stale curvature pairs: restart from the (preconditioned) gradient
                direction = -z
                ls, x_new, energy_new, grad_new = advance(
                    problem, x, energy, grad, direction, 1.0, C2
                )
            if not ls.ok:
                return tracker.finish(
                    x, Status.LINE_SEARCH_FAILED, "line search failed: no Wolfe step along descent"
                )
        energy = energy_new
        rebuilt = False
        if precon is not None:
            precon.update(x_new)
            rebuilt, builds = precon.n_builds != builds, precon.n_builds
        z_new = precon.solve(grad_new) if precon is not None else grad_new
        if rebuilt:
            assert precon is not None
            pairs.refresh(precon)
        pairs.store(x, x_new, grad, grad_new, z, z_new, precon if rebuilt else None)
        x, grad, z = x_new, grad_new, z_new
        if tracker.record(energy, grad):
            return tracker.finish(x, Status.CONVERGED, "converged")
    return tracker.finish(x, Status.ITERATION_LIMIT, f"iteration limit {maxiter} reached")
