"""The paper's Exp preconditioner on the device, applied as a fixed linear operator: one
smoothed-aggregation V-cycle on the scalar matrix ``L = mu (Lap_c + C_stab I)``, from a zero
start, with :data:`SWEEPS` damped Jacobi sweeps before and after each coarse correction and an
exact solve on the coarsest level.

The hierarchy (aggregates, smoothed prolongators ``P``, Galerkin operators ``P^T A P``) is
pyamg's (:func:`~athermal.linalg.aggregation_hierarchy`, the constant vector as near-null space),
set up on the host at the preconditioner's rebuilds
(:meth:`athermal.engines.precon.ExpPreconditioner
.assemble`, when a particle has moved ``r_cut / 4``); the cycle runs on the device as sparse
products over padded coordinate lists. Jacobi before and after, restriction ``P^T`` and an
exact coarse solve make the cycle symmetric, and a damping below ``2 / rho(D^-1 A)`` on every
level (:data:`DAMPING` over Gershgorin's bound on ``rho``; 2/3 on the finest, diagonally dominant
level) makes each sweep a contraction in the energy norm and the cycle positive definite: L-BFGS's
``H0 = gamma P^-1`` and CG's ``P^-1`` are a fixed operator between rebuilds, as the paper's
Cholesky solve is. Why a V-cycle and not a polynomial in ``L``: ``docs/decisions.md``, section
"The JAX engine".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ...linalg import aggregation_hierarchy
from ._pairs import capacity_for, padded

SWEEPS = 2
"""Damped Jacobi sweeps before and after each coarse correction."""
DAMPING = 4.0 / 3.0
"""Jacobi's damping on a level is this over Gershgorin's bound on ``rho(D^-1 A)`` there."""
MAX_COARSE = 64
"""Largest coarsest level, solved by its dense inverse."""


def _sparse(matrix: sp.spmatrix, capacity: int) -> tuple[Any, Any, Any]:
    """``matrix`` as padded device coordinates ``(rows, cols, values)`` (zero values, their
    indices spread: :func:`~._pairs.padded`)."""
    coo = matrix.tocoo()
    rows, cols = matrix.shape
    return (
        padded(coo.row.astype(np.int64), capacity, rows),
        padded(coo.col.astype(np.int64), capacity, cols),
        padded(coo.data.astype(np.float64), capacity),
    )


@dataclass(frozen=True)
class Hierarchy:
    """The V-cycle's levels on the device: ``levels`` holds, per level but the coarsest, ``A``
    and ``P`` as padded coordinates and the damped ``omega D^-1`` ``(rows,)`` (its length the
    level's padded size);
    ``coarse_inverse`` the coarsest level's dense inverse (padded with the identity);
    ``capacities`` the padded sizes (reused by the next build, so that the jitted loops compile
    again only when a level outgrows them); built at ``reference`` ``(N, d)``, due a rebuild
    beyond ``sqrt(reach_sq)``."""

    levels: tuple[tuple[Any, ...], ...]
    coarse_inverse: Any
    capacities: tuple[int, ...]
    reference: NDArray[np.float64]
    reach_sq: float

    @property
    def arrays(self) -> tuple[Any, ...]:
        """``(levels, coarse_inverse)``, as :func:`apply` takes them."""
        return self.levels, self.coarse_inverse

    @classmethod
    def of(
        cls,
        matrix: sp.csr_matrix,
        reference: NDArray[np.float64],
        reach_sq: float,
        capacities: tuple[int, ...] = (),
    ) -> Hierarchy:
        """The hierarchy of the SPD ``matrix`` ``(N, N)``; ``capacities`` those of the last
        build (grown where needed; a different number of levels starts afresh)."""
        ml = aggregation_hierarchy(matrix, np.ones((matrix.shape[0], 1)), MAX_COARSE)
        wanted = []
        for level in ml.levels[:-1]:
            wanted += [level.A.shape[0], level.A.nnz, level.P.nnz]
        wanted.append(ml.levels[-1].A.shape[0])
        old = capacities if len(capacities) == len(wanted) else (0,) * len(wanted)
        sizes = tuple(capacity_for(w, c) for w, c in zip(wanted, old, strict=True))
        if len(ml.levels) > 1:  # the finest level is the particles themselves: never padded
            sizes = (matrix.shape[0], *sizes[1:])
        levels = []
        for k, level in enumerate(ml.levels[:-1]):
            rows, a_nnz, p_nnz = sizes[3 * k : 3 * k + 3]
            diagonal = level.A.diagonal()
            bound = float((np.asarray(abs(level.A).sum(axis=1)).ravel() / diagonal).max())
            inverse_diagonal = np.ones(rows)
            inverse_diagonal[: level.A.shape[0]] = DAMPING / bound / diagonal
            levels.append(
                (
                    *_sparse(level.A, a_nnz),
                    *_sparse(level.P, p_nnz),
                    jnp.asarray(inverse_diagonal),
                )
            )
        coarse = ml.levels[-1].A.toarray()
        inverse = np.eye(sizes[-1])
        inverse[: coarse.shape[0], : coarse.shape[0]] = np.linalg.inv(coarse)
        return cls(
            tuple(levels),
            jnp.asarray(inverse),
            sizes,
            np.array(reference, copy=True),
            float(reach_sq),
        )


def _product(rows: Any, cols: Any, values: Any, v: Any, size: int) -> Any:
    """``M v`` for ``M`` in coordinates with ``size`` rows and ``v`` ``(columns, d)``."""
    return jnp.zeros((size, v.shape[1])).at[rows].add(values[:, None] * v[cols])


def _transposed(rows: Any, cols: Any, values: Any, v: Any, size: int) -> Any:
    """``M^T v`` for ``M`` in coordinates with ``size`` columns and ``v`` ``(rows, d)``."""
    return jnp.zeros((size, v.shape[1])).at[cols].add(values[:, None] * v[rows])


def _cycle(levels: tuple[tuple[Any, ...], ...], coarse_inverse: Any, b: Any) -> Any:
    """One V-cycle from zero for ``A_0 u = b`` over ``levels`` (see :class:`Hierarchy`)."""
    if not levels:
        return coarse_inverse @ b
    a_rows, a_cols, a_values, p_rows, p_cols, p_values, inverse_diagonal = levels[0]
    size = inverse_diagonal.shape[0]
    scale = inverse_diagonal[:, None]

    def residual(u: Any) -> Any:
        return b - _product(a_rows, a_cols, a_values, u, size)

    u = scale * b
    for _ in range(SWEEPS - 1):
        u = u + scale * residual(u)
    coarse_size = levels[1][6].shape[0] if len(levels) > 1 else coarse_inverse.shape[0]
    coarse = _transposed(p_rows, p_cols, p_values, residual(u), coarse_size)
    u = u + _product(p_rows, p_cols, p_values, _cycle(levels[1:], coarse_inverse, coarse), size)
    for _ in range(SWEEPS):
        u = u + scale * residual(u)
    return u


def apply(g: Any, levels: tuple[tuple[Any, ...], ...], coarse_inverse: Any) -> Any:
    """``P^-1 g`` ``(N, d)`` by one V-cycle (the ``d`` columns together); the padded rows of
    the finest level are cut off."""
    n = g.shape[0]
    size = levels[0][6].shape[0] if levels else coarse_inverse.shape[0]
    b = jnp.zeros((size, g.shape[1])).at[:n].set(g)
    return _cycle(levels, coarse_inverse, b)[:n]
