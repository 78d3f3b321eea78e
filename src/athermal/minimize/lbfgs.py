"""Limited-memory BFGS (seed Algorithm 2), optionally preconditioned (seed's boxed step).

The L-BFGS step with memory ``m`` and the initial inverse Hessian ``H0 = gamma P^-1``
(``P = I`` without a preconditioner), ``gamma = s.y / y.P^-1 y`` of the newest pair (Nocedal &
Wright, eq. 7.20, in the metric of ``P``). Steps come from the strong-Wolfe line search of
:mod:`.linesearch` (``c1 = 1e-4``, ``c2 = 0.9``), unit step tried first.

One solve per iteration: the method keeps ``z = P^-1 g`` and, for each pair, ``P^-1 y =
z_{k+1} - z_k``, so ``H0`` applied to the pairs is a combination of stored vectors
(recomputed by ``m`` solves when ``P`` is rebuilt). The seed's unscaled ``H0 = P^-1`` left the
Exp preconditioner about 3x too soft on Case 1 (N = 4096, alpha = 2): accepted steps 0.29-0.32,
the unit step never accepted, two evaluations per iteration. With ``gamma`` the unit step is
the accepted one (``benchmarks/results/breakdown*.md``).

The step is the two-loop recursion's (Nocedal & Wright, Algorithm 7.4) in the compact form of
Byrd, Nocedal & Schnabel (1994): two blocked passes over the stored ``s`` and ``P^-1 y`` and
``O(m^2)`` work on their dot products, kept from one iteration to the next. The recursion
streams ``s``, ``y`` and ``P^-1 y`` about five times; measured on Case 1 (Intel Xeon, one core),
0.064 against 0.090 ms per P-L-BFGS iteration (0.291 against 0.322 ms in all).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .. import _kernels
from ._step import advance
from .result import MinimizeResult, Preconditioner, Problem, Status, Tracker


class _Memory:
    """The last ``m`` pairs ``s = x_{k+1} - x_k``, ``y = g_{k+1} - g_k`` and ``P^-1 y`` in ring
    buffers of ``m + 1`` rows ``(m + 1, n)`` (a new pair is written into the free row, so a
    rejected pair costs no stored one), with their dot products ``s_a.y_b`` and
    ``y_a.P^-1 y_b`` ``(m + 1, m + 1)`` for the compact form; without a preconditioner
    ``P^-1 y`` is ``y`` (the same buffer)."""

    def __init__(self, m: int, n: int, precon: Preconditioner | None) -> None:
        self.m = m
        self.s = np.zeros((m + 1, n))
        self.y = np.zeros((m + 1, n))
        self.py = np.zeros((m + 1, n)) if precon is not None else self.y
        self.sy = np.zeros((m + 1, m + 1))
        self.ypy = np.zeros((m + 1, m + 1))
        self.gamma = np.zeros(m + 1)
        self.work = np.zeros((4, m + 1))
        self.slots: list[int] = []  # rows in use, oldest to newest
        self.order = np.zeros(0, dtype=np.int64)  # the same, for the compiled kernel
        self.free = 0
        self.fresh = False  # the newest pair's dot products with the others are still due

    def __len__(self) -> int:
        return len(self.slots)

    def clear(self) -> None:
        self.slots = []
        self.order = self.order[:0]
        self.fresh = False

    def _complete_newest(self) -> None:
        """Form the newest pair's dot products with the others now (a pair stored without a
        :meth:`direction` after it; the minimizer never does this)."""
        newest, rows = self.slots[-1], self.order
        self.sy[rows, newest] = self.s[rows] @ self.y[newest]
        self.ypy[rows, newest] = self.ypy[newest, rows] = self.py[rows] @ self.y[newest]
        self.fresh = False

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
        if self.fresh:
            self._complete_newest()
        row = self.free
        sy, ypy = _kernels.lbfgs_pair(
            x, x_new, grad, grad_new, z, z_new, self.s[row], self.y[row], self.py[row]
        )
        if precon is not None:
            self.py[row] = precon.solve(self.y[row])
            ypy = float(self.y[row] @ self.py[row])
        if not (sy > 0.0 and ypy > 0.0):
            return
        self.gamma[row] = sy / ypy
        self.sy[row, row], self.ypy[row, row] = sy, ypy
        self.slots = [*self.slots[-(self.m - 1) :], row] if self.m > 1 else [row]
        self.order = np.array(self.slots, dtype=np.int64)
        self.free = (row + 1) % (self.m + 1)
        self.fresh = True

    def refresh(self, precon: Preconditioner) -> None:
        """Recompute ``P^-1 y``, ``gamma`` and ``y.P^-1 y`` of every stored pair after ``P``
        was rebuilt."""
        for slot in self.order.tolist():
            self.py[slot] = precon.solve(self.y[slot])
            ypy = float(self.y[slot] @ self.py[slot])
            if not ypy > 0.0:  # cannot happen for an SPD P; keep the direction well defined
                self.clear()
                return
            self.gamma[slot] = self.sy[slot, slot] / ypy
        rows = self.order
        products = self.y[rows] @ self.py[rows].T
        self.ypy[np.ix_(rows, rows)] = 0.5 * (products + products.T)

    def direction(self, grad: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.float64]:
        """``-H grad`` by the compiled compact form, with ``z = P^-1 grad``."""
        out = np.empty_like(grad)
        newest = self.y[self.slots[-1]] if self.slots else grad
        _kernels.lbfgs_direction(
            grad,
            z,
            self.s,
            self.py,
            newest,
            self.fresh,
            self.sy,
            self.ypy,
            self.gamma,
            self.order,
            self.work,
            out,
        )
        self.fresh = False
        return out


def lbfgs(
    problem: Problem,
    x0: NDArray[np.float64],
    *,
    gtol: float,
    maxiter: int = 100_000,
    etol: float = 0.0,
    precon: Preconditioner | None = None,
    memory: int = 10,
) -> MinimizeResult:
    """Minimize ``problem`` from ``x0`` ``(n_dof,)`` by (preconditioned) L-BFGS.

    Stops when ``problem.max_gradient(grad) <= gtol`` or the energy is ``<= etol`` (default:
    exactly zero; status ``CONVERGED``), after ``maxiter`` iterations (``ITERATION_LIMIT``), or
    when no step satisfying the Wolfe conditions exists even along the (preconditioned)
    gradient (``LINE_SEARCH_FAILED``).
    """
    tracker = Tracker.start(problem, "lbfgs", precon, gtol, maxiter, etol)
    x = np.array(x0, dtype=np.float64, copy=True)
    energy, grad = problem(x)
    if precon is not None:
        precon.update(x)
    z = precon.solve(grad) if precon is not None else grad
    builds = precon.n_builds if precon is not None else 0
    pairs = _Memory(memory, problem.n_dof, precon)
    if tracker.record(energy, grad):
        return tracker.finish(x, Status.CONVERGED, "converged")
    while tracker.iterations < maxiter:
        direction = pairs.direction(grad, z)
        if not float(grad @ direction) < 0.0:  # curvature pairs gone stale: restart
            pairs.clear()
            direction = -z
        ls, x_new, energy_new, grad_new = advance(problem, x, energy, grad, direction, 1.0, 0.9)
        if not ls.ok and pairs:
            pairs.clear()  # stale curvature pairs: restart from the (preconditioned) gradient
            direction = -z
            ls, x_new, energy_new, grad_new = advance(problem, x, energy, grad, direction, 1.0, 0.9)
        if not ls.ok:
            return tracker.finish(
                x, Status.LINE_SEARCH_FAILED, "line search failed: no Wolfe step along descent"
            )
        energy = energy_new
        rebuilt = False
        if precon is not None:
            precon.update(x_new)
            rebuilt, builds = precon.n_builds != builds, precon.n_builds
        z_new = precon.solve(grad_new) if precon is not None else grad_new
        if rebuilt:
            assert precon is not None
            pairs.refresh(precon)
        pairs.store(x, x_new, grad, grad_new, z, z_new, precon if rebuilt else None)
        x, grad, z = x_new, grad_new, z_new
        if tracker.record(energy, grad):
            return tracker.finish(x, Status.CONVERGED, "converged")
    return tracker.finish(x, Status.ITERATION_LIMIT, f"iteration limit {maxiter} reached")
