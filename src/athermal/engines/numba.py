"""The default engine: the minimizers of :mod:`athermal.minimize` on the CPU, over the numba
kernels of the objective, with every preconditioner of :mod:`athermal.engines.precon`."""

from __future__ import annotations

from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from .. import minimize as library
from ..linalg import available, resolve_solver
from ..minimize import MinimizeResult, Preconditioner
from ..model.objective import Objective
from . import Capabilities, Engine
from .precon import PRECONDITIONERS, PreconName, make_preconditioner


def run(
    objective: Objective,
    method: str,
    x: NDArray[np.float64],
    precon: Preconditioner | None,
    *,
    gtol: float,
    etol: float,
    maxiter: int,
    memory: int = 10,
    cg_variant: str = "fr",
) -> MinimizeResult:
    """Minimize ``objective`` from ``x`` ``(N d,)`` by the base ``method`` with ``precon`` to
    ``max_i |grad_i| <= gtol`` or energy ``<= etol`` within ``maxiter`` iterations (L-BFGS
    memory ``memory``, CG variant ``cg_variant``); FIRE without a preconditioner takes its time
    step from the objective's curvature bound."""
    options: dict[str, Any] = {}
    if method == "fire" and precon is None:
        options["curvature"] = objective.curvature_bound(x)
    return library.minimize(
        objective,
        x,
        method=cast(library.Method, method),
        precon=precon,
        gtol=gtol,
        maxiter=maxiter,
        etol=etol,
        memory=memory,
        cg_variant=cast(Any, cg_variant),
        options=options,
    )


class NumbaSession:
    """The numba engine bound to ``objective``: its preconditioner built once (it rebuilds by
    its own rule within each run); one named in :meth:`minimize` is built fresh for that run."""

    def __init__(self, objective: Objective, precon: str, *, A: float, solver: str) -> None:
        self.objective = objective
        self.solver = solver
        self.own = make_preconditioner(
            cast(PreconName, precon), objective, A=A, solver=cast(Any, solver)
        )

    @property
    def n_rebuilds(self) -> int:
        """Verlet-list builds of the objective so far."""
        return self.objective.n_rebuilds

    def minimize(
        self,
        method: str,
        x: NDArray[np.float64],
        *,
        gtol: float,
        etol: float,
        maxiter: int,
        precon: str | None = None,
    ) -> MinimizeResult:
        """:func:`run` with the bound preconditioner, or a new one named ``precon`` (default
        parameters, the bound solver)."""
        chosen = self.own
        if precon is not None:
            chosen = make_preconditioner(
                cast(PreconName, precon), self.objective, solver=cast(Any, self.solver)
            )
        return run(self.objective, method, x, chosen, gtol=gtol, etol=etol, maxiter=maxiter)


class NumbaEngine(Engine):
    """The CPU engine: every method (``lbfgs``, ``cg``, ``fire``, ``newton``), preconditioner
    and geometry; the same bits on every CPU (``docs/decisions.md``, "Same input, same bits")
    except where a linear solver sums in its BLAS's order."""

    name = "numba"
    label = "the numba engine"
    capabilities = Capabilities(
        methods=("lbfgs", "cg", "fire", "newton"),
        preconditioners=PRECONDITIONERS,
        fire_preconditioned=True,
        solvers=True,
        walls=True,
        frozen=True,
        enthalpy=True,
    )

    def bind(self, objective: Objective, precon: str, *, A: float, solver: str) -> NumbaSession:
        """A :class:`NumbaSession`."""
        return NumbaSession(objective, precon, A=A, solver=solver)

    def machine_dependence(self, precon: str, solver: str, n: int, dim: int) -> str:
        """Empty but for a preconditioner solved by AMG, or by SciPy's SuperLU (cholespy
        missing): both call BLAS."""
        if precon == "none":
            return ""
        chosen = resolve_solver(cast(Any, solver), n, dim, m_matrix=precon == "exp")
        if chosen == "amg":
            return "AMG: pyamg's setup and coarse solve call BLAS"
        if chosen == "direct" and not available("cholespy"):
            return "SciPy's SuperLU (cholespy missing) calls BLAS"
        return ""
