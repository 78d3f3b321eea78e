"""The compiled steps of nonlinear CG: ``beta`` (Fletcher-Reeves or Polak-Ribiere+, zero by
Powell's restart test) and the next direction with its first trial step, each in one pass with
a fixed order of partial sums, so that the compiled loop and the Python one go the same way bit
for bit."""

from __future__ import annotations

import numpy as np

from .._jit import _jit

POWELL = 0.1
"""Powell's restart threshold on the overlap of consecutive gradients."""
YG, STEP_GUESS, RESTARTED, SLOPE = range(4)
"""Fields of :func:`~._compiled.iterate`'s ``scalars``: ``y.g`` of the iterate, the next first trial
step, whether the direction is the (preconditioned) gradient, and the slope ``g.p`` along the
direction (the one :func:`next_direction` formed, or ``-y.g`` for the preconditioned gradient): the
compiled and the Python loop take it from there and never form it again, so that the two go the same
way bit for bit."""


@_jit
def next_direction(ls_step, slope, beta, direction, y_new, grad_new):
    """The next direction ``beta direction - y_new``, written into ``direction``, the first
    trial step along it (Nocedal & Wright's ``a_{k-1} g_{k-1}.p_{k-1} / g_k.p_k``, or 1 after a
    restart or where that is not a positive number) and its slope ``g_k.p_k``, in one pass
    (four partial sums, :func:`beta_of`'s order)."""
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
def beta_of(y_new, grad_new, grad, yg, polak):
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
    if abs(overlap) >= POWELL * yg_new:
        return 0.0, yg_new
    if not polak:
        return yg_new / yg, yg_new
    return max(0.0, change / yg), yg_new
