"""The L-BFGS memory: the last ``m`` curvature pairs in ring buffers, their dot products, and
the compiled vector loops of the compact form (Byrd, Nocedal & Schnabel 1994) that turn them
into a direction.

The step is the two-loop recursion's (Nocedal & Wright, Algorithm 7.4) in compact form: two
blocked passes over the stored ``s`` and ``P^-1 y`` and ``O(m^2)`` work on their dot products,
kept from one iteration to the next (the recursion streams ``s``, ``y`` and ``P^-1 y`` about five
times).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._jit import _jit
from .._portable import LANES, add_products, dot, lane_total, vdot
from .result import Preconditioner

_COUNT, _FREE, _FRESH = 0, 1, 2
"""Fields of :attr:`Memory.ring`: pairs kept, the row the next pair goes to, and whether the
newest pair's dot products with the others are still due (0 / 1)."""


class Memory:
    """The last ``m`` pairs ``s = x_{k+1} - x_k``, ``y = g_{k+1} - g_k`` and ``P^-1 y`` in ring
    buffers of ``m + 1`` rows ``(m + 1, n)`` (a new pair is written into the free row, so a
    rejected pair costs no stored one), with their dot products ``s_a.y_b`` and
    ``y_a.P^-1 y_b`` ``(m + 1, m + 1)`` for the compact form; without a preconditioner
    ``P^-1 y`` is ``y`` (the same buffer). ``rows`` ``(m,)`` lists the rows in use, oldest
    first; ``ring`` holds the counters (:data:`_COUNT`, :data:`_FREE`, :data:`_FRESH`), so that
    compiled code updates them as Python does."""

    def __init__(self, m: int, n: int, precon: Preconditioner | None) -> None:
        self.m = m
        self.s = np.zeros((m + 1, n))
        self.y = np.zeros((m + 1, n))
        self.py = np.zeros((m + 1, n)) if precon is not None else self.y
        self.sy = np.zeros((m + 1, m + 1))
        self.ypy = np.zeros((m + 1, m + 1))
        self.gamma = np.zeros(m + 1)
        self.work = np.zeros((4, m + 1))
        self.rows = np.zeros(m, dtype=np.int64)
        self.ring = np.zeros(3, dtype=np.int64)

    def __len__(self) -> int:
        return int(self.ring[_COUNT])

    @property
    def order(self) -> NDArray[np.int64]:
        """The rows in use, oldest first."""
        return self.rows[: self.ring[_COUNT]]

    @property
    def slots(self) -> list[int]:
        """:attr:`order` as a list."""
        return [int(r) for r in self.order]

    @property
    def fresh(self) -> bool:
        """The newest pair's dot products with the others are still due."""
        return bool(self.ring[_FRESH])

    @fresh.setter
    def fresh(self, value: bool) -> None:
        self.ring[_FRESH] = int(value)

    def arrays(self) -> tuple[NDArray[Any], ...]:
        """The buffers compiled code works on: ``s, y, py, sy, ypy, gamma, work, rows, ring``."""
        return (
            self.s,
            self.y,
            self.py,
            self.sy,
            self.ypy,
            self.gamma,
            self.work,
            self.rows,
            self.ring,
        )

    def clear(self) -> None:
        self.ring[_COUNT] = 0
        self.ring[_FRESH] = 0

    def store(
        self,
        x: NDArray[np.float64],
        x_new: NDArray[np.float64],
        grad: NDArray[np.float64],
        grad_new: NDArray[np.float64],
        z: NDArray[np.float64],
        z_new: NDArray[np.float64],
        precon: Preconditioner | None = None,
    ) -> None:
        """Form and keep the pair of the step ``x -> x_new`` (``z = P^-1 grad``, or ``grad``
        without a preconditioner); ``P^-1 y`` by the solve of ``precon`` when given (``P`` was
        just rebuilt, so ``z_new - z`` mixes two matrices). Kept only when ``s.y > 0`` and
        ``y.P^-1 y > 0``; its dot products with the other pairs are formed by the next
        :meth:`direction`."""
        if precon is None:
            store_pair(x, x_new, grad, grad_new, z, z_new, *self.arrays())
            return
        _complete_newest(*self.arrays())
        row = int(self.ring[_FREE])
        sy, _ = lbfgs_pair(
            x, x_new, grad, grad_new, z, z_new, self.s[row], self.y[row], self.py[row]
        )
        self.py[row] = precon.solve(self.y[row])
        _keep(row, sy, vdot(self.y[row], self.py[row]), *self.arrays())

    def refresh(self, precon: Preconditioner) -> None:
        """Recompute ``P^-1 y``, ``gamma`` and ``y.P^-1 y`` of every stored pair after ``P``
        was rebuilt."""
        for slot in self.slots:
            self.py[slot] = precon.solve(self.y[slot])
            ypy = vdot(self.y[slot], self.py[slot])
            if not ypy > 0.0:  # cannot happen for an SPD P; keep the direction well defined
                self.clear()
                return
            self.gamma[slot] = self.sy[slot, slot] / ypy
        rows = self.order
        products = _products(self.y, self.py, rows)
        self.ypy[np.ix_(rows, rows)] = 0.5 * (products + products.T)

    def direction(self, grad: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.float64]:
        """``-H grad`` by the compiled compact form, with ``z = P^-1 grad``."""
        out = np.empty_like(grad)
        arguments = (grad, z, *self.arrays(), out)
        direction_into(*arguments)
        return out


@_jit
def _products(y, py, rows):
    """``y_a . P^-1 y_b`` ``(k, k)`` for the stored pairs ``rows`` (``dot``'s order)."""
    out = np.empty((rows.size, rows.size))
    for a in range(rows.size):
        for b in range(rows.size):
            out[a, b] = dot(y[rows[a]], py[rows[b]])
    return out


@_jit
def _complete_newest(s, y, py, sy, ypy, gamma, work, rows, ring):
    """Form the newest pair's dot products with the others now, if still due (a pair stored
    without a direction after it; the minimizer never does this)."""
    if ring[_FRESH] == 0:
        return
    count = ring[_COUNT]
    newest = rows[count - 1]
    for t in range(count):
        r = rows[t]
        sy[r, newest] = dot(s[r], y[newest])
        ypy[r, newest] = ypy[newest, r] = dot(py[r], y[newest])
    ring[_FRESH] = 0


@_jit
def _keep(row, sy_row, ypy_row, s, y, py, sy, ypy, gamma, work, rows, ring):
    """Keep the pair just written into ``row`` (``s.y = sy_row``, ``y.P^-1 y = ypy_row``) when
    both are > 0, dropping the oldest of a full memory."""
    if not (sy_row > 0.0 and ypy_row > 0.0):
        return
    gamma[row] = sy_row / ypy_row
    sy[row, row] = sy_row
    ypy[row, row] = ypy_row
    m = rows.size
    count = ring[_COUNT]
    if count == m:
        for t in range(m - 1):
            rows[t] = rows[t + 1]
        rows[m - 1] = row
    else:
        rows[count] = row
        ring[_COUNT] = count + 1
    ring[_FREE] = (row + 1) % (m + 1)
    ring[_FRESH] = 1


@_jit
def store_pair(x, x_new, g, g_new, z, z_new, s, y, py, sy, ypy, gamma, work, rows, ring):
    """:meth:`Memory.store` without a rebuilt preconditioner."""
    _complete_newest(s, y, py, sy, ypy, gamma, work, rows, ring)
    row = ring[_FREE]
    sy_row, ypy_row = lbfgs_pair(x, x_new, g, g_new, z, z_new, s[row], y[row], py[row])
    _keep(row, sy_row, ypy_row, s, y, py, sy, ypy, gamma, work, rows, ring)


@_jit
def direction_into(grad, z, s, y, py, sy, ypy, gamma, work, rows, ring, out):
    """:meth:`Memory.direction` into ``out``."""
    count = ring[_COUNT]
    newest = y[rows[count - 1]] if count > 0 else grad
    lbfgs_direction(
        grad, z, s, py, newest, ring[_FRESH] == 1, sy, ypy, gamma, rows[:count], work, out
    )
    ring[_FRESH] = 0


_CHUNK = 1024
"""Entries of a vector per block of the L-BFGS loops: two 8 kB blocks stay in L1 cache (a
multiple of :data:`~athermal._portable.LANES`, so that each dot product's lanes get the
elements they get in :func:`~athermal._portable.dot`)."""


@_jit
def lbfgs_direction(grad, z, s_mem, py_mem, y_new, fresh, sy_mat, ypy_mat, gamma, order, work, out):
    """The L-BFGS step ``out = -H grad`` in compact form (Byrd, Nocedal & Schnabel 1994),
    ``H0 = gamma_newest P^-1``, in two blocked passes over the stored vectors.

    ``H grad = gamma z + S p - gamma PY w`` with ``z = P^-1 grad``, ``w = R^-1 S^T grad`` and
    ``p = R^-T (D w + gamma (Y^T P^-1 Y) w - gamma PY^T grad)``, where ``R`` is the upper
    triangle of ``S^T Y`` (pairs oldest first) and ``D`` its diagonal; ``Y^T P^-1 y =
    PY^T y`` since ``P`` is symmetric. It equals the two-loop recursion's step, reading the
    pairs' ``s`` and ``P^-1 y`` twice in all instead of ``s``, ``y`` and ``P^-1 y`` about
    five times.

    Pairs are the rows ``order`` (oldest first) of ``s_mem`` and ``py_mem`` ``(m + 1, n)``;
    ``sy_mat[a, b] = s_a.y_b`` (``a`` no newer than ``b``) and ``ypy_mat[a, b] = y_a.P^-1 y_b``
    ``(m + 1, m + 1)``. When ``fresh``, the newest pair's column of both (its dot products
    with ``y_new``, the newest ``y``) is computed in the first pass and written. ``work``
    ``(4, m + 1)`` is scratch; ``out`` ``(n,)`` receives the step.
    """
    n = grad.size
    count = order.size
    if count == 0:
        for p in range(n):
            out[p] = -z[p]
        return
    u = work[0]
    v = work[1]
    col_sy = work[2]
    col_ypy = work[3]
    # the dot products' lanes, as :func:`dot` sums them: pair t's s and P^-1 y (its rows of the
    # flat stores) against grad and y_new (y_new's products are only kept when fresh)
    lanes = np.zeros((count, 2, 2, LANES))
    stored = (s_mem.reshape(s_mem.size), py_mem.reshape(py_mem.size))
    against = (grad, y_new)
    for lo in range(0, n, _CHUNK):
        size = min(n, lo + _CHUNK) - lo
        for t in range(count):
            at = order[t] * n + lo
            add_products(lanes[t], stored, (at, at), against, (lo, lo), size)
    for t in range(count):
        u[t] = lane_total(lanes[t, 0, 0])
        v[t] = lane_total(lanes[t, 1, 0])
        col_sy[t] = lane_total(lanes[t, 0, 1])
        col_ypy[t] = lane_total(lanes[t, 1, 1])
    newest = order[count - 1]
    if fresh:
        for t in range(count):
            sy_mat[order[t], newest] = col_sy[t]
            ypy_mat[order[t], newest] = col_ypy[t]
            ypy_mat[newest, order[t]] = col_ypy[t]
    scale = gamma[newest]
    # w = R^-1 u (back substitution), into u
    for i in range(count - 1, -1, -1):
        acc = u[i]
        for j in range(i + 1, count):
            acc -= sy_mat[order[i], order[j]] * u[j]
        u[i] = acc / sy_mat[order[i], order[i]]
    # r = D w + gamma (Y^T P^-1 Y) w - gamma v, into v
    for i in range(count):
        acc = 0.0
        for j in range(count):
            acc += ypy_mat[order[i], order[j]] * u[j]
        v[i] = sy_mat[order[i], order[i]] * u[i] + scale * (acc - v[i])
    # p = R^-T r (forward substitution), into v
    for i in range(count):
        acc = v[i]
        for j in range(i):
            acc -= sy_mat[order[j], order[i]] * v[j]
        v[i] = acc / sy_mat[order[i], order[i]]
    for lo in range(0, n, _CHUNK):
        hi = min(n, lo + _CHUNK)
        o_blk = out[lo:hi]
        z_blk = z[lo:hi]
        for p in range(hi - lo):
            o_blk[p] = -scale * z_blk[p]
        for t in range(count):
            s_blk = s_mem[order[t], lo:hi]
            py_blk = py_mem[order[t], lo:hi]
            cs = -v[t]
            cp = scale * u[t]
            for p in range(hi - lo):
                o_blk[p] += cs * s_blk[p] + cp * py_blk[p]


@_jit
def lbfgs_pair(x, x_new, g, g_new, z, z_new, s, y, py):
    """One L-BFGS pair in one pass: ``s = x_new - x``, ``y = g_new - g``, ``py = z_new - z``
    (written into the given rows; when ``py`` is ``y`` itself, ``z`` must be ``g`` and ``py``
    is not written, so that no write aliases another and the loop vectorizes as it does with
    separate rows). Returns ``(s.y, y.py)``."""
    separate = py.ctypes.data != y.ctypes.data
    sy = 0.0
    ypy = 0.0
    for p in range(x.size):
        sp = x_new[p] - x[p]
        yp = g_new[p] - g[p]
        pyp = z_new[p] - z[p]
        s[p] = sp
        y[p] = yp
        if separate:
            py[p] = pyp
        sy += sp * yp
        ypy += yp * pyp
    return sy, ypy
