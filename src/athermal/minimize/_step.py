"""What L-BFGS and CG share: the line search along a direction, with the problem's step cap."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .linesearch import LineSearchResult, strong_wolfe
from .result import Problem


def search(
    problem: Problem,
    x: NDArray[np.float64],
    energy: float,
    grad: NDArray[np.float64],
    direction: NDArray[np.float64],
    step: float,
    c2: float,
) -> LineSearchResult:
    """Strong-Wolfe search along ``direction`` from ``x``, the step capped at
    :meth:`Problem.step_limit` (for an :class:`~athermal.objective.Objective`: no particle moves
    more than its ``max_step``)."""

    def phi(a: float) -> tuple[float, float]:
        f, g = problem(x + a * direction)
        return f, float(g @ direction)

    return strong_wolfe(
        phi,
        energy,
        float(grad @ direction),
        step,
        c2=c2,
        step_max=problem.step_limit(direction),
        noise=problem.energy_noise(energy),
    )
