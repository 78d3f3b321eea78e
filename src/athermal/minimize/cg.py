"""Nonlinear conjugate gradients: Fletcher-Reeves (seed Algorithms 3 and 4) or Polak-Ribiere+.

With a preconditioner, ``y = P^-1 g`` and ``beta_FR = y_k.g_k / y_{k-1}.g_{k-1}`` (seed
Algorithm 4). Steps satisfy the strong Wolfe conditions with ``c2 = 0.1`` (the curvature bound
that keeps FR directions descent directions); the first trial step follows Nocedal & Wright's
``a_k = a_{k-1} g_{k-1}.p_{k-1} / g_k.p_k``. The method restarts from the (preconditioned)
gradient when a direction is not a descent direction, when a line search fails, and by Powell's
test when consecutive gradients are far from orthogonal, ``|g_{k-1}.y_k| >= 0.1 g_k.y_k``
(Nocedal & Wright, section 5.2): without it FR crawls.

On an :class:`~athermal.objective.Objective`, without a preconditioner or with the Exp
preconditioner's incomplete factor, whole iterations run in compiled code (:func:`_iterate`, as
L-BFGS's: :mod:`._compiled`), ``beta`` and the next direction by the same compiled functions as
the Python loop's, so the iterations are the same.

Measurements (Powell's test, the compiled iterations): ``docs/decisions.md``, section
"Nonlinear CG".
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from .._kernels import _jit
from .._validate import choice
from .._wolfe import ACCEPTED, STEP
from ._compiled import (
    CONVERGED,
    FULL,
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

CGVariant = Literal["fr", "pr+"]
C2 = 0.1
"""The line search's curvature constant."""
_POWELL = 0.1  # restart threshold on the overlap of consecutive gradients
_YG, _STEP_GUESS, _RESTARTED, _SLOPE = range(4)
"""Fields of :func:`_iterate`'s ``scalars``: ``y.g`` of the iterate, the next first trial step,
whether the direction is the (preconditioned) gradient, and the slope ``g.p`` along the
direction (the one :func:`_next` formed, or ``-y.g`` for the preconditioned gradient): the
compiled and the Python loop take it from there and never form it again, so that the two go
the same way bit for bit."""


@_jit
def _next(ls_step, slope, beta, direction, y_new, grad_new):  # type: ignore[no-untyped-def]
    """The next direction ``beta direction - y_new``, written into ``direction``, the first
    trial step along it (Nocedal & Wright's ``a_{k-1} g_{k-1}.p_{k-1} / g_k.p_k``, or 1 after a
    restart or where that is not a positive number) and its slope ``g_k.p_k``, in one pass
    (four partial sums, :func:`_beta`'s order)."""
    n = direction.size
    s0 = s1 = s2 = s3 = 0.0
    p = 0
    while p + 4 <= n:
        v0 = beta * direction[p] - y_new[p]
        v1 = beta * direction[p + 1] - y_new[p + 1]
        v2 = beta * direction[p + 2] - y_new[p + 2]
        v3 = beta * direction[p + 3] - y_new[p + 3]
        direction[p], direction[p + 1], direction[p + 2], direction[p + 3] = v0, v1, v2, v3
        s0 += grad_new[p] * v0
        s1 += grad_new[p + 1] * v1
        s2 += grad_new[p + 2] * v2
        s3 += grad_new[p + 3] * v3
        p += 4
    while p < n:
        v0 = beta * direction[p] - y_new[p]
        direction[p] = v0
        s0 += grad_new[p] * v0
        p += 1
    new_slope = (s0 + s1) + (s2 + s3)
    step = ls_step * slope / new_slope if beta else 1.0
    return (step if np.isfinite(step) and step > 0.0 else 1.0), new_slope


@_jit
def _beta(y_new, grad_new, grad, yg, polak):  # type: ignore[no-untyped-def]
    """``(beta, y_new.grad_new)``: zero by Powell's restart test, else Fletcher-Reeves or, with
    ``polak``, Polak-Ribiere+. The three products in one pass, each as four partial sums in a
    fixed order: the same bits whether the compiled loop inlines this or Python calls it (a
    reduction the compiler may reorder, ``fastmath``'s, differs between the two)."""
    n = y_new.size
    a0 = a1 = a2 = a3 = b0 = b1 = b2 = b3 = c0 = c1 = c2 = c3 = 0.0
    p = 0
    while p + 4 <= n:
        y0, y1, y2, y3 = y_new[p], y_new[p + 1], y_new[p + 2], y_new[p + 3]
        a0 += y0 * grad_new[p]
        a1 += y1 * grad_new[p + 1]
        a2 += y2 * grad_new[p + 2]
        a3 += y3 * grad_new[p + 3]
        b0 += y0 * grad[p]
        b1 += y1 * grad[p + 1]
        b2 += y2 * grad[p + 2]
        b3 += y3 * grad[p + 3]
        c0 += y0 * (grad_new[p] - grad[p])
        c1 += y1 * (grad_new[p + 1] - grad[p + 1])
        c2 += y2 * (grad_new[p + 2] - grad[p + 2])
        c3 += y3 * (grad_new[p + 3] - grad[p + 3])
        p += 4
    while p < n:
        a0 += y_new[p] * grad_new[p]
        b0 += y_new[p] * grad[p]
        c0 += y_new[p] * (grad_new[p] - grad[p])
        p += 1
    yg_new, overlap, change = (a0 + a1) + (a2 + a3), (b0 + b1) + (b2 + b3), (c0 + c1) + (c2 + c3)
    if abs(overlap) >= _POWELL * yg_new:
        return 0.0, yg_new
    if not polak:
        return yg_new / yg, yg_new
    return max(0.0, change / yg), yg_new


@_jit
def _iterate(  # type: ignore[no-untyped-def]
    x,
    grad,
    y,
    y_new,
    direction,
    trial,
    trial_grad,
    state,
    energy,
    scalars,
    polak,
    history,
    counts,
    tolerances,
    constants,
    energy_args,
    solver,
):
    """CG iterations in compiled code, the same as :func:`cg`'s, from ``x``, ``grad``, ``y``
    (``P^-1 grad``, or ``grad`` itself without a preconditioner), ``direction``, ``energy``
    and ``scalars`` (:data:`_YG`, ...), all updated in place; ``polak`` for Polak-Ribiere+, the
    other arguments as :func:`~athermal.minimize.lbfgs._iterate`'s. Runs until convergence, the
    iteration limit or a full history, or until the iteration under way needs Python
    (:mod:`._compiled`'s codes). Returns the code, the energy of the last point evaluated
    (always in ``trial``, ``trial_grad``), its contact count, and the energy of the accepted
    point when stopping at :data:`~._compiled.TAIL`."""
    dim = constants[0]
    gtol, etol = tolerances
    yg, step, restarted = scalars[_YG], scalars[_STEP_GUESS], scalars[_RESTARTED] != 0.0
    slope = scalars[_SLOPE]
    iterations, maxiter, recorded = counts[0], counts[1], counts[2]
    evaluations = 0
    solves = 0
    last_energy = energy
    contacts = -1
    accepted = energy
    stop = LIMIT
    swapped = False  # the buffers x, grad, y hold the caller's trial, trial_grad, y_new
    last_in_x = False  # the last point evaluated is the iterate (trial holds an older one)
    while iterations < maxiter:
        if recorded >= history.shape[1]:
            stop = FULL
            break
        if not slope < 0.0:
            for p in range(direction.size):
                direction[p] = -y[p]
            slope, restarted = -yg, True
        code, n_eval, f, n_contacts, stale = search_from(
            state, x, direction, trial, trial_grad, energy, slope, step, C2, constants, energy_args
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
            fresh_y = trial_grad
        else:
            if not solve_at(solver, trial, trial_grad, y_new, dim):
                stop = TAIL
                break
            solves += 1
            fresh_y = y_new
        beta, yg = _beta(fresh_y, trial_grad, grad, yg, polak)
        step, slope = _next(state[STEP], slope, beta, direction, fresh_y, trial_grad)
        x, trial, grad, trial_grad, y, y_new = accept(
            x, trial, grad, trial_grad, y, y_new, solver is not None
        )
        swapped = not swapped
        last_in_x = True
        restarted = False
        energy = f
        gmax = record(history, recorded, energy, grad, dim)
        recorded += 1
        iterations += 1
        if gmax <= gtol or energy <= etol:
            stop = CONVERGED
            break
    hand_back(x, trial, grad, trial_grad, y, y_new, solver is not None, swapped, last_in_x)
    scalars[_YG], scalars[_STEP_GUESS] = yg, step
    scalars[_RESTARTED] = 1.0 if restarted else 0.0
    scalars[_SLOPE] = slope
    counts[0], counts[2], counts[3], counts[4] = iterations, recorded, evaluations, solves
    return stop, last_energy, contacts, accepted


class _Compiled(CompiledLoop):
    """:class:`~._compiled.CompiledLoop` for :func:`_iterate`, with its scalars."""

    def __init__(self, problem: Problem, precon: Preconditioner | None, polak: bool) -> None:
        super().__init__(problem, precon)
        self.polak = polak
        self.scalars = np.zeros(4)

    def run(
        self,
        x: NDArray[np.float64],
        grad: NDArray[np.float64],
        y: NDArray[np.float64],
        direction: NDArray[np.float64],
        energy: float,
        tracker: Tracker,
    ) -> tuple[int, float]:
        """Iterate from ``x``, ``grad``, ``y``, ``direction``, ``energy`` and :attr:`scalars`
        (copied in); the results stay in the buffers, the iterates go to ``tracker``. Returns
        :func:`_iterate`'s code and the accepted energy of a :data:`~._compiled.TAIL` stop."""
        y_buffer, solver, constants, arguments = self.load(x, grad, y, tracker)
        self.direction[:] = direction
        stop, last_energy, contacts, accepted = _iterate(
            self.x,
            self.grad,
            y_buffer,
            self.z_new,
            self.direction,
            self.trial,
            self.trial_grad,
            self.state,
            energy,
            self.scalars,
            self.polak,
            self.history,
            self.counts,
            (tracker.gtol, tracker.etol),
            constants,
            arguments,
            solver,
        )
        self.unload(tracker, last_energy, contacts)
        return int(stop), float(accepted)


def cg(
    problem: Problem,
    x0: NDArray[np.float64],
    *,
    gtol: float,
    maxiter: int = 100_000,
    etol: float = 0.0,
    precon: Preconditioner | None = None,
    variant: CGVariant = "fr",
) -> MinimizeResult:
    """Minimize ``problem`` from ``x0`` ``(n_dof,)`` by (preconditioned) nonlinear CG.

    ``variant``: ``"fr"`` (Fletcher-Reeves, the seed's) or ``"pr+"`` (Polak-Ribiere+).
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
    yg = float(y @ grad)
    slope = -yg
    step = 1.0
    restarted = True
    polak = variant == "pr+"
    compiled = None
    if CompiledLoop.possible(problem, precon):
        compiled = _Compiled(problem, precon, polak)
    while tracker.iterations < maxiter:
        resume, accepted = None, None  # Python's own iteration, from its start
        if compiled is not None:
            compiled.scalars[[_YG, _STEP_GUESS, _RESTARTED, _SLOPE]] = (
                yg,
                step,
                float(restarted),
                slope,
            )
            stop, accepted_energy = compiled.run(x, grad, y, direction, energy, tracker)
            x, grad = compiled.x.copy(), compiled.grad.copy()
            y = compiled.z.copy() if precon is not None else grad
            direction = compiled.direction.copy()
            energy = tracker.energies[-1]
            yg, step, slope = (float(compiled.scalars[k]) for k in (_YG, _STEP_GUESS, _SLOPE))
            restarted = bool(compiled.scalars[_RESTARTED])
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
        beta, yg = _beta(y_new, grad_new, grad, yg, polak)
        step, slope = _next(ls_step, slope, beta, direction, y_new, grad_new)
        grad, y, restarted = grad_new, y_new, False
        if tracker.record(energy, grad):
            return tracker.finish(x, Status.CONVERGED, "converged")
    return tracker.finish(x, Status.ITERATION_LIMIT, f"iteration limit {maxiter} reached")
