"""What L-BFGS and CG share: the line search along a direction, capped per-particle moves."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..objective import Objective
from .linesearch import LineSearchResult, strong_wolfe


def max_particle_step(objective: Objective) -> float:
    """Largest displacement of one particle allowed in one iteration: 0.1 x mean radius."""
    return 0.1 * float(np.mean(objective.radii))


def search(
    objective: Objective,
    x: NDArray[np.float64],
    energy: float,
    grad: NDArray[np.float64],
    direction: NDArray[np.float64],
    step: float,
    c2: float,
) -> LineSearchResult:
    """Strong-Wolfe search along ``direction`` from ``x``; no particle moves more than
    :func:`max_particle_step` (the step is capped so)."""
    longest = objective.max_gradient(direction)  # largest per-particle length of the direction
    step_max = max_particle_step(objective) / max(longest, 1e-300)

    def phi(a: float) -> tuple[float, float]:
        f, g = objective(x + a * direction)
        return f, float(g @ direction)

    return strong_wolfe(
        phi,
        energy,
        float(grad @ direction),
        step,
        c2=c2,
        step_max=step_max,
        noise=objective.energy_noise(energy),
    )
