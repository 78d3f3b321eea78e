"""What L-BFGS, CG and Newton share: the line search along a direction, with the problem's step
cap, and the move to the accepted point.

A :class:`CompiledProblem` (an :class:`~athermal.objective.Objective`) is searched without
leaving compiled code: the trial points, the energy kernel and the line search's state machine
run in one call, and control comes back to Python only when the search ends or a trial point
moves beyond where the Verlet list holds; the same iterations as a search driven from Python.
The compiled iterations of L-BFGS and CG (:mod:`._compiled`) go further. Measurements:
``docs/decisions.md``, section "The compiled line search".
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from .._wolfe import GO_ON, TRIAL, feed, resumed
from .linesearch import C1, EPS, MAX_EVALUATIONS, LineSearchResult, started
from .result import Problem


class CompiledProblem(Problem, Protocol):
    """A :class:`Problem` that runs a line search's state machine on its own energy in compiled
    code (:meth:`athermal.objective.Objective.search`; for the compiled iterations, the
    arguments and constants that takes), and takes back what that evaluated."""

    def search(
        self,
        state: NDArray[np.float64],
        code: int,
        x: NDArray[np.float64],
        direction: NDArray[np.float64],
        trial: NDArray[np.float64],
        grad: NDArray[np.float64],
    ) -> tuple[int, int, float, int, bool]:
        """Feed the search ``state`` (:mod:`athermal._wolfe`) trial points ``x + a direction``
        (written into ``trial``, their gradients into ``grad``) until it ends or needs a point
        this problem cannot evaluate in compiled code; returns the code, the evaluations, the
        last energy and contact count, and whether it stopped at such a point."""
        ...

    def search_arguments(self, x: NDArray[np.float64]) -> tuple[Any, ...]:
        """The arguments of :func:`~athermal._wolfe.energy_search` after its first six, valid
        near ``x``."""
        ...

    def search_constants(self) -> tuple[int, float, float, float]:
        """``(d, max_step, noise scale, alpha)`` of :func:`~athermal._kernels.step_limit` and
        :func:`~athermal._kernels.energy_noise`."""
        ...

    def took(
        self,
        x: NDArray[np.float64],
        energy: float,
        grad: NDArray[np.float64],
        contacts: int,
        evaluations: int,
    ) -> None:
        """Count ``evaluations``; the last, at ``x`` with ``energy`` and ``grad``, is cached."""
        ...


def is_compiled(problem: Problem) -> bool:
    """Whether ``problem`` is a :class:`CompiledProblem` (it has ``took``)."""
    return callable(getattr(problem, "took", None))


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
    at :meth:`Problem.step_limit` (for an :class:`~athermal.objective.Objective`: no particle
    moves more than its ``max_step``); returns the result, the accepted point ``x + a
    direction``, its energy and gradient (``x``, ``energy``, ``grad`` themselves when the
    search failed). A :class:`CompiledProblem` evaluates the trial points in compiled code.
    ``resume`` is the state of a search along ``direction`` from ``x`` that compiled code
    began and left at a trial point it could not evaluate, or ended without a step (``step``
    and ``c2`` are then its own). ``slope`` is ``grad.direction`` where the caller has formed it
    (CG, as its compiled loop does: the two then search from the same value)."""
    if resume is None:
        state, code = started(
            energy,
            float(grad @ direction) if slope is None else slope,
            step,
            C1,
            c2,
            problem.step_limit(direction),
            EPS,
            problem.energy_noise(energy),
            MAX_EVALUATIONS,
        )
    else:
        state, code = resume, resumed(resume)
    compiled = is_compiled(problem)
    trial = np.empty_like(x)  # the compiled search's trial points and their gradients
    trial_grad = np.empty_like(x)
    last: tuple[NDArray[np.float64], float, NDArray[np.float64]] | None = None
    while code == GO_ON:
        if compiled:
            code, evaluations, f, contacts, stale = problem.search(  # type: ignore[attr-defined]
                state, code, x, direction, trial, trial_grad
            )
            if evaluations:
                problem.took(trial, f, trial_grad, contacts, evaluations)  # type: ignore[attr-defined]
                last = (trial, f, trial_grad)
            if not stale:
                continue
        # in Python, or a trial point the problem's own call evaluates (renewing its lists)
        point = x + float(state[TRIAL]) * direction
        f, g = problem(point)
        last = (point, f, g)
        code = int(feed(state, f, float(g @ direction)))
    ls = LineSearchResult.of(state, code)
    if not ls.ok:
        return ls, x, energy, grad
    assert last is not None  # an accepted step is the last point evaluated
    return ls, *last
