"""Minimization at fixed pressure: the enthalpy ``H = U + P V`` over the particle positions and
the cell (its volume, its volume and shape, or the gaps between its walls), with the package's
minimizers.

Variables. The cell is ``h = F h0`` with ``F`` upper triangular (the cell stays HOOMD's upper
triangular form) and the positions ``x_i = F u_i``; the minimizers see ``(u, c)`` with
``c = l (F - I)`` (``d x d``, the lower triangle fixed at 0), or, for the volume alone, ``F = (1
+ c_00 / l) I``. The length ``l = V0^(1/d) N^((d-2)/(2d))`` makes a cell variable as stiff as a
particle coordinate (``V B / l^2 ~ k`` for Hooke contacts, ``B`` the bulk modulus).

Gradients. With ``g_i = dU/dx_i`` and the stress ``sigma``, ``dH/du_i = F^T g_i`` and
``dH/dF = V (P I - sigma) F^-T`` (``dU/dF = -V sigma F^-T``, ``dV/dF = V F^-T``): at a minimum
the forces balance and ``sigma = P I`` (shape free; volume alone: ``p = P``), to the force
tolerance over ``l``; with the walls free, ``sigma_aa = P`` along each walled axis, the force per
unit area on its walls. With the shape free the shear stresses vanish, the packing is stable to
every shear of its cell, and its shear modulus is ``>= 0`` (shear-stabilized packings,
Dagois-Bohy et al., PRL 109, 095703 (2012)).

Each evaluation finds the contacts afresh (the cell changes at every step), many times the cost
of an evaluation in a fixed cell; a Verlet list that follows the cell is future work.

Preconditioner (:class:`EnthalpyPreconditioner`, ``precon="exp"``): optional, the default is
none; it pays with the shape free and at the larger N, not always at small N.

Measurements (the cost of an evaluation, iterations with and without the preconditioner):
``docs/decisions.md``, section "Minimization at fixed pressure".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ._portable import transform, upper_inverse
from ._validate import choice, positive_scalar
from .analysis.observables import stress
from .engines.precon import REBUILD_FRACTION, ExpPreconditioner
from .errors import InputError
from .minimize import CompiledSearch, Hooks, MinimizeResult
from .minimize.cg import cg
from .minimize.fire import fire
from .minimize.lbfgs import lbfgs
from .model.cell import Cell
from .model.contact import ContactModel, find_contacts, gradient, total_energy
from .model.objective import MAX_STEP_FACTOR, Objective
from .model.packing import Packing

CellFreedom = Literal["volume", "shape", "walls"]
"""What of the cell relaxes: its volume (isotropic), its volume and shape, or the gaps between
its walls (each walled axis stretched on its own: walls at a fixed force per unit area ``P``)."""
CELL_FREEDOMS: tuple[str, ...] = ("volume", "shape", "walls")
ENTHALPY_METHODS: tuple[str, ...] = ("lbfgs", "cg", "fire")
"""The minimizers that take an enthalpy."""
CELL_REBUILD = 0.05
""":class:`EnthalpyPreconditioner` rebuilds once the cell has strained this much."""


class Enthalpy:
    """``H = U + P V`` of ``packing`` as a function of ``(u, c)`` ``((N + d) d,)``, the
    :class:`~athermal.minimize.Problem` the minimizers need (module docstring).

    Parameters
    ----------
    packing : start configuration; its cell is ``h0`` (``c = 0``).
    model : contact law.
    pressure : ``P > 0`` (``k l^(alpha-d)``).
    cell : ``"volume"``, ``"shape"`` (a periodic cell) or ``"walls"`` (a cell with walls: at the
        minimum ``sigma_aa = P`` along each walled axis, the force per unit area on its walls).
    """

    def __init__(
        self, packing: Packing, model: ContactModel, pressure: float, cell: CellFreedom = "volume"
    ) -> None:
        self.model = model
        self.pressure = positive_scalar(pressure, "pressure")
        self.freedom = choice(cell, "cell", CELL_FREEDOMS)
        self.walls = packing.cell.walls
        if self.freedom == "walls" and not self.walls:
            raise InputError("cell: 'walls' frees the gaps between walls; this cell has none")
        if self.freedom == "shape" and self.walls:
            raise InputError(
                "cell: 'shape' would tilt a cell with walls; free the walls ('walls') or the "
                "volume ('volume')"
            )
        self.radii = packing.radii
        self.h0 = packing.cell.h
        self.v0 = packing.cell.volume
        self.n, self.dim = packing.n, packing.dim
        d = self.dim
        self.scale = self.v0 ** (1.0 / d) * self.n ** ((d - 2.0) / (2.0 * d))
        self.x0 = np.concatenate([packing.positions.ravel(), np.zeros(d * d)])
        self.max_step = MAX_STEP_FACTOR * float(np.mean(self.radii))
        eps = float(np.finfo(np.float64).eps)
        self.hooks = Hooks(d, self.max_step, (10.0 * eps, 1.0, 1.0))
        """Blocks of ``d``: a particle's gradient or a row of the cell block; steps capped at
        :attr:`max_step` per block; round-off ``10 eps H`` (``P V`` dominates ``H > 0``)."""
        self.n_evaluations = 0
        self._upper = np.triu(np.ones((d, d), dtype=bool))

    @property
    def n_dof(self) -> int:
        """``(N + d) d``: the positions, then the ``d x d`` cell block."""
        return (self.n + self.dim) * self.dim

    def compiled_search(self) -> CompiledSearch | None:
        """None: the enthalpy is evaluated from Python."""
        return None

    def deformation(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """``F`` ``(d, d)`` of the cell block of ``x``."""
        d = self.dim
        c = np.asarray(x[self.n * d :]).reshape(d, d)
        if self.freedom == "shape":
            return np.eye(d) + np.triu(c) / self.scale
        if self.freedom == "walls":
            f = np.eye(d)
            for a in self.walls:
                f[a, a] += c[a, a] / self.scale
            return f
        return (1.0 + c[0, 0] / self.scale) * np.eye(d)

    def packing(self, x: NDArray[np.float64], *, internal: bool = False) -> Packing:
        """The configuration at ``x``: positions ``F u``, cell ``F h0`` (one particle order)."""
        f = self.deformation(x)
        u = np.asarray(x[: self.n * self.dim]).reshape(self.n, self.dim)
        return Packing(transform(u, f), self.radii, Cell(transform(self.h0.T, f).T, self.walls))

    def __call__(self, x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        """``H`` and its gradient ``((N + d) d,)`` at ``x``."""
        f = self.deformation(x)
        if np.linalg.det(f) <= 0.0 or np.any(np.diag(f) <= 0.0):
            return float("inf"), np.zeros(self.n_dof)
        packing = self.packing(x)
        contacts = find_contacts(packing, self.model)
        self.n_evaluations += 1
        volume = packing.cell.volume
        sigma = stress(contacts, packing.cell)
        grad = np.empty(self.n_dof)
        d = self.dim
        grad[: self.n * d] = transform(gradient(contacts, self.n), f.T).ravel()
        d_f = volume * transform(self.pressure * np.eye(d) - sigma, upper_inverse(f))
        cell_grad = np.zeros((d, d))
        if self.freedom == "shape":
            cell_grad[self._upper] = d_f[self._upper] / self.scale
        elif self.freedom == "walls":
            for a in self.walls:
                cell_grad[a, a] = d_f[a, a] / self.scale
        else:
            cell_grad[0, 0] = np.trace(d_f) / self.scale
        grad[self.n * d :] = cell_grad.ravel()
        return total_energy(contacts) + self.pressure * volume, grad

    def curvature_bound(self, x: NDArray[np.float64]) -> float:
        """The particles' Gershgorin bound (:meth:`Objective.curvature_bound`, for FIRE's
        time step); the scale ``l`` makes the cell block's curvature comparable."""
        packing = self.packing(x)
        objective = Objective(packing, self.model, sort=False)
        return 2.0 * objective.curvature_bound(objective.x0)


class EnthalpyPreconditioner:
    """The Exp preconditioner extended to the cell: ``P = blockdiag(L (x) I_d, c I)`` on
    ``(u, c)``, with ``L`` the paper's Exp matrix of the current configuration
    (:class:`~athermal.engines.precon.ExpPreconditioner`) and ``c`` its mean diagonal entry (the
    cell variables are scaled to be as stiff as a particle coordinate). Rebuilt when a particle has
    moved a quarter of the cut-off, or the cell has strained by :data:`CELL_REBUILD`, since the
    last build."""

    name = "exp"

    def __init__(self, problem: Enthalpy) -> None:
        self.problem = problem
        self.n_builds = 0
        self.n_solves = 0
        self._exp: ExpPreconditioner | None = None
        self._cell_stiffness = 1.0
        self._reference: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None

    def update(self, x: NDArray[np.float64]) -> None:
        packing = self.problem.packing(x)
        f = self.problem.deformation(x)
        if self._exp is not None and self._reference is not None:
            positions, f_ref = self._reference
            moved = float(np.sqrt(((packing.positions - positions) ** 2).sum(axis=1)).max())
            relative = transform(upper_inverse(f_ref).T, f).T  # f f_ref^-1
            strained = float(np.abs(relative - np.eye(self.problem.dim)).max())
            if moved <= REBUILD_FRACTION * self._exp.r_cut and strained <= CELL_REBUILD:
                return
        objective = Objective(packing, self.problem.model, sort=False)
        self._exp = ExpPreconditioner(objective, solver="direct")
        self._exp.update(objective.x0)
        assert self._exp.matrix is not None
        self._cell_stiffness = float(np.mean(self._exp.matrix.diagonal()))
        self._reference = (packing.positions, f)
        self.n_builds += 1

    def _split(self, v: NDArray[np.float64]) -> tuple[ExpPreconditioner, int]:
        if self._exp is None:
            raise RuntimeError("enthalpy preconditioner: call update(x) first")
        return self._exp, self.problem.n * self.problem.dim

    def compiled_solver(self) -> None:
        """None: solved from Python."""
        return None

    def solve(self, g: NDArray[np.float64]) -> NDArray[np.float64]:
        """``P^-1 g``."""
        self.n_solves += 1
        exp, k = self._split(g)
        return np.concatenate([exp.solve(g[:k]), g[k:] / self._cell_stiffness])

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """``P v``."""
        exp, k = self._split(v)
        return np.concatenate([exp.dot(v[:k]), v[k:] * self._cell_stiffness])


@dataclass(frozen=True, eq=False)
class EnthalpyResult:
    """A packing at an enthalpy minimum at pressure ``target``.

    ``packing`` (positions and the relaxed cell), its ``pressure`` (``trace(sigma) / d``: with
    the walls free the target is ``sigma_aa`` of the walled axes, not this) and ``stress``
    ``(d, d)``, the cell deformation ``deformation`` ``F`` ``(d, d)`` from the start's cell, and the
    minimizer's ``result`` (iterations, evaluations, convergence).
    """

    packing: Packing
    target: float
    pressure: float
    stress: NDArray[np.float64]
    deformation: NDArray[np.float64]
    result: MinimizeResult


def check_enthalpy_method(method: str, precon: str) -> None:
    """:class:`InputError` unless ``method`` is one of :data:`ENTHALPY_METHODS` and ``precon``
    none or exp (the Exp preconditioner extended to the cell)."""
    if method not in ENTHALPY_METHODS:
        raise InputError(
            f"method: {method} cannot minimize an enthalpy; use {' / '.join(ENTHALPY_METHODS)}"
        )
    choice(precon, "precon", ("none", "exp"))


def relax_at_pressure(
    packing: Packing,
    model: ContactModel,
    pressure: float,
    *,
    cell: CellFreedom = "volume",
    method: str = "lbfgs",
    precon: str = "none",
    gtol: float | None = None,
    rtol: float = 1e-9,
    maxiter: int = 100_000,
) -> EnthalpyResult:
    """Minimize ``H = U + P V`` over the positions and the cell (``cell``: its volume, its
    volume and shape, or the gaps between its walls) from ``packing``, by ``method``
    (``lbfgs``, ``cg`` or ``fire``) with ``precon`` ``"none"`` or ``"exp"``
    (:class:`EnthalpyPreconditioner`).

    The tolerance is ``gtol`` on the largest block of the gradient (:attr:`Enthalpy.hooks`), or
    ``rtol`` x ``P <2r>^(d-1)``, the contact force a pressure ``P`` implies (near the mean contact
    force at the minimum: ``docs/decisions.md``, "Measured behind the code"). An unjammed start
    shrinks until it jams at pressure ``P``.

    Examples
    --------
    >>> from athermal import ContactModel, random_packing
    >>> r = relax_at_pressure(random_packing(64, 0.8, seed=1), ContactModel(), 1e-3)
    >>> r.result.converged, abs(r.pressure / 1e-3 - 1) < 1e-6
    (True, True)
    """
    check_enthalpy_method(method, precon)
    problem = Enthalpy(packing, model, pressure, cell)
    pre = EnthalpyPreconditioner(problem) if precon == "exp" else None
    if gtol is None:  # the start's forces may be far from those at P (an unjammed start)
        diameter = 2.0 * float(np.mean(packing.radii))
        gtol = positive_scalar(rtol, "rtol") * problem.pressure * diameter ** (packing.dim - 1)
    elif not np.isfinite(gtol) or gtol <= 0.0:
        raise InputError(f"gtol: must be finite and > 0, got {gtol!r}")
    if method == "lbfgs":  # H > 0: the etol stop never triggers
        result = lbfgs(problem, problem.x0, gtol=gtol, maxiter=maxiter, precon=pre)
    elif method == "cg":
        result = cg(problem, problem.x0, gtol=gtol, maxiter=maxiter, precon=pre)
    else:
        curvature = problem.curvature_bound(problem.x0) if pre is None else None
        result = fire(
            problem, problem.x0, gtol=gtol, maxiter=maxiter, precon=pre, curvature=curvature
        )
    final = problem.packing(result.x)
    sigma = stress(find_contacts(final, model), final.cell)
    return EnthalpyResult(
        packing=final,
        target=problem.pressure,
        pressure=float(np.trace(sigma) / final.dim),
        stress=sigma,
        deformation=problem.deformation(result.x),
        result=result,
    )
