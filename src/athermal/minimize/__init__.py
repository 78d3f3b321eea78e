"""Energy minimizers on an :class:`~athermal.objective.Objective`: one entry, a registry.

Methods: ``"lbfgs"`` (seed Algorithm 2), ``"cg"`` (Fletcher-Reeves, seed Algorithms 3-4, or
Polak-Ribiere+), ``"fire"`` (FIRE 2.0, the community's baseline), ``"newton"`` (truncated Newton
with a lagged Cholesky factor of the Hessian, beyond the seed: for quasi-static steps near
jamming); ``"plbfgs"`` and ``"pcg"`` are the seed's names for ``lbfgs`` and ``cg`` with the Exp
preconditioner. Preconditioners: ``"none"``, ``"exp"`` (the seed's universal preconditioner,
parameter ``A``) and ``"contact"`` (contact stiffness + Exp stabilization).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..objective import Objective
from ..precon import PRECONDITIONERS, PreconName, SolverName, make_preconditioner
from .cg import cg
from .fire import fire
from .lbfgs import lbfgs
from .newton import newton
from .result import MinimizeResult, Preconditioner, Problem, Status
from .spec import METHODS, NEWTON_TAKES_NO_PRECON, RTOL, Method, Minimizer, resolve_method


def minimize(
    objective: Objective,
    method: Method = "lbfgs",
    *,
    x0: NDArray[np.float64] | None = None,
    precon: PreconName | Preconditioner = "none",
    A: float = 0.0,
    solver: SolverName = "auto",
    gtol: float | None = None,
    rtol: float | None = None,
    maxiter: int = 100_000,
    etol: float = 0.0,
    memory: int = 10,
    cg_variant: Literal["fr", "pr+"] = "fr",
) -> MinimizeResult:
    """Relax ``objective`` from ``x0`` to ``max_i |grad_i| <= gtol``.

    Parameters
    ----------
    method : ``lbfgs``, ``cg``, ``fire``, ``newton``, or the seed's ``plbfgs`` / ``pcg``
        (``newton`` takes no ``precon``: its inner CG uses its own factored Hessian).
    x0 : the start ``(N d,)`` in the objective's internal order; default ``objective.x0``.
    precon : preconditioner name, or a ready :class:`Preconditioner` (reused across calls,
        e.g. by the quasi-static protocols).
    A, solver : parameter of the Exp weights and the linear solver (``direct`` Cholesky,
        ``amg``, incomplete Cholesky ``ic0``, or ``auto`` by size), used when ``precon`` is a name.
    gtol, rtol : absolute tolerance on ``max_i |grad_i|``, or relative to the mean contact
        force at the start (give exactly one).
    maxiter : iteration limit (non-convergence is reported in the result).
    etol : the run also stops, converged, once the energy is ``<= etol`` (absolute, energy
        units; default 0: only an exactly zero energy). The jamming protocol uses it to end the
        relaxation of an unjammed packing.
    memory : L-BFGS memory ``m``.
    cg_variant : ``fr`` (Fletcher-Reeves) or ``pr+`` (Polak-Ribiere+).

    The result's ``status`` (:class:`Status`) says why the run stopped.
    """
    start = objective.x0 if x0 is None else np.asarray(x0, dtype=np.float64)
    if start.shape != (objective.n_dof,):
        raise InputError(f"x0: expected shape ({objective.n_dof},), got {start.shape}")
    base, name = resolve_method(method, precon if isinstance(precon, str) else "none")
    if base == "newton" and not isinstance(precon, str):
        raise InputError(NEWTON_TAKES_NO_PRECON)
    tol = objective.tolerance(gtol, rtol, start)
    if base == "newton":
        return newton(objective, start, gtol=tol, maxiter=maxiter, etol=etol)
    pre = (
        make_preconditioner(name, objective, A=A, solver=solver)
        if isinstance(precon, str)
        else precon
    )
    if base == "lbfgs":
        return lbfgs(
            objective,
            start,
            gtol=tol,
            maxiter=maxiter,
            etol=etol,
            precon=pre,
            memory=memory,
        )
    if base == "cg":
        return cg(
            objective,
            start,
            gtol=tol,
            maxiter=maxiter,
            etol=etol,
            precon=pre,
            variant=cg_variant,
        )
    return fire(objective, start, gtol=tol, maxiter=maxiter, etol=etol, precon=pre)


def relax(
    objective: Objective,
    how: Minimizer,
    *,
    gtol: float | None = None,
    rtol: float | None = None,
    maxiter: int | None = None,
    x0: NDArray[np.float64] | None = None,
) -> MinimizeResult:
    """:func:`minimize` from ``x0`` with the method, preconditioner, ``A``, solver and (unless
    given) ``maxiter`` of ``how``."""
    return minimize(
        objective,
        how.method,
        x0=x0,
        precon=how.precon,
        A=how.A,
        solver=how.solver,
        gtol=gtol,
        rtol=rtol,
        maxiter=how.maxiter if maxiter is None else maxiter,
    )


__all__ = [
    "METHODS",
    "PRECONDITIONERS",
    "RTOL",
    "Method",
    "MinimizeResult",
    "Minimizer",
    "Preconditioner",
    "Problem",
    "Status",
    "minimize",
    "relax",
    "resolve_method",
]
