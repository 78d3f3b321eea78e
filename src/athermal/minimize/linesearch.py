"""Line search for the strong Wolfe conditions that keeps working below energy round-off.

Nocedal & Wright's bracketing and zoom (Algorithms 3.5 and 3.6, cubic interpolation) on
``phi(a) = E(x + a p)``. Near a minimum, energy differences ``E(x + a p) - E(x)`` fall below the
round-off of ``E`` long before the gradient reaches ``1e-9`` of the contact forces, and an
energy-based search stalls (as scipy's L-BFGS-B and ASE's PreconLBFGS do). So when
``|phi(a) - phi(0)|`` is below the round-off (``eps |phi(0)|``, or an absolute ``noise`` given by
the caller) energy comparisons are not trusted: sufficient decrease is
judged by Hager & Zhang's approximate Wolfe condition ``phi'(a) <= (1 - 2 c1) |phi'(0)|``
(exact for a quadratic) and interpolation falls back to the secant of ``phi'``.

The search itself is a compiled state machine (:mod:`._wolfe`): :func:`strong_wolfe`
drives it with a Python ``phi``, a function's compiled line search
(:class:`~.result.CompiledSearch`) without leaving compiled code.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ._wolfe import (
    ACCEPTED,
    EVALUATIONS,
    GO_ON,
    SLOPE,
    STATE_SIZE,
    STEP,
    TRIAL,
    VALUE,
    begin,
    feed,
)

Phi = Callable[[float], tuple[float, float]]

C1 = 1e-4
"""Default sufficient-decrease constant."""
EPS = 1e-12
"""Default relative energy round-off."""
MAX_EVALUATIONS = 40
"""Default budget of ``phi`` evaluations of one search."""


@dataclass(frozen=True)
class LineSearchResult:
    """Accepted step ``a`` with ``phi(a)``, ``phi'(a)``; ``ok`` False when none was found."""

    step: float
    value: float
    slope: float
    evaluations: int
    ok: bool

    @classmethod
    def of(cls, state: NDArray[np.float64], code: int) -> LineSearchResult:
        """The result an ended search's ``state`` holds (``code`` from
        :func:`~._wolfe.feed`)."""
        return cls(
            float(state[STEP]),
            float(state[VALUE]),
            float(state[SLOPE]),
            int(state[EVALUATIONS]),
            code == ACCEPTED,
        )


def strong_wolfe(
    phi: Phi,
    f0: float,
    g0: float,
    step: float,
    *,
    c1: float = C1,
    c2: float = 0.9,
    step_max: float = np.inf,
    eps: float = EPS,
    noise: float = 0.0,
    max_evaluations: int = MAX_EVALUATIONS,
) -> LineSearchResult:
    """Find ``a > 0`` with sufficient decrease and ``|phi'(a)| <= c2 |phi'(0)|``.

    Parameters
    ----------
    phi : ``a -> (phi(a), phi'(a))``.
    f0, g0 : ``phi(0)`` and ``phi'(0) < 0``.
    step : first trial step (clipped to ``step_max``).
    c1, c2 : Wolfe constants, ``0 < c1 < c2 < 1``.
    eps, noise : relative and absolute energy round-off; energy differences below the larger
        of ``eps |phi(0)|`` and ``noise`` are not trusted.
    max_evaluations : budget of ``phi`` calls.

    :func:`~._wolfe.feed` says what ends a search.
    """
    state, code = started(f0, g0, step, c1, c2, step_max, eps, noise, max_evaluations)
    while code == GO_ON:
        f, df = phi(float(state[TRIAL]))
        code = int(feed(state, float(f), float(df)))
    return LineSearchResult.of(state, code)


def started(
    f0: float,
    g0: float,
    step: float,
    c1: float,
    c2: float,
    step_max: float,
    eps: float,
    noise: float,
    max_evaluations: int,
) -> tuple[NDArray[np.float64], int]:
    """A new state vector after :func:`~._wolfe.begin`, and its code; ``ValueError``
    unless ``g0 < 0``."""
    if not g0 < 0.0:
        raise ValueError(f"phi'(0) = {g0} is not a descent direction")
    state = np.empty(STATE_SIZE)
    code = begin(state, f0, g0, step, c1, c2, step_max, eps, noise, float(max_evaluations))
    return state, int(code)
