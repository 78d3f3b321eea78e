"""The strong-Wolfe line search of :mod:`.linesearch` as a compiled state machine.

Reverse communication: :func:`begin` sets the search up and names the first trial step, each
:func:`feed` of ``phi(a), phi'(a)`` at the trial step ``state[TRIAL]`` names the next one or
ends the search. :func:`~.linesearch.strong_wolfe` drives it with a Python ``phi``; a
function's compiled line search (:class:`~.result.CompiledSearch`, e.g.
:func:`athermal.model.objective.energy_search`) with its own compiled energy, so that one minimizer
iteration costs a few calls from Python, not dozens.
"""

from __future__ import annotations

import numpy as np

from .._jit import _jit

# The state vector's fields (float64, ``STATE_SIZE``).
(_F0, _G0, _C1, _C2, _EPS, _NOISE, _STEP_MAX, _MAX_EVALS, EVALUATIONS, _ZOOM) = range(10)
(TRIAL, _A_PREV, _F_PREV, _DF_PREV, _LO, _F_LO, _DF_LO, _HI, _F_HI, _DF_HI) = range(10, 20)
(STEP, VALUE, SLOPE, _CODE) = range(20, 24)
STATE_SIZE = 24
"""Length of the state vector of :func:`begin` and :func:`feed`."""
GO_ON, ACCEPTED, FAILED = 0, 1, 2
"""What :func:`begin` and :func:`feed` return: evaluate ``phi`` at ``state[TRIAL]`` next; the
search ended at ``state[STEP]`` (``phi`` there ``state[VALUE]``, ``phi'`` ``state[SLOPE]``,
after ``state[EVALUATIONS]`` evaluations) with a Wolfe step, or without one (the last point with
sufficient decrease, or 0)."""


@_jit
def begin(state, f0, g0, step, c1, c2, step_max, eps, noise, max_evaluations):
    """Start a search from ``phi(0) = f0``, ``phi'(0) = g0 < 0`` with the first trial step
    ``min(step, step_max)`` (parameters as :func:`~athermal.minimize.linesearch.strong_wolfe`);
    returns :data:`GO_ON`, or :data:`FAILED` for a zero budget."""
    state[_F0], state[_G0], state[_C1], state[_C2] = f0, g0, c1, c2
    state[_EPS], state[_NOISE], state[_STEP_MAX] = eps, noise, step_max
    state[_MAX_EVALS], state[EVALUATIONS], state[_ZOOM] = max_evaluations, 0.0, 0.0
    state[_A_PREV], state[_F_PREV], state[_DF_PREV] = 0.0, f0, g0
    state[TRIAL] = min(step, step_max)
    state[_CODE] = GO_ON
    if max_evaluations <= 0:
        return _end(state, 0.0, f0, g0, FAILED)
    return GO_ON


@_jit
def _end(state, a, f, df, code):
    state[STEP], state[VALUE], state[SLOPE], state[_CODE] = a, f, df, code
    return code


def resumed(state: np.ndarray) -> int:
    """The code of the search ``state`` (:data:`GO_ON` while it goes on)."""
    return int(state[_CODE])


@_jit
def _resolved(state, f, f_ref):
    """True when ``f`` and ``f_ref`` differ by more than the energy round-off."""
    return abs(f - f_ref) > max(state[_EPS] * abs(state[_F0]), state[_NOISE])


@_jit
def _decrease(state, a, f, df):
    if _resolved(state, f, state[_F0]):
        return f <= state[_F0] + state[_C1] * a * state[_G0]
    return df <= (1.0 - 2.0 * state[_C1]) * abs(state[_G0])


@_jit
def _curvature(state, df):
    return abs(df) <= state[_C2] * abs(state[_G0])


@_jit
def _zoom_next(state):
    """The next trial inside ``[lo, hi]``, or the end of the budget at ``lo``."""
    if state[EVALUATIONS] >= state[_MAX_EVALS]:
        return _end(state, state[_LO], state[_F_LO], state[_DF_LO], FAILED)
    state[TRIAL] = _interpolate(state)
    return GO_ON


@_jit
def _set(state, at, a, f, df):
    state[at], state[at + 1], state[at + 2] = a, f, df


@_jit
def feed(state, f, df):
    """Take ``phi, phi'`` at ``state[TRIAL]``; returns :data:`GO_ON` (the next trial is in
    ``state[TRIAL]``), :data:`ACCEPTED` or :data:`FAILED`.

    Bracketing grows the step fourfold while ``phi`` descends with sufficient decrease; zoom
    shrinks a bracket ``[lo, hi]`` whose ``lo`` has sufficient decrease. A zero energy with a
    zero slope (an unjammed packing) is accepted at once: it cannot be improved. When
    ``step_max`` stops the bracketing while ``phi`` still descends, the capped step is accepted
    (sufficient decrease holds, the curvature condition may not)."""
    state[EVALUATIONS] += 1.0
    a = state[TRIAL]
    if f == 0.0 and df == 0.0:
        return _end(state, a, f, df, ACCEPTED)
    if state[_ZOOM] == 0.0:
        a_prev, f_prev, df_prev = state[_A_PREV], state[_F_PREV], state[_DF_PREV]
        if not _decrease(state, a, f, df) or (
            _resolved(state, f, f_prev) and f >= f_prev and a_prev > 0.0
        ):
            state[_ZOOM] = 1.0
            _set(state, _LO, a_prev, f_prev, df_prev)
            _set(state, _HI, a, f, df)
            return _zoom_next(state)
        if _curvature(state, df):
            return _end(state, a, f, df, ACCEPTED)
        if df >= 0.0:
            state[_ZOOM] = 1.0
            _set(state, _LO, a, f, df)
            _set(state, _HI, a_prev, f_prev, df_prev)
            return _zoom_next(state)
        if a >= state[_STEP_MAX]:
            return _end(state, a, f, df, ACCEPTED)
        _set(state, _A_PREV, a, f, df)
        if state[EVALUATIONS] >= state[_MAX_EVALS]:
            return _end(state, a, f, df, FAILED)
        state[TRIAL] = min(4.0 * a, state[_STEP_MAX])
        return GO_ON
    if not _decrease(state, a, f, df) or (_resolved(state, f, state[_F_LO]) and f >= state[_F_LO]):
        _set(state, _HI, a, f, df)
        return _zoom_next(state)
    if _curvature(state, df):
        return _end(state, a, f, df, ACCEPTED)
    if df * (state[_HI] - state[_LO]) >= 0.0:
        _set(state, _HI, state[_LO], state[_F_LO], state[_DF_LO])
    _set(state, _LO, a, f, df)
    return _zoom_next(state)


@_jit
def _interpolate(state):
    """Cubic minimizer of the bracket's end points (secant of ``phi'`` below round-off), kept
    inside the middle 80 % of the bracket."""
    lo, f_lo, df_lo = state[_LO], state[_F_LO], state[_DF_LO]
    hi, f_hi, df_hi = state[_HI], state[_F_HI], state[_DF_HI]
    width = hi - lo
    trial = np.nan
    if _resolved(state, f_hi, f_lo):
        d1 = df_lo + df_hi - 3.0 * (f_lo - f_hi) / (lo - hi)
        disc = d1 * d1 - df_lo * df_hi
        if disc >= 0.0:
            d2 = np.sign(hi - lo) * np.sqrt(disc)
            denom = df_hi - df_lo + 2.0 * d2
            if denom != 0.0:
                trial = hi - width * (df_hi + d2 - d1) / denom
    if not np.isfinite(trial) and df_hi != df_lo:
        trial = lo - df_lo * width / (df_hi - df_lo)
    low = min(lo + 0.1 * width, hi - 0.1 * width)
    high = max(lo + 0.1 * width, hi - 0.1 * width)
    if not np.isfinite(trial):
        return lo + 0.5 * width
    return min(max(trial, low), high)
