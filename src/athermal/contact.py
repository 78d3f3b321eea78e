"""Repulsive contact potential ``E_ij = k_ij delta^alpha / alpha`` for overlaps ``delta > 0``.

``delta = r_i + r_j - l`` with ``l = |x_i - x_j|`` (periodic image) and ``alpha >= 2``
(2 = Hooke, 2.5 = Hertz). The force on ``i`` from ``j`` is ``f = k delta^(alpha-1) n`` with
``n = (x_i - x_j) / l`` (seed eqs. for E_c and its derivatives). Energy in units of ``k`` x
length^alpha; forces in ``k`` x length^(alpha-1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from . import _kernels
from ._wolfe import evaluate
from .errors import InputError
from .neighbors import NeighborList
from .packing import Packing


@dataclass(frozen=True, eq=False)
class ContactModel:
    """Exponent ``alpha >= 2`` and stiffness: a scalar ``k`` or a symmetric ``(T, T)`` matrix
    giving ``k_ij`` by the species (``Packing.types()``) of ``i`` and ``j``."""

    alpha: float = 2.0
    stiffness: float | NDArray[np.float64] = 1.0
    kmat: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        alpha = float(self.alpha)
        if not np.isfinite(alpha) or alpha < 2.0:
            raise InputError(
                f"alpha: contact exponent must be a finite number >= 2, got {self.alpha!r}"
            )
        object.__setattr__(self, "alpha", alpha)
        kmat = np.atleast_2d(np.asarray(self.stiffness, dtype=np.float64))
        if kmat.ndim != 2 or kmat.shape[0] != kmat.shape[1]:
            raise InputError(
                f"stiffness: expected a scalar or a square matrix, got shape {kmat.shape}"
            )
        if not np.all(np.isfinite(kmat)) or np.any(kmat <= 0.0) or not np.allclose(kmat, kmat.T):
            raise InputError("stiffness: must be finite, > 0 and symmetric")
        kmat = np.ascontiguousarray(kmat)
        kmat.setflags(write=False)
        object.__setattr__(self, "kmat", kmat)
        if kmat.shape == (1, 1):
            object.__setattr__(self, "stiffness", float(kmat[0, 0]))

    def typeid(self, packing: Packing) -> NDArray[np.int32]:
        """Per-particle index ``(N,)`` into ``kmat`` (all zero for a scalar stiffness)."""
        if self.kmat.shape == (1, 1):
            return np.zeros(packing.n, dtype=np.int32)
        typeid, names = packing.types()
        if len(names) != self.kmat.shape[0]:
            raise InputError(
                f"stiffness: matrix is {self.kmat.shape[0]}x{self.kmat.shape[0]} but the packing "
                f"has {len(names)} species"
            )
        return typeid


def energy_gradient(
    positions: NDArray[np.float64],
    radii: NDArray[np.float64],
    typeid: NDArray[np.int32],
    shifts: NDArray[np.float64],
    nlist: NeighborList,
    model: ContactModel,
    grad: NDArray[np.float64],
) -> float:
    """Total energy; its gradient ``dE/dx`` ``(N, d)`` is written into ``grad`` (hot path).

    ``shifts`` is ``nlist.shifts(cell)``; all arrays C-contiguous float64 (no checks here).
    """
    return energy_gradient_contacts(positions, radii, typeid, shifts, nlist, model, grad)[0]


def energy_gradient_contacts(
    positions: NDArray[np.float64],
    radii: NDArray[np.float64],
    typeid: NDArray[np.int32],
    shifts: NDArray[np.float64],
    nlist: NeighborList,
    model: ContactModel,
    grad: NDArray[np.float64],
) -> tuple[float, int]:
    """:func:`energy_gradient` and the number of overlapping pairs, from the same pass."""
    energy, contacts = evaluate(
        positions,
        grad,
        radii,
        nlist.first,
        nlist.second,
        nlist.code,
        shifts,
        typeid,
        model.kmat,
        model.alpha,
    )
    return float(energy), int(contacts)


@dataclass(frozen=True, eq=False)
class Contacts:
    """The overlapping pairs (``delta > 0``) of a configuration, M of them.

    ``i, j`` ``(M,)``; ``branch`` ``(M, d)`` = ``x_i - x_j`` (periodic image); ``distance`` and
    ``overlap`` ``(M,)``; ``stiffness`` ``(M,)`` = ``k_ij``; ``alpha``.
    """

    i: NDArray[np.int64]
    j: NDArray[np.int64]
    branch: NDArray[np.float64]
    distance: NDArray[np.float64]
    overlap: NDArray[np.float64]
    stiffness: NDArray[np.float64]
    alpha: float

    def subset(self, keep: NDArray[np.bool_]) -> Contacts:
        """The contacts where ``keep`` ``(M,)`` is True."""
        return Contacts(
            self.i[keep],
            self.j[keep],
            self.branch[keep],
            self.distance[keep],
            self.overlap[keep],
            self.stiffness[keep],
            self.alpha,
        )

    @property
    def normal(self) -> NDArray[np.float64]:
        """Unit normals ``n = branch / distance`` ``(M, d)``, pointing from j to i."""
        return self.branch / self.distance[:, None]

    @property
    def force_magnitude(self) -> NDArray[np.float64]:
        """``k delta^(alpha-1)`` ``(M,)``, > 0 (repulsive)."""
        return self.stiffness * self.overlap ** (self.alpha - 1.0)

    @property
    def force(self) -> NDArray[np.float64]:
        """Force on ``i`` from ``j`` ``(M, d)``: ``k delta^(alpha-1) n``."""
        return self.force_magnitude[:, None] * self.normal

    @property
    def energy(self) -> NDArray[np.float64]:
        """Energy of each contact ``k delta^alpha / alpha`` ``(M,)``."""
        return self.stiffness * self.overlap**self.alpha / self.alpha


def find_contacts(
    packing: Packing, model: ContactModel, nlist: NeighborList | None = None
) -> Contacts:
    """All overlapping pairs of ``packing`` (a fresh neighbour list is built when none is given).

    Raises :class:`~athermal.errors.InputError` naming two particles whose centres coincide."""
    if nlist is None:
        from .neighbors import build_neighbor_list

        nlist = build_neighbor_list(packing.positions, packing.radii, packing.cell, skin=0.0)
    sep = nlist.separations(packing.positions, packing.cell)
    dist = np.sqrt(np.einsum("ij,ij->i", sep, sep))
    if np.any(dist == 0.0):
        k = int(np.flatnonzero(dist == 0.0)[0])
        raise InputError(
            f"particles {nlist.first[k]} and {nlist.second[k]} coincide (zero distance between "
            "their centres): no contact normal exists"
        )
    overlap = packing.radii[nlist.first] + packing.radii[nlist.second] - dist
    hit = overlap > 0.0
    typeid = model.typeid(packing)
    i, j = nlist.first[hit].astype(np.int64), nlist.second[hit].astype(np.int64)
    return Contacts(
        i, j, sep[hit], dist[hit], overlap[hit], model.kmat[typeid[i], typeid[j]], model.alpha
    )


def total_energy(contacts: Contacts) -> float:
    """Sum of the contact energies."""
    return float(contacts.energy.sum())


def gradient(contacts: Contacts, n: int) -> NDArray[np.float64]:
    """``dE/dx`` ``(N, d)`` from a contact set (vectorized reference of the compiled kernel)."""
    f = contacts.force
    grad = np.zeros((n, f.shape[1]))
    for axis in range(f.shape[1]):
        grad[:, axis] = np.bincount(contacts.j, f[:, axis], n) - np.bincount(
            contacts.i, f[:, axis], n
        )
    return grad


def contact_blocks(contacts: Contacts) -> NDArray[np.float64]:
    """Second derivatives ``d^2 E_c / dx_i dx_i`` ``(M, d, d)`` (seed eq. for the Hessian).

    ``K = k delta^(alpha-2) [(alpha - 1 + delta/l) n n^T - (delta/l) I]``; the ``(i, j)`` block is
    ``-K`` and ``(j, j)`` is ``K``.
    """
    n = contacts.normal
    d = n.shape[1]
    ratio = contacts.overlap / contacts.distance
    scale = contacts.stiffness * contacts.overlap ** (contacts.alpha - 2.0)
    nn = n[:, :, None] * n[:, None, :]
    return scale[:, None, None] * (
        (contacts.alpha - 1.0 + ratio)[:, None, None] * nn - ratio[:, None, None] * np.eye(d)
    )


def assemble_blocks(
    i: NDArray[np.int64], j: NDArray[np.int64], blocks: NDArray[np.float64], n: int
) -> sp.csr_matrix:
    """Symmetric ``(N d, N d)`` matrix: ``+K`` on blocks (i,i), (j,j) and ``-K`` on (i,j), (j,i).

    Pairs of a particle with its own image (``i == j``) contribute nothing, as for the Hessian.
    """
    indptr, indices, data = _kernels.block_csr(
        np.ascontiguousarray(i, dtype=np.int64),
        np.ascontiguousarray(j, dtype=np.int64),
        np.ascontiguousarray(blocks, dtype=np.float64),
        n,
    )
    size = n * blocks.shape[1]
    return sp.csr_matrix((data, indices, indptr), shape=(size, size))


def hessian(contacts: Contacts, n: int) -> sp.csr_matrix:
    """Sparse Hessian ``d^2 E / dx dx`` ``(N d, N d)``, symmetric, of the contact energy."""
    return assemble_blocks(contacts.i, contacts.j, contact_blocks(contacts), n)


def strain_derivative(contacts: Contacts) -> NDArray[np.float64]:
    """``dE/d(epsilon)`` ``(d, d)`` under the homogeneous deformation ``x -> (I + epsilon) x``.

    ``dE/d(epsilon_ab) = -sum_c f_a l_b`` (cell and positions deformed together); it equals
    ``-V sigma``.
    """
    return -np.einsum("ca,cb->ab", contacts.force, contacts.branch)


def packing_energy(packing: Packing, model: ContactModel) -> float:
    """Energy of ``packing`` (convenience; builds a neighbour list)."""
    return total_energy(find_contacts(packing, model))


@dataclass(frozen=True, eq=False)
class HessianOperator:
    """The Hessian ``H`` ``(N d, N d)`` at one configuration as a linear operator: matrix-free
    products for iterative solves, and the sparse matrix for factorizations.

    A contact's block (:func:`contact_blocks`) is written ``K = a b b^T - c I`` with ``b`` the
    branch vector ``x_i - x_j`` (``l = |b|``), ``a = kappa (alpha - 1 + delta/l) / l^2``,
    ``c = kappa delta/l`` and ``kappa = k delta^(alpha-2)``; ``pairs (M, 2)``, ``sep (M, d)``
    (= ``b``) and ``coef (M, 2)`` = ``(a, c)`` hold the ``M`` contacts of ``n`` particles
    (:meth:`athermal.objective.Objective.hessian` fills them by a compiled pass).
    """

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

    def contact_blocks(self, rows: NDArray[np.int64] | None = None) -> NDArray[np.float64]:
        """Each contact's block ``K = a b b^T - c I`` ``(M, d, d)``, or those of the contacts
        ``rows`` only."""
        if rows is None:
            rows = np.arange(self.pairs.shape[0])
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        out = np.empty((rows.size, self.sep.shape[1], self.sep.shape[1]))
        _kernels.pair_blocks(self.sep, self.coef, rows, out)
        return out

    def lowest_block_eigenvalue(self) -> float:
        """The smallest eigenvalue of the ``d x d`` diagonal blocks of ``H`` (``>= 0`` when it
        has none): ``H`` is indefinite where it is negative (its value is then an upper bound on
        the smallest eigenvalue of ``H``)."""
        d = self.sep.shape[1]
        diagonal = np.empty((self.n, d, d))
        _kernels.diagonal_blocks(self.pairs, self.sep, self.coef, diagonal)
        return float(np.linalg.eigvalsh(diagonal)[:, 0].min()) if self.n else 0.0

    def matrix(self) -> sp.csr_matrix:
        """``H`` as a symmetric sparse matrix (for a factorization)."""
        blocks = self.contact_blocks()
        return assemble_blocks(self.pairs[:, 0], self.pairs[:, 1], blocks, self.n)
