"""Nonlinear conjugate gradients: Fletcher-Reeves (seed Algorithms 3 and 4) or Polak-Ribiere+.

With a preconditioner, ``y = P^-1 g`` and ``beta_FR = y_k.g_k / y_{k-1}.g_{k-1}`` (seed
Algorithm 4). Steps satisfy the strong Wolfe conditions with ``c2 = 0.1`` (the curvature bound
that keeps FR directions descent directions); the first trial step follows Nocedal & Wright's
``a_k = a_{k-1} g_{k-1}.p_{k-1} / g_k.p_k``. The method restarts from the (preconditioned)
gradient when a direction is not a descent direction, when a line search fails, and by Powell's
test when consecutive gradients are far from orthogonal, ``|g_{k-1}.y_k| >= 0.1 g_k.y_k``
(Nocedal & Wright, section 5.2): without it FR crawls.

On a problem with a compiled line search, without a preconditioner or with an incomplete
factor, whole iterations run in compiled code (:func:`~._compiled.iterate`, which L-BFGS
shares), ``beta`` and the next direction by the same compiled functions as the Python loop's
(:mod:`._conjugate`), so the iterations are the same.

Measurements (Powell's test, the compiled iterations): ``docs/decisions.md``, section
"Nonlinear CG".
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from .._portable import vdot
from .._validate import choice
from ._compiled import CONVERGED, FULL, LIMIT, SEARCH, TAIL, CompiledLoop
from ._conjugate import RESTARTED, SLOPE, STEP_GUESS, YG, beta_of, next_direction
from ._step import advance
from ._wolfe import STEP
from .result import MinimizeResult, Preconditioner, Problem, Status, Tracker

CGVariant = Literal["fr", "pr+"]
C2 = 0.1
"""The line search's curvature constant."""


def cg(
    problem: Problem,
    x0: NDArray[np.float64],
    *,
    gtol: float,
    maxiter: int = 100_000,
    etol: float = -np.inf,
    precon: Preconditioner | None = None,
    variant: CGVariant = "fr",
) -> MinimizeResult:
    """Minimize ``problem`` from ``x0`` ``(n_dof,)`` by (preconditioned) nonlinear CG.

    ``variant``: ``"fr"`` (Fletcher-Reeves, the paper's) or ``"pr+"`` (Polak-Ribiere+).
    Stopping rules as :func:`~athermal.minimize.lbfgs.lbfgs`.
    """
    choice(variant, "variant", ("fr", "pr+"))
    tracker = Tracker.start(problem, "cg", precon, gtol, maxiter, etol)
    x = np.array(x0, dtype=np.float64, copy=True)
    energy, grad = problem(x)
    if precon is not None:
        precon.update(x)
    if tracker.record(energy, grad):
        return tracker.finish(x, Status.CONVERGED, "converged")
    y = precon.solve(grad) if precon is not None else grad
    direction = -y
    yg = vdot(y, grad)
    slope = -yg
    step = 1.0
    restarted = True
    polak = variant == "pr+"
    compiled = None
    if CompiledLoop.possible(problem, precon):
        compiled = CompiledLoop(problem, precon, C2, polak=polak)
    constants = problem.hooks.constants()
    while tracker.iterations < maxiter:
        resume, accepted = None, None  # Python's own iteration, from its start
        if compiled is not None:
            compiled.scalars[[YG, STEP_GUESS, RESTARTED, SLOPE]] = (
                yg,
                step,
                float(restarted),
                slope,
            )
            compiled.direction[:] = direction
            stop, accepted_energy = compiled.run(x, grad, y, energy, tracker, constants)
            x, grad = compiled.x.copy(), compiled.grad.copy()
            y = compiled.z.copy() if precon is not None else grad
            direction = compiled.direction.copy()
            energy = tracker.energies[-1]
            yg, step, slope = (float(compiled.scalars[k]) for k in (YG, STEP_GUESS, SLOPE))
            restarted = bool(compiled.scalars[RESTARTED])
            if stop == CONVERGED:
                return tracker.finish(x, Status.CONVERGED, "converged")
            if stop in (LIMIT, FULL):
                continue
            if stop == TAIL:  # the step is taken, the preconditioner is Python's
                accepted = (compiled.trial.copy(), accepted_energy, compiled.trial_grad.copy())
                ls_step = float(compiled.state[STEP])
            elif stop == SEARCH:  # the search goes on in Python
                resume = compiled.state.copy()
        if accepted is not None:
            x_new, energy_new, grad_new = accepted
        else:
            if resume is None and not slope < 0.0:
                direction, slope, restarted = -y, -yg, True
            ls, x_new, energy_new, grad_new = advance(
                problem, x, energy, grad, direction, step, C2, resume=resume, slope=slope
            )
            if not ls.ok and not restarted:
                direction, slope, restarted = -y, -yg, True
                ls, x_new, energy_new, grad_new = advance(
                    problem, x, energy, grad, direction, 1.0, C2, slope=slope
                )
            if not ls.ok:
                return tracker.finish(
                    x, Status.LINE_SEARCH_FAILED, "line search failed: no Wolfe step along descent"
                )
            ls_step = ls.step
        x, energy = x_new, energy_new
        if precon is not None:
            precon.update(x)
        y_new = precon.solve(grad_new) if precon is not None else grad_new
        beta, yg = beta_of(y_new, grad_new, grad, yg, polak)
        step, slope = next_direction(ls_step, slope, beta, direction, y_new, grad_new)
        grad, y, restarted = grad_new, y_new, False
        if tracker.record(energy, grad):
            return tracker.finish(x, Status.CONVERGED, "converged")
    return tracker.finish(x, Status.ITERATION_LIMIT, f"iteration limit {maxiter} reached")
