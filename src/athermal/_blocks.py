"""Compiled loops over a flat vector read as blocks of ``d`` coordinates (one particle each):
the largest block norm, the largest gap to a reference with the trial point written on the way,
the step cap, and an exact comparison. The minimizers (their stop rule and step limit) and the
physics (Verlet and preconditioner reach) share them.
"""

from __future__ import annotations

import numpy as np

from ._jit import _jit


@_jit
def _row_norm_sq(v, p, dim):  # type: ignore[no-untyped-def]
    """``|v_p|^2`` of the ``dim``-vector at flat offset ``p``."""
    s = 0.0
    for k in range(dim):
        s += v[p + k] * v[p + k]
    return s


@_jit
def _row_gap_sq(u, v, a, w, p, dim):  # type: ignore[no-untyped-def]
    """``|(u + a v) - w|^2`` of the ``dim``-vectors at flat offset ``p``: ``u + a v`` rounds as
    the trial points of :func:`~athermal.model.objective.energy_search` do, so that the compiled and
    the Python reach tests agree on the point evaluated."""
    s = 0.0
    for k in range(dim):
        t = (u[p + k] + a * v[p + k]) - w[p + k]
        s += t * t
    return s


@_jit
def _row_place_sq(u, v, a, w, out, p, dim):  # type: ignore[no-untyped-def]
    """:func:`_row_gap_sq`, writing ``u + a v`` into ``out`` on the way (the same bits)."""
    s = 0.0
    for k in range(dim):
        t = u[p + k] + a * v[p + k]
        out[p + k] = t
        t = t - w[p + k]
        s += t * t
    return s


NORM, GAP, PLACE = range(3)
"""Modes of :func:`max_row_sq`: the rows' norms, their gaps, their gaps with the points
written."""


@_jit
def _row_sq(u, v, a, w, out, p, dim, mode):  # type: ignore[no-untyped-def]
    """:func:`_row_norm_sq` of ``u``, :func:`_row_gap_sq` or :func:`_row_place_sq` by
    ``mode``."""
    if mode == PLACE:
        return _row_place_sq(u, v, a, w, out, p, dim)
    if mode == GAP:
        return _row_gap_sq(u, v, a, w, p, dim)
    return _row_norm_sq(u, p, dim)


@_jit
def _max_row_sq(u, v, a, w, out, dim, mode):  # type: ignore[no-untyped-def]
    """``max_i`` of :func:`_row_sq` over the ``dim``-vectors of the flat arrays, four rows at a
    time: four running maxima, where one waits on the last comparison (measurements:
    ``docs/decisions.md``, section "Compiled kernels"). Called with a literal ``dim`` and
    ``mode``, which the compiler folds in."""
    rows = u.size // dim
    b0 = b1 = b2 = b3 = 0.0
    i = 0
    while i + 4 <= rows:
        p = i * dim
        b0 = max(b0, _row_sq(u, v, a, w, out, p, dim, mode))
        b1 = max(b1, _row_sq(u, v, a, w, out, p + dim, dim, mode))
        b2 = max(b2, _row_sq(u, v, a, w, out, p + 2 * dim, dim, mode))
        b3 = max(b3, _row_sq(u, v, a, w, out, p + 3 * dim, dim, mode))
        i += 4
    while i < rows:
        b0 = max(b0, _row_sq(u, v, a, w, out, i * dim, dim, mode))
        i += 1
    return max(max(b0, b1), max(b2, b3))


@_jit
def max_row_sq(u, v, a, w, out, dim, mode):  # type: ignore[no-untyped-def]
    """By ``mode``: ``max_i |u_i|^2`` (:data:`NORM`), ``max_i |(u_i + a v_i) - w_i|^2``
    (:data:`GAP`), or that with ``u + a v`` written into ``out`` (:data:`PLACE`), over the
    ``dim``-vectors of the flat arrays (:func:`_max_row_sq`, with ``dim`` 2 and 3 as
    compile-time constants)."""
    if dim == 2:
        return _max_row_sq(u, v, a, w, out, 2, mode)
    if dim == 3:
        return _max_row_sq(u, v, a, w, out, 3, mode)
    return _max_row_sq(u, v, a, w, out, dim, mode)


@_jit
def max_displacement_sq(x, reference):  # type: ignore[no-untyped-def]
    """Largest squared displacement ``max_i |x_i - reference_i|^2`` over the rows of ``x`` and
    ``reference`` ``(N, d)`` (C-contiguous)."""
    flat = x.reshape(x.size)
    return max_row_sq(flat, flat, 0.0, reference.reshape(reference.size), flat, x.shape[1], GAP)


@_jit
def same_values(a, b):  # type: ignore[no-untyped-def]
    """True when the flat arrays ``a`` and ``b`` (same size) hold equal values; stops at the
    first difference (NaN equals nothing)."""
    for p in range(a.size):
        if a[p] != b[p]:
            return False
    return True


@_jit
def max_row_norm(v, d):  # type: ignore[no-untyped-def]
    """``max_i |v_i|`` over the ``d``-vectors of a flat ``(N d,)`` array."""
    return np.sqrt(max_row_sq(v, v, 0.0, v, v, d, NORM))


@_jit
def step_limit(max_step, direction, d):  # type: ignore[no-untyped-def]
    """Largest ``a`` for which ``a direction`` moves no ``d``-vector more than ``max_step``;
    ``inf`` for a zero direction."""
    longest = max_row_norm(direction, d)
    return max_step / longest if longest > 0.0 else np.inf
