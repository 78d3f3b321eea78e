"""Preconditioners ``P`` approximating the Hessian, and the sparse solvers that apply ``P^-1``.

Two preconditioners satisfy :class:`~athermal.minimize.Preconditioner`:

* :class:`ExpPreconditioner`, the paper's universal preconditioner (section 3.2.2, after Packwood
  et al. 2016): ``u^T P u = mu sum_{0<|r_ij|<r_cut} c_ij |u_i - u_j|^2 + mu C_stab |u|^2`` with
  ``c_ij = exp(-A (r_ij / r_nn - 1))``. ``P = L (x) I_d`` for a scalar ``(N, N)`` matrix ``L``, so
  one factorization of ``L`` solves the ``d`` Cartesian components together.
* :class:`ContactPreconditioner`, beyond the paper, aimed at the soft modes near jamming:
  ``P = K_+ + L (x) I_d``, where ``K_+`` is the contact stiffness matrix built from the positive
  (normal) part of every contact's Hessian block and ``L`` is the Exp matrix as stabilization.

Flat vectors are ``(N d,)``, particle-major (``x.reshape(N, d)``), in the objective's internal
order. Both factor ``P`` once per rebuild and reuse the factor for every :meth:`solve`, with
the solvers of :mod:`athermal.linalg` (CHOLMOD, SuperLU without cholespy, AMG V-cycles, or the
incomplete Cholesky factor IC(0)).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .. import _blocks
from .._portable import sin_2pi, vdot
from .._validate import choice, positive_scalar
from ..errors import InputError
from ..linalg import (
    AMG_CYCLES,
    Factor,
    IncompleteCholeskyFactor,
    SolverName,
    factorize,
    pin_rows,
    resolve_solver,
)
from ..minimize import Preconditioner
from ..model.contact import assemble_blocks, find_contacts
from ..model.neighbors import build_neighbor_list
from ..model.objective import Objective

PreconName = Literal["none", "exp", "contact"]
PRECONDITIONERS: tuple[str, ...] = ("none", "exp", "contact")

R_CUT_FACTOR = 2.2
"""Default cut-off ``r_cut = 2.2 r_max`` (seed)."""
C_STAB = 0.1
"""Default stabilization ``C_stab`` (seed)."""
REBUILD_FRACTION = 0.25
"""Rebuild when a particle has moved more than ``REBUILD_FRACTION * r_cut`` (seed: 1/4)."""
SINE_AMPLITUDE = 1e-3
"""Amplitude of the sine test perturbation in units of ``r_cut`` (seed: ``M = 1e-3 r_cut``)."""
CONTACT_CHANGE = 0.1
"""The contact preconditioner rebuilds when the contact number changes by more than 10 %."""


def cutoff_pairs(
    positions: NDArray[np.float64], objective: Objective, r_cut: float
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """Pairs ``i < j`` with ``0 < |x_i - x_j + h n| < r_cut`` and their distances ``(P,)``.

    Periodic images count; ``r_cut`` below half the narrowest cell width makes each pair unique.
    """
    radii = np.full(objective.n, 0.5 * r_cut)
    nlist = build_neighbor_list(positions, radii, objective.cell, skin=0.0)
    sep = nlist.separations(positions, objective.cell)
    dist = np.sqrt(np.einsum("ij,ij->i", sep, sep))
    keep = (nlist.first != nlist.second) & (dist > 0.0)
    return (
        nlist.first[keep].astype(np.int64),
        nlist.second[keep].astype(np.int64),
        dist[keep],
    )


def nearest_neighbor_distance(
    i: NDArray[np.int64], j: NDArray[np.int64], dist: NDArray[np.float64], n: int, fallback: float
) -> float:
    """``r_nn``: the mean over particles with a pair of the distance to their nearest partner.

    ``fallback`` (length units) when there are no pairs at all.
    """
    if dist.size == 0:
        return fallback
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, i, dist)
    np.minimum.at(nearest, j, dist)
    return float(nearest[np.isfinite(nearest)].mean())


def exp_laplacian(
    i: NDArray[np.int64],
    j: NDArray[np.int64],
    dist: NDArray[np.float64],
    n: int,
    *,
    A: float,
    r_nn: float,
    c_stab: float,
) -> sp.csr_matrix:
    """``P_{mu=1}`` as the scalar ``(N, N)`` matrix: weighted graph Laplacian plus ``c_stab I``.

    Off-diagonal ``-c_ij``, diagonal ``sum_j c_ij + c_stab``, ``c_ij = exp(-A (r_ij/r_nn - 1))``.
    """
    c = np.exp(-A * (dist / r_nn - 1.0))
    diag = np.bincount(i, c, n) + np.bincount(j, c, n) + c_stab
    idx = np.arange(n)
    rows = np.concatenate([i, j, idx])
    cols = np.concatenate([j, i, idx])
    vals = np.concatenate([-c, -c, diag])
    return sp.csr_matrix(sp.coo_matrix((vals, (rows, cols)), shape=(n, n)))


def sine_perturbation(
    positions: NDArray[np.float64], objective: Objective, r_cut: float
) -> NDArray[np.float64]:
    """Test perturbation ``v = M sin(2 pi s)`` ``(N, d)``: ``s = h^-1 x``, ``M = 1e-3 r_cut``.

    Each Cartesian component ``a`` of ``v_i`` is ``M sin(2 pi s_ia)``: periodic in every lattice
    direction, so it is the same for every image of a particle, in any (tilted) cell.
    """
    s = objective.cell.fractional(positions)
    out: NDArray[np.float64] = SINE_AMPLITUDE * r_cut * sin_2pi(s)
    return out


class _PairPreconditioner(ABC):
    """Shared state and rebuild logic; subclasses assemble the matrix in :meth:`_assemble`."""

    name: str
    m_matrix: bool
    """Whether the factored matrix is an M-matrix (``solver="auto"`` may take IC(0) then)."""
    per_particle: bool
    """Whether the factored matrix has a row per particle (else one per coordinate)."""

    def __init__(
        self,
        objective: Objective,
        *,
        A: float = 0.0,
        r_cut: float | None = None,
        c_stab: float = C_STAB,
        mu: float | None = None,
        solver: SolverName = "auto",
        amg_cycles: int = AMG_CYCLES,
    ) -> None:
        self.objective = objective
        self.A = float(A)
        if not np.isfinite(self.A) or self.A < 0.0:
            raise InputError(f"A: must be a finite number >= 0, got {A!r}")
        rc = R_CUT_FACTOR * float(objective.radii.max()) if r_cut is None else r_cut
        self.r_cut = positive_scalar(rc, "r_cut")
        half_width = 0.5 * objective.cell.narrowest_width
        if self.r_cut >= half_width:
            raise InputError(
                f"r_cut: {self.r_cut:.6g} must be below half the narrowest cell width "
                f"({half_width:.6g}); use a larger cell or a smaller r_cut"
            )
        self.c_stab = positive_scalar(c_stab, "c_stab")
        self._fixed_mu = None if mu is None else positive_scalar(mu, "mu")
        if int(amg_cycles) != amg_cycles or amg_cycles < 1:
            raise InputError(f"amg_cycles: must be an integer >= 1, got {amg_cycles!r}")
        self.amg_cycles = int(amg_cycles)
        self.solver = resolve_solver(solver, objective.n, objective.dim, m_matrix=self.m_matrix)
        self.mu = float("nan")
        self.r_nn = float("nan")
        self.matrix: sp.csr_matrix | None = None
        self.backend = ""
        self.n_builds = 0
        self.n_factorizations = 0
        self.n_solves = 0
        self.build_seconds = 0.0
        self.factorize_seconds = 0.0
        self._factor: Factor | None = None
        self._reference: NDArray[np.float64] | None = None

    def update(self, x: NDArray[np.float64]) -> None:
        """Rebuild ``P`` at ``x`` ``(N d,)`` if this is the first call or :meth:`_stale` says so."""
        if np.shape(x) != (self.objective.n_dof,):
            raise InputError(f"x: expected shape ({self.objective.n_dof},), got {np.shape(x)}")
        positions = np.ascontiguousarray(x, dtype=np.float64).reshape(
            self.objective.n, self.objective.dim
        )
        if self._reference is None or self._stale(positions):
            self._rebuild(positions)

    def compiled_solver(self) -> tuple[Any, ...] | None:
        """None: solved from Python (:class:`ExpPreconditioner` with ``ic0`` is solved in
        compiled code)."""
        return None

    def _stale(self, positions: NDArray[np.float64]) -> bool:
        """True when a particle moved more than ``r_cut / 4`` since the last build."""
        moved_sq = _blocks.max_displacement_sq(positions, self._reference)
        return bool(moved_sq > self._reach_sq)

    @property
    def reach(self) -> float:
        """Displacement of a particle since the last build beyond which ``P`` is rebuilt,
        ``REBUILD_FRACTION r_cut`` (length units)."""
        return REBUILD_FRACTION * self.r_cut

    @property
    def _reach_sq(self) -> float:
        return self.reach**2

    def _exp_part(self, positions: NDArray[np.float64]) -> sp.csr_matrix:
        """The scalar Exp matrix ``mu P_{mu=1}`` at ``positions``; sets ``r_nn`` and ``mu``."""
        n = self.objective.n
        i, j, dist = cutoff_pairs(positions, self.objective, self.r_cut)
        fallback = 2.0 * float(self.objective.radii.mean())
        self.r_nn = nearest_neighbor_distance(i, j, dist, n, fallback)
        unit = exp_laplacian(i, j, dist, n, A=self.A, r_nn=self.r_nn, c_stab=self.c_stab)
        self.mu = (
            self._fixed_mu if self._fixed_mu is not None else self._estimate_mu(positions, unit)
        )
        return sp.csr_matrix(self.mu * unit)

    def _estimate_mu(self, positions: NDArray[np.float64], unit: sp.csr_matrix) -> float:
        """Seed's energy scale: ``mu = v.(grad E(x + v) - grad E(x)) / (v^T P_{mu=1} v)``.

        ``v`` is :func:`sine_perturbation`. Costs one objective evaluation when ``grad E(x)`` is
        the objective's cached one, else two; the objective's cache then holds ``x + v``. When
        the ratio is not finite and > 0 (no contacts, ``E = 0``), the previous ``mu`` is kept, or
        on the first build the mean contact stiffness ``k`` (the Hooke scale; 1 in the paper's
        units).

        The test mode is the cell's longest wavelength, where ``v^T P_{mu=1} v`` is mostly the
        ``C_stab`` term, so ``mu`` falls with ``N`` at fixed density (Case 1 type packings:
        0.069 at N = 4096, 0.0054 at N = 65536). L-BFGS does not rely on it: its
        ``H0 = gamma P^-1`` rescales ``P`` at every iteration; FIRE and CG use ``mu`` as is.
        """
        v = sine_perturbation(positions, self.objective, self.r_cut)
        x = positions.ravel()
        _, g0 = self.objective(x)
        _, g1 = self.objective(x + v.ravel())
        numerator = vdot(v, g1 - g0)
        denominator = vdot(v, unit @ v)
        with np.errstate(divide="ignore", invalid="ignore"):
            mu = numerator / denominator if denominator > 0.0 else float("nan")
        if np.isfinite(mu) and mu > 0.0:
            return mu
        if np.isfinite(self.mu):
            return self.mu
        return float(np.mean(self.objective.model.kmat))

    @abstractmethod
    def _assemble(self, positions: NDArray[np.float64]) -> sp.csr_matrix:
        """The matrix ``P`` to factor at ``positions`` ``(N, d)`` (sets ``r_nn`` and ``mu``)."""

    @abstractmethod
    def _near_null(self) -> NDArray[np.float64]:
        """Near-null space of ``P`` for AMG: its rigid translations, one per column."""

    def _rebuild(self, positions: NDArray[np.float64]) -> None:
        start = time.perf_counter()
        self.matrix = self._assemble(positions)
        obj = self.objective
        if obj.frozen_rows.size:  # the frozen particles held: P^-1 g is zero on their rows
            rows = obj.frozen_particles if self.per_particle else obj.frozen_rows
            self.matrix = pin_rows(self.matrix, rows)
        mid = time.perf_counter()
        self._factor = factorize(self.matrix, self.solver, self.amg_cycles, self._near_null())
        end = time.perf_counter()
        self.backend = self._factor.backend
        self._reference = positions.copy()
        self.n_builds += 1
        self.n_factorizations += 1
        self.factorize_seconds += end - mid
        self.build_seconds += end - start

    def _ready(self, vec: NDArray[np.float64], what: str) -> tuple[sp.csr_matrix, Factor]:
        if self.matrix is None or self._factor is None:
            raise RuntimeError(f"{self.name} preconditioner: call update(x) before {what}()")
        if np.shape(vec) != (self.objective.n_dof,):
            raise InputError(
                f"{what}: expected shape ({self.objective.n_dof},), got {np.shape(vec)}"
            )
        return self.matrix, self._factor


class ExpPreconditioner(_PairPreconditioner):
    """The paper's universal preconditioner ``P = L (x) I_d`` (Exp, section 3.2.2).

    ``L = mu (Lap_c + C_stab I)`` ``(N, N)``: ``Lap_c`` is the graph Laplacian of the pairs
    closer than ``r_cut`` (periodic images included) weighted by ``c_ij = exp(-A (r_ij/r_nn - 1))``.

    Parameters
    ----------
    objective : supplies ``N``, ``d``, radii, cell and (for ``mu``) gradients.
    A : decay of the weights with distance (``A = 0``: plain adjacency, the paper's choice).
    r_cut : pair cut-off (length units); default ``2.2 r_max``; must be below half the narrowest
        cell width.
    c_stab : stabilization ``C_stab`` (dimensionless, > 0).
    mu : energy scale (energy / length^2); default re-estimated at every build by the paper's
        sine test (:meth:`_estimate_mu`).
    solver : ``"direct"`` (cholespy Cholesky, SciPy ``splu`` without cholespy), ``"amg"``
        (pyamg, ``amg_cycles`` V-cycles), ``"ic0"`` (zero-fill incomplete Cholesky,
        :class:`~athermal.linalg.IncompleteCholeskyFactor`) or ``"auto"`` (ic0 for
        N < 200 000; from there direct below 2 000 000 in 2D, else AMG, direct without pyamg;
        :data:`~athermal.linalg.AUTO_IC0_MAX_N` has the measurements).
    amg_cycles : V-cycles per AMG application (default 1).

    Attributes
    ----------
    matrix : the factored matrix, here ``L`` ``(N, N)`` CSR including ``mu``.
    mu, r_nn : energy scale and nearest-neighbour distance of the last build.
    solver, backend : ``"direct"``/``"amg"``/``"ic0"`` and
        ``"cholespy"``/``"splu"``/``"pyamg"``/``"ic0"``.
    n_builds, n_factorizations, n_solves : counters.
    build_seconds, factorize_seconds : wall time spent in builds (factorization included) and
        in factorizations alone.

    Notes
    -----
    ``r_nn`` is the mean over particles of the distance to their nearest partner within
    ``r_cut`` (particles without one are left out; ``2 <r>`` when no pair exists). ``P`` is
    rebuilt (pairs, ``r_nn``, ``mu``, factorization) on the first :meth:`update` and whenever a
    particle has moved more than ``r_cut / 4`` since the last build.

    Examples
    --------
    >>> from athermal.model.contact import ContactModel
    >>> from athermal.model.packing import random_packing
    >>> obj = Objective(random_packing(64, 0.9, seed=1), ContactModel())
    >>> precon = ExpPreconditioner(obj, solver="direct")
    >>> precon.update(obj.x0)
    >>> bool(np.allclose(precon.dot(precon.solve(obj.x0)), obj.x0))
    True
    """

    name = "exp"
    m_matrix = True
    per_particle = True

    def _assemble(self, positions: NDArray[np.float64]) -> sp.csr_matrix:
        return self._exp_part(positions)

    def _near_null(self) -> NDArray[np.float64]:
        return np.ones((self.objective.n, 1))

    def assemble(self, x: NDArray[np.float64]) -> sp.csr_matrix:
        """``L`` ``(N, N)`` at ``x`` ``(N d,)``, not factored (sets ``r_nn`` and ``mu``, counts
        a build): for an engine that applies ``P^-1`` its own way
        (:mod:`athermal.engines.jax.device`)."""
        if np.shape(x) != (self.objective.n_dof,):
            raise InputError(f"x: expected shape ({self.objective.n_dof},), got {np.shape(x)}")
        positions = np.ascontiguousarray(x, dtype=np.float64).reshape(
            self.objective.n, self.objective.dim
        )
        self.n_builds += 1
        return self._exp_part(positions)

    def solve(self, g: NDArray[np.float64]) -> NDArray[np.float64]:
        """``P^-1 g`` ``(N d,)``: the ``d`` columns of ``g.reshape(N, d)`` solved together."""
        _, factor = self._ready(g, "solve")
        self.n_solves += 1
        rhs = np.asarray(g, dtype=np.float64).reshape(self.objective.n, self.objective.dim)
        return factor.solve(rhs).ravel()

    def compiled_solver(
        self,
    ) -> tuple[tuple[NDArray[Any], ...], NDArray[np.float64], float] | None:
        """The incomplete factor's arrays (:meth:`~athermal.linalg.IncompleteCholeskyFactor
        .arrays`), the positions ``(N, d)`` of the last build and the squared displacement up
        to which it holds, for a solve in compiled code; None unless built with ``ic0``."""
        if not isinstance(self._factor, IncompleteCholeskyFactor) or self._reference is None:
            return None
        return self._factor.arrays(), self._reference, self._reach_sq

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """``P v = (L (x) I_d) v`` ``(N d,)``."""
        matrix, _ = self._ready(v, "dot")
        block = np.asarray(v, dtype=np.float64).reshape(self.objective.n, self.objective.dim)
        return np.asarray(matrix @ block).ravel()


class ContactPreconditioner(_PairPreconditioner):
    """Contact stiffness plus Exp stabilization: ``P = K_+ + L (x) I_d`` ``(N d, N d)``.

    ``K_+`` is assembled from the current contacts with the positive part of each contact's
    Hessian block, ``E'' n n^T`` (the law's stiffness; the tangential term ``-(f/l) (I - n
    n^T)`` is dropped, so ``K_+`` is positive semidefinite and
    ``P`` is SPD). ``L`` is the :class:`ExpPreconditioner` matrix with its own sine-test ``mu``.

    Parameters and attributes are those of :class:`ExpPreconditioner` (``matrix`` is ``P``
    ``(N d, N d)``, ``exp_matrix`` its ``L`` ``(N, N)``, ``n_contacts`` the contact number at
    the last build), plus ``contact_change`` (default 0.1):
    besides the ``r_cut / 4`` displacement rule, ``P`` is rebuilt when the number of contacts
    ``M`` differs from its value ``M_b`` at the last build by more than ``contact_change * M_b``
    (any contact appearing when ``M_b = 0``). The AMG solver works on the ``(N d)`` system with
    the ``d`` rigid translations as near-null space. ``P`` is no M-matrix, so ``solver="auto"``
    never takes ic0 here (it takes more iterations than direct: ``docs/decisions.md``, "Measured
    behind the code").
    """

    name = "contact"
    m_matrix = False
    per_particle = False

    def __init__(
        self,
        objective: Objective,
        *,
        A: float = 0.0,
        r_cut: float | None = None,
        c_stab: float = C_STAB,
        mu: float | None = None,
        solver: SolverName = "auto",
        amg_cycles: int = AMG_CYCLES,
        contact_change: float = CONTACT_CHANGE,
    ) -> None:
        super().__init__(
            objective, A=A, r_cut=r_cut, c_stab=c_stab, mu=mu, solver=solver, amg_cycles=amg_cycles
        )
        self.contact_change = positive_scalar(contact_change, "contact_change")
        self.n_contacts = 0
        self.exp_matrix: sp.csr_matrix | None = None

    def count_contacts(self, positions: NDArray[np.float64]) -> int:
        """Number of overlapping pairs at ``positions`` ``(N, d)``.

        Uses (and when stale, rebuilds) the objective's Verlet list.
        """
        return self.objective.count_contacts(positions.ravel())

    def _stale(self, positions: NDArray[np.float64]) -> bool:
        if super()._stale(positions):
            return True
        change = abs(self.count_contacts(positions) - self.n_contacts)
        return change > self.contact_change * self.n_contacts

    def _assemble(self, positions: NDArray[np.float64]) -> sp.csr_matrix:
        obj = self.objective
        self.exp_matrix = self._exp_part(positions)
        contacts = find_contacts(
            obj.packing(positions.ravel(), internal=True),
            obj.model,
            obj.neighbor_list(positions.ravel()),
        )
        scale = contacts.normal_stiffness
        normal = contacts.normal
        blocks = scale[:, None, None] * normal[:, :, None] * normal[:, None, :]
        stiffness = assemble_blocks(contacts.i, contacts.j, blocks, obj.n)
        self.n_contacts = self.count_contacts(positions)
        return sp.csr_matrix(stiffness + sp.kron(self.exp_matrix, sp.eye(obj.dim), format="csr"))

    def _near_null(self) -> NDArray[np.float64]:
        return np.tile(np.eye(self.objective.dim), (self.objective.n, 1))

    def solve(self, g: NDArray[np.float64]) -> NDArray[np.float64]:
        """``P^-1 g`` ``(N d,)``."""
        _, factor = self._ready(g, "solve")
        self.n_solves += 1
        return factor.solve(np.asarray(g, dtype=np.float64).reshape(-1, 1)).ravel()

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """``P v`` ``(N d,)``."""
        matrix, _ = self._ready(v, "dot")
        return np.asarray(matrix @ np.asarray(v, dtype=np.float64))


def make_preconditioner(
    name: PreconName, objective: Objective, *, A: float = 0.0, solver: SolverName = "auto"
) -> Preconditioner | None:
    """The preconditioner called ``name`` (``"none"``, ``"exp"``, ``"contact"``) for ``objective``.

    ``"none"`` gives ``None``; the others use their default parameters with ``A`` and ``solver``.
    """
    choice(name, "precon", PRECONDITIONERS)
    if name == "exp":
        return ExpPreconditioner(objective, A=A, solver=solver)
    if name == "contact":
        return ContactPreconditioner(objective, A=A, solver=solver)
    return None
