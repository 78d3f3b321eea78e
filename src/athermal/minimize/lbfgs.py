"""Limited-memory BFGS (the paper's Algorithm 2), optionally preconditioned (its boxed step).

The L-BFGS step with memory ``m`` and the initial inverse Hessian ``H0 = gamma P^-1``
(``P = I`` without a preconditioner), ``gamma = s.y / y.P^-1 y`` of the newest pair (Nocedal &
Wright, eq. 7.20, in the metric of ``P``). Steps come from the strong-Wolfe line search of
:mod:`.linesearch` (``c1 = 1e-4``, ``c2 = 0.9``), unit step tried first.

One solve per iteration: the method keeps ``z = P^-1 g`` and, for each pair, ``P^-1 y =
z_{k+1} - z_k``, so ``H0`` applied to the pairs is a combination of stored vectors
(recomputed by ``m`` solves when ``P`` is rebuilt). The paper's unscaled ``H0 = P^-1`` left the
Exp preconditioner too soft, the unit step never accepted; with ``gamma`` it is the accepted one.

The step is the two-loop recursion's in the compact form of Byrd, Nocedal & Schnabel (1994)
(:mod:`._memory`).

On a problem with a compiled line search (:class:`~.result.CompiledSearch`), without a
preconditioner or with one solved in compiled code (an incomplete factor), whole iterations run
compiled (:func:`~._compiled.iterate`, which CG shares): the direction, the line search with its
evaluations, the solve, the pair and the record. Python takes over, for the rest of that
iteration, where compiled code cannot go on: a trial point the function cannot evaluate there,
a failed search or a direction that does not descend, a preconditioner to rebuild. The same
iterations either way. The accepted point's buffers swap with the iterate's instead of being
copied, and the block maxima (step cap, largest gradient, preconditioner reach) take four blocks
at a time.

Measurements (the scaled ``H0``, the compact step, the compiled iterations):
``docs/decisions.md``, section "L-BFGS".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .._portable import vdot
from ._compiled import CONVERGED, FULL, HEAD, LIMIT, SEARCH, TAIL, CompiledLoop
from ._memory import Memory
from ._step import advance
from .result import MinimizeResult, Preconditioner, Problem, Status, Tracker

C2 = 0.9
"""The line search's curvature constant (the unit step is always tried first)."""


def lbfgs(
    problem: Problem,
    x0: NDArray[np.float64],
    *,
    gtol: float,
    maxiter: int = 100_000,
    etol: float = -np.inf,
    precon: Preconditioner | None = None,
    memory: int = 10,
) -> MinimizeResult:
    """Minimize ``problem`` from ``x0`` ``(n_dof,)`` by (preconditioned) L-BFGS.

    Stops when the largest block of the gradient (:meth:`~.hooks.Hooks.max_gradient`) is
    ``<= gtol`` or the energy is ``<= etol`` (default ``-inf``: never; status ``CONVERGED``),
    after ``maxiter`` iterations (``ITERATION_LIMIT``), or when no step satisfying the Wolfe
    conditions exists even along the (preconditioned) gradient (``LINE_SEARCH_FAILED``).
    """
    tracker = Tracker.start(problem, "lbfgs", precon, gtol, maxiter, etol)
    x = np.array(x0, dtype=np.float64, copy=True)
    energy, grad = problem(x)
    if precon is not None:
        precon.update(x)
    z = precon.solve(grad) if precon is not None else grad
    builds = precon.n_builds if precon is not None else 0
    pairs = Memory(memory, problem.n_dof, precon)
    if tracker.record(energy, grad):
        return tracker.finish(x, Status.CONVERGED, "converged")
    compiled = None
    if CompiledLoop.possible(problem, precon):
        compiled = CompiledLoop(problem, precon, C2, memory=pairs)
    constants = problem.hooks.constants()
    while tracker.iterations < maxiter:
        stop, step, resume = HEAD, None, None  # Python's own iteration, from its start
        if compiled is not None:
            stop, accepted = compiled.run(x, grad, z, energy, tracker, constants)
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
                if not vdot(grad, direction) < 0.0:  # curvature pairs gone stale: restart
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
