"""What L-BFGS, CG and Newton share: the line search along a direction, with the problem's step
cap, and the move to the accepted point.

A problem with a compiled line search (:class:`~.result.CompiledSearch`) is searched without
leaving compiled code: the trial points, the function and the line search's state machine run in
one call, and control comes back to Python only when the search ends or a trial point is one the
function cannot evaluate there (the physics: beyond where its Verlet list holds); the same
iterations as a search driven from Python. The compiled iterations of L-BFGS and CG
(:mod:`._compiled`) go further. Measurements: ``docs/decisions.md``, section "The compiled line
search".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .._portable import vdot
from ._wolfe import GO_ON, TRIAL, feed, resumed
from .linesearch import C1, EPS, MAX_EVALUATIONS, LineSearchResult, started
from .result import Problem


def advance(
    problem: Problem,
    x: NDArray[np.float64],
    energy: float,
    grad: NDArray[np.float64],
    direction: NDArray[np.float64],
    step: float,
    c2: float,
    resume: NDArray[np.float64] | None = None,
    slope: float | None = None,
) -> tuple[LineSearchResult, NDArray[np.float64], float, NDArray[np.float64]]:
    """Strong-Wolfe search along ``direction`` from ``x`` from the first trial ``step``, capped
    at :meth:`~.hooks.Hooks.step_limit` (no block moves more than its ``max_step``); returns
    the result, the accepted point ``x + a direction``, its energy and gradient (``x``,
    ``energy``, ``grad`` themselves when the search failed). A problem with a compiled line
    search evaluates the trial points in compiled code.
    ``resume`` is the state of a search along ``direction`` from ``x`` that compiled code
    began and left at a trial point it could not evaluate, or ended without a step (``step``
    and ``c2`` are then its own). ``slope`` is ``grad.direction`` where the caller has formed it
    (CG, as its compiled loop does: the two then search from the same value)."""
    if resume is None:
        state, code = started(
            energy,
            vdot(grad, direction) if slope is None else slope,
            step,
            C1,
            c2,
            problem.hooks.step_limit(direction),
            EPS,
            problem.hooks.energy_noise(energy),
            MAX_EVALUATIONS,
        )
    else:
        state, code = resume, resumed(resume)
    compiled = problem.compiled_search()
    trial = np.empty_like(x)  # the compiled search's trial points and their gradients
    trial_grad = np.empty_like(x)
    last: tuple[NDArray[np.float64], float, NDArray[np.float64]] | None = None
    while code == GO_ON:
        if compiled is not None:
            code, evaluations, f, tag, stale = compiled.function(
                state,
                code,
                np.ascontiguousarray(x),
                np.ascontiguousarray(direction),
                trial,
                trial_grad,
                compiled.arguments(x),
            )
            if evaluations:
                compiled.took(trial, float(f), trial_grad, int(tag), int(evaluations))
                last = (trial, float(f), trial_grad)
            if not stale:
                continue
        # in Python, or a trial point the problem's own call evaluates (the physics renews its
        # Verlet list)
        point = x + float(state[TRIAL]) * direction
        f, g = problem(point)
        last = (point, f, g)
        code = int(feed(state, f, vdot(g, direction)))
    ls = LineSearchResult.of(state, code)
    if not ls.ok:
        return ls, x, energy, grad
    assert last is not None  # an accepted step is the last point evaluated
    return ls, *last
