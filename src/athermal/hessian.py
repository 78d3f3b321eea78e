"""The Hessian of the contact energy as a linear operator: matrix-free products for iterative
solves, and the sparse matrix for factorizations, from one set of per-contact blocks.

A contact between ``i`` and ``j`` with separation ``b = x_i - x_j`` (``l = |b|``, overlap
``delta``) has the block ``K = a b b^T - c I`` with ``a = kappa (alpha - 1 + delta/l) / l^2``,
``c = kappa delta/l`` and ``kappa = k delta^(alpha-2)`` (the seed's Hessian; ``c`` is the
destabilizing tangential term of a compressed contact). ``H`` holds ``+K`` on the blocks
``(i, i)`` and ``(j, j)`` and ``-K`` on ``(i, j)`` and ``(j, i)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from . import _kernels
from .contact import assemble_blocks


@dataclass(frozen=True, eq=False)
class HessianOperator:
    """``H`` ``(N d, N d)`` at one configuration: ``pairs (M, 2)``, ``sep (M, d)`` and
    ``coef (M, 2)`` = ``(a, c)`` of the ``M`` contact blocks (module doc), ``n`` particles."""

    n: int
    pairs: NDArray[np.int64]
    sep: NDArray[np.float64]
    coef: NDArray[np.float64]

    @property
    def shape(self) -> tuple[int, int]:
        size = self.n * self.sep.shape[1]
        return size, size

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """``H v`` for a flat ``v`` ``(N d,)``, by one compiled pass over the contacts."""
        d = self.sep.shape[1]
        out = np.empty(self.n * d)
        _kernels.hessian_product(
            self.pairs,
            self.sep,
            self.coef,
            np.ascontiguousarray(v, dtype=np.float64).reshape(self.n, d),
            out.reshape(self.n, d),
        )
        return out

    def matrix(self) -> sp.csr_matrix:
        """``H`` as a symmetric sparse matrix (for a factorization)."""
        d = self.sep.shape[1]
        outer = self.sep[:, :, None] * self.sep[:, None, :]
        blocks = self.coef[:, 0, None, None] * outer - self.coef[:, 1, None, None] * np.eye(d)
        return assemble_blocks(self.pairs[:, 0], self.pairs[:, 1], blocks, self.n)
