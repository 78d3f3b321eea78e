"""Minimizers of a smooth function of a flat float64 vector, in scipy's vocabulary.

:func:`minimize` takes ``fun(x) -> (f, grad)`` and a start ``x0``. Methods: ``"lbfgs"`` (seed
Algorithm 2), ``"cg"`` (Fletcher-Reeves, seed Algorithms 3-4, or Polak-Ribiere+), ``"fire"``
(FIRE 2.0, the community's baseline), ``"newton"`` (truncated Newton with a lagged Cholesky
factor of the Hessian, for quasi-static steps near jamming). A preconditioner is any object with
``update(x)``, ``solve(r)`` and ``dot(v)`` (:class:`Preconditioner`). What only the caller knows
(blocks of coordinates, the step cap, the round-off of ``f``) comes as :class:`Hooks`.

Nothing here knows particles: :mod:`athermal.relaxation` minimizes a packing's energy with
these, the preconditioners of :mod:`athermal.engines.precon` and the physics' hooks.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .._validate import choice
from ..errors import InputError
from .cg import cg
from .fire import fire
from .function import Function, compiled_function
from .hooks import Hooks
from .lbfgs import lbfgs
from .newton import Hessian, SecondOrderProblem, SparseHessian, newton
from .result import CompiledSearch, MinimizeResult, Preconditioner, Problem, Status

Method = Literal["lbfgs", "cg", "fire", "newton"]
METHODS: tuple[str, ...] = ("lbfgs", "cg", "fire", "newton")
NEWTON_TAKES_NO_PRECON = "precon: newton preconditions with its own Hessian factor; give none"
"""Why ``newton`` refuses a preconditioner (the physics' names add what they got)."""


class _SecondOrder(Function):
    """A :class:`Function` that also gives its Hessian (a :class:`Hessian`, or a sparse matrix
    wrapped in :class:`SparseHessian`)."""

    def __init__(
        self,
        fun: Callable[[NDArray[np.float64]], tuple[float, NDArray[np.float64]]],
        n_dof: int,
        hooks: Hooks,
        hess: Callable[[NDArray[np.float64]], Any],
    ) -> None:
        super().__init__(fun, n_dof, hooks)
        self._hess = hess

    def hessian(self, x: NDArray[np.float64]) -> Hessian:
        """The Hessian at ``x``."""
        h = self._hess(x)
        if sp.issparse(h) or isinstance(h, np.ndarray):
            return SparseHessian(sp.csr_matrix(h), self.hooks.block)
        hessian: Hessian = h
        return hessian


def minimize(
    fun: Callable[[NDArray[np.float64]], tuple[float, NDArray[np.float64]]] | Problem,
    x0: NDArray[np.float64],
    *,
    method: Method = "lbfgs",
    precon: Preconditioner | None = None,
    gtol: float = 1e-5,
    maxiter: int = 100_000,
    etol: float = -np.inf,
    hooks: Hooks | None = None,
    hess: Callable[[NDArray[np.float64]], Any] | None = None,
    memory: int = 10,
    cg_variant: Literal["fr", "pr+"] = "fr",
    options: dict[str, Any] | None = None,
) -> MinimizeResult:
    """Minimize ``fun`` from ``x0`` to a gradient whose largest block is ``<= gtol``.

    Parameters
    ----------
    fun : ``fun(x) -> (f, grad)`` of a flat float64 vector ``(n,)``; or a ready
        :class:`Problem` (its own hooks and compiled line search: the physics' objective).
    x0 : the start ``(n,)``.
    method : ``lbfgs``, ``cg``, ``fire`` or ``newton``.
    precon : a :class:`Preconditioner` (``update(x)`` at each iterate, ``solve(r) = P^-1 r``);
        not for ``newton``, which preconditions with its own Hessian factor.
    gtol : absolute tolerance on the largest Euclidean norm of a block of ``grad``
        (:class:`Hooks`; single coordinates by default: ``max_i |grad_i|``).
    maxiter : iteration limit (non-convergence is reported in the result, not raised).
    etol : the run also stops, converged, once ``f <= etol`` (default ``-inf``: never; the
        physics gives 0 for a contact energy, which is exactly 0 only without overlaps).
    hooks : blocks, step cap and round-off of ``f`` (:class:`Hooks`); not with a
        :class:`Problem`, which has its own.
    hess : for ``newton``: ``hess(x)``, the Hessian as a sparse matrix or a :class:`Hessian`.
    memory : L-BFGS memory ``m``.
    cg_variant : ``fr`` (Fletcher-Reeves) or ``pr+`` (Polak-Ribiere+).
    options : more keywords of the method (:func:`~.fire.fire`: ``dt_max`` or ``curvature``,
        a bound on the Hessian's largest eigenvalue, without a preconditioner; ``dt``,
        ``n_delay``, ...).

    Returns
    -------
    :class:`MinimizeResult` (``x``, ``fun``, ``jac``, ``nit``, ``nfev``, ``status``,
    ``success``, ``message``, histories and counters).

    Examples
    --------
    The 100-dimensional Rosenbrock function, its minimum at ``x = 1`` (FIRE is given a bound on
    the Hessian's largest eigenvalue, 1802 at the minimum, for its time step):

    >>> import numpy as np
    >>> from scipy.optimize import rosen, rosen_der
    >>> from athermal.minimize import minimize
    >>> fun = lambda x: (rosen(x), rosen_der(x))
    >>> for method, options in [("lbfgs", None), ("cg", None), ("fire", {"curvature": 2500.0})]:
    ...     result = minimize(fun, np.zeros(100), method=method, gtol=1e-10, options=options)
    ...     print(method, result.success, bool(np.allclose(result.x, 1.0)))
    lbfgs True True
    cg True True
    fire True True
    """
    choice(method, "method", METHODS)
    if hess is not None and method != "newton":
        raise InputError(f"hess: only newton uses the Hessian, not {method}")
    if options and method not in ("fire", "newton"):
        raise InputError(f"options: {method} takes none, got {sorted(options)}")
    if isinstance(x0, str) or x0 is None:
        raise InputError(
            "minimize(fun, x0, *, method=...): x0 is the start vector; to relax a packing's "
            "energy use athermal.relaxation.minimize_objective(objective, method, ...) or "
            "athermal.relax(packing, model)"
        )
    start = np.array(x0, dtype=np.float64, copy=True).reshape(-1)
    if isinstance(fun, Problem):
        if hooks is not None or hess is not None:
            raise InputError("hooks, hess: a Problem brings its own")
        problem: Problem = fun
        if start.shape != (problem.n_dof,):
            raise InputError(f"x0: expected shape ({problem.n_dof},), got {np.shape(x0)}")
    elif method == "newton":
        if hess is None:
            raise InputError("hess: newton needs the Hessian, hess(x)")
        problem = _SecondOrder(fun, start.size, hooks or Hooks(), hess)
    else:
        problem = Function(fun, start.size, hooks)
    extra = dict(options or {})
    if method == "newton":
        if precon is not None:
            raise InputError(NEWTON_TAKES_NO_PRECON)
        if not isinstance(problem, SecondOrderProblem):
            raise InputError("hess: newton needs the Hessian of the problem, hessian(x)")
        return newton(problem, start, gtol=gtol, maxiter=maxiter, etol=etol, **extra)
    if method == "lbfgs":
        return lbfgs(
            problem, start, gtol=gtol, maxiter=maxiter, etol=etol, precon=precon, memory=memory
        )
    if method == "cg":
        return cg(
            problem,
            start,
            gtol=gtol,
            maxiter=maxiter,
            etol=etol,
            precon=precon,
            variant=cg_variant,
        )
    return fire(problem, start, gtol=gtol, maxiter=maxiter, etol=etol, precon=precon, **extra)


__all__ = [
    "METHODS",
    "NEWTON_TAKES_NO_PRECON",
    "CompiledSearch",
    "Function",
    "Hessian",
    "Hooks",
    "Method",
    "MinimizeResult",
    "Preconditioner",
    "Problem",
    "SecondOrderProblem",
    "SparseHessian",
    "Status",
    "compiled_function",
    "minimize",
]
