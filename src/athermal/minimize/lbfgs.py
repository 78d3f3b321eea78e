"""Limited-memory BFGS (seed Algorithm 2), optionally preconditioned (seed's boxed step).

The two-loop recursion with memory ``m``; the initial inverse Hessian is
``B0 = (s.y / y.y) I`` (seed) or ``P^-1`` with a preconditioner (the seed's boxed step). Steps
come from the strong-Wolfe line search of :mod:`.linesearch` (``c1 = 1e-4``, ``c2 = 0.9``),
unit step tried first.

Measured on the seed's Case 1 (N = 4096, alpha = 2): with the Exp preconditioner the accepted
steps cluster near 0.3 (the sine-test ``mu`` leaves ``P`` softer than the Hessian), costing a
second evaluation per iteration. Rescaling ``B0`` by the newest pair's ``s.P s / s.y`` made
steps ~0.03, and calibrating a scale from the first accepted steps traded iterations for
evaluations (1159 -> 1440 iterations, no gain in time); both were dropped.
``benchmarks/precon_scan.py`` scans ``mu``, ``C_stab``, ``r_cut``, ``A`` and the memory: no
single change brings the iteration ratio to L-BFGS below 0.42 on Cases 1 and 2 at N = 4096
(the best per problem: 0.42-0.50).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .. import _kernels
from ..objective import Objective
from ._step import search
from .result import MinimizeResult, Preconditioner, Tracker


class _Memory:
    """The last ``m`` pairs ``s = x_{k+1} - x_k``, ``y = g_{k+1} - g_k`` in ring buffers."""

    def __init__(self, m: int, n: int) -> None:
        self.s = np.zeros((m, n))
        self.y = np.zeros((m, n))
        self.rho = np.zeros(m)
        self.alphas = np.zeros(m)
        self.order = np.zeros(0, dtype=np.int64)  # slots from oldest to newest

    def __len__(self) -> int:
        return int(self.order.size)

    def clear(self) -> None:
        self.order = self.order[:0]

    def push(self, s: NDArray[np.float64], y: NDArray[np.float64], sy: float) -> None:
        m = self.rho.size
        slot = int((self.order[-1] + 1) % m) if len(self) else 0
        self.s[slot], self.y[slot], self.rho[slot] = s, y, 1.0 / sy
        self.order = np.append(self.order[-(m - 1) :] if m > 1 else self.order[:0], slot)

    def b0(self, q: NDArray[np.float64], precon: Preconditioner | None) -> NDArray[np.float64]:
        """The boxed step ``r = B0 q``: ``P^-1 q``, else ``(s.y / y.y) q`` for the newest pair
        ``(s, y)`` (``q`` before the first pair)."""
        if precon is not None:
            return precon.solve(q)
        if len(self):
            newest = self.order[-1]
            y = self.y[newest]
            return q / (self.rho[newest] * float(y @ y))
        return q.copy()

    def apply(
        self, grad: NDArray[np.float64], precon: Preconditioner | None
    ) -> NDArray[np.float64]:
        """``B grad`` by the two-loop recursion (compiled loops, ``B0`` in between)."""
        q = grad.copy()
        _kernels.lbfgs_first_loop(q, self.s, self.y, self.rho, self.order, self.alphas)
        r = self.b0(q, precon)
        _kernels.lbfgs_second_loop(r, self.s, self.y, self.rho, self.order, self.alphas)
        return r


def lbfgs(
    objective: Objective,
    *,
    gtol: float | None = None,
    rtol: float | None = None,
    maxiter: int = 100_000,
    etol: float = 0.0,
    precon: Preconditioner | None = None,
    memory: int = 10,
) -> MinimizeResult:
    """Minimize ``objective`` from ``objective.x0`` by (preconditioned) L-BFGS.

    Stops when ``max_i |grad_i| <= gtol`` (or ``rtol`` x the mean contact force at the start),
    when the energy is ``<= etol`` (default: exactly zero), after ``maxiter`` iterations, or
    when no step satisfying the Wolfe conditions exists even along steepest descent (reported,
    ``converged=False``).
    """
    tracker = Tracker.start(objective, "lbfgs", precon, gtol, rtol, maxiter, etol)
    x = objective.x0.copy()
    energy, grad = objective(x)
    if precon is not None:
        precon.update(x)
    pairs = _Memory(memory, objective.n_dof)
    if tracker.record(energy, grad):
        return tracker.finish(x, True, "converged")
    while tracker.iterations < maxiter:
        direction = -pairs.apply(grad, precon)
        if not float(grad @ direction) < 0.0:  # curvature pairs gone stale: restart
            pairs.clear()
            direction = -pairs.b0(grad, precon)
        ls = search(objective, x, energy, grad, direction, 1.0, c2=0.9)
        if not ls.ok and pairs:
            pairs.clear()  # stale curvature pairs: restart from the (preconditioned) gradient
            direction = -pairs.b0(grad, precon)
            ls = search(objective, x, energy, grad, direction, 1.0, c2=0.9)
        if not ls.ok:
            return tracker.finish(x, False, "line search failed: no Wolfe step along descent")
        x_new = x + ls.step * direction
        energy, grad_new = objective(x_new)
        s, y = x_new - x, grad_new - grad
        sy = float(s @ y)
        if sy > 0.0:
            pairs.push(s, y, sy)
        x, grad = x_new, grad_new
        if precon is not None:
            precon.update(x)
        if tracker.record(energy, grad):
            return tracker.finish(x, True, "converged")
    return tracker.finish(x, False, f"iteration limit {maxiter} reached")
