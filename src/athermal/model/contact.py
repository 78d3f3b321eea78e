"""Repulsive contacts between particles of overlap ``delta = r_i + r_j - l > 0``, ``l = |x_i -
x_j|`` (periodic image), each storing the contact law's energy ``E(delta)`` (default ``k
delta^alpha / alpha``, :mod:`athermal.model.law`): the contact model, the contact set and its
energy, gradient, Hessian and strain derivative (vectorized), the Hessian as an operator, and the
entry to the compiled pair loops (:mod:`athermal.model.loops`). The force on ``i`` from ``j`` is
``f n`` with ``n = (x_i - x_j) / l``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .._portable import outer_sum, row_norms
from ..errors import InputError
from .cell import Cell
from .law import ContactLaw, LawContacts, PowerContact
from .loops import (
    NO_WALLS,
    block_csr,
    diagonal_blocks,
    hessian_product,
    kernels,
    pair_blocks,
    parallel_slabs,
)
from .neighbors import NeighborList
from .packing import Packing
from .walls import WallContacts, find_wall_contacts, wall_gradient, wall_hessian

Walls = tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]
"""What the kernels take of a cell's walls: the walled axes ``(W,)``, the half lengths
``L_a / 2`` ``(W,)`` (the walls at ``x_a = -+L_a / 2``) and the wall stiffness by species
``(T,)``; every array empty or ``(T,)`` for a periodic cell."""


@dataclass(frozen=True, eq=False)
class ContactModel:
    """The contact law and stiffness: a scalar ``k`` or a symmetric ``(T, T)`` matrix giving
    ``k_ij`` by the species (``Packing.types()``) of ``i`` and ``j``; ``wall_stiffness`` ``k_w``
    of a particle's contact with a wall (default its species' own ``k_ii``). The law is
    ``law`` or, when none is given, :class:`~athermal.model.law.PowerContact` of exponent ``alpha
    >= 2``; ``alpha`` is then the law's small-overlap exponent."""

    alpha: float = 2.0
    stiffness: float | NDArray[np.float64] = 1.0
    wall_stiffness: float | None = None
    law: ContactLaw = None  # type: ignore[assignment]
    kmat: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.law is None:
            object.__setattr__(self, "law", PowerContact(self.alpha))
        elif not isinstance(self.law, ContactLaw):
            raise InputError(f"law: expected a ContactLaw, got {type(self.law).__name__}")
        elif float(self.alpha) not in (2.0, self.law.alpha):
            raise InputError(
                f"alpha: the law {self.law.name} has its own exponent {self.law.alpha:g}; "
                "give alpha or a law, not both"
            )
        object.__setattr__(self, "alpha", float(self.law.alpha))
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
        if self.wall_stiffness is not None:
            wall = float(self.wall_stiffness)
            if not np.isfinite(wall) or wall <= 0.0:
                raise InputError(f"wall_stiffness: must be finite and > 0, got {wall}")
            object.__setattr__(self, "wall_stiffness", wall)

    @property
    def kwall(self) -> NDArray[np.float64]:
        """Wall stiffness ``(T,)`` by species: ``wall_stiffness``, or the diagonal of ``kmat``."""
        if self.wall_stiffness is None:
            return np.ascontiguousarray(np.diag(self.kmat))
        return np.full(self.kmat.shape[0], self.wall_stiffness)

    def walls(self, cell: Cell) -> Walls:
        """The wall arguments of the compiled kernels for ``cell`` (:data:`Walls`)."""
        return (
            np.array(cell.walls, dtype=np.int64),
            np.array([0.5 * cell.h[a, a] for a in cell.walls]),
            self.kwall,
        )

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
    """Total energy; its gradient ``dE/dx`` ``(N, d)`` is written into ``grad`` (hot path, one
    thread).

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
    walls: Walls | None = None,
    slabs: tuple[NDArray[np.int64], bool] | None = None,
) -> tuple[float, int]:
    """:func:`energy_gradient` and the number of overlapping pairs and wall contacts, from the
    same pass (``walls``: :meth:`ContactModel.walls`, none: a periodic cell; ``slabs``:
    :func:`parallel_slabs` of ``nlist``, found here when not given)."""
    if walls is None:
        walls = (*NO_WALLS, model.kwall)
    if slabs is None:
        slabs = parallel_slabs(nlist)
    energy, contacts = kernels(model.law)["evaluate"](
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
        *walls,
        *slabs,
    )
    return float(energy), int(contacts)


@dataclass(frozen=True, eq=False)
class Contacts(LawContacts):
    """The overlapping pairs (``delta > 0``) of a configuration, M of them.

    ``i, j`` ``(M,)``; ``branch`` ``(M, d)`` = ``x_i - x_j`` (periodic image); ``distance`` and
    ``overlap`` ``(M,)``; ``stiffness`` ``(M,)`` = ``k_ij``; the contact ``law``; ``walls`` the
    particles' contacts with the cell's walls (None: no walls). Forces and energies by the law
    (:class:`~athermal.model.law.LawContacts`; the force is on ``i`` from ``j``). The functions
    below (energy, gradient, Hessian, stress) count both.
    """

    i: NDArray[np.int64]
    j: NDArray[np.int64]
    branch: NDArray[np.float64]
    distance: NDArray[np.float64]
    overlap: NDArray[np.float64]
    stiffness: NDArray[np.float64]
    law: ContactLaw
    walls: WallContacts | None = None

    def subset(self, keep: NDArray[np.bool_]) -> Contacts:
        """The pair contacts where ``keep`` ``(M,)`` is True (the wall contacts kept)."""
        return Contacts(
            self.i[keep],
            self.j[keep],
            self.branch[keep],
            self.distance[keep],
            self.overlap[keep],
            self.stiffness[keep],
            self.law,
            self.walls,
        )

    @property
    def alpha(self) -> float:
        """The law's small-overlap exponent (:attr:`~athermal.model.law.ContactLaw.alpha`)."""
        return self.law.alpha

    def overlaps_in(self, packing: Packing) -> NDArray[np.float64]:
        """The overlaps of these pairs (nearest image) and then of these wall contacts, with the
        particles where ``packing`` has them (negative where a contact has opened)."""
        sep = packing.cell.minimum_image(packing.positions[self.i] - packing.positions[self.j])
        pairs = packing.radii[self.i] + packing.radii[self.j] - row_norms(sep)
        if self.walls is None:
            return pairs
        walls = self.walls.overlaps_in(packing.positions, packing.radii, packing.cell)
        return np.concatenate([pairs, walls])

    @property
    def count(self) -> int:
        """Pair contacts and wall contacts together."""
        return int(self.i.size) + (0 if self.walls is None else int(self.walls.particle.size))

    @property
    def normal(self) -> NDArray[np.float64]:
        """Unit normals ``n = branch / distance`` ``(M, d)``, pointing from j to i."""
        return self.branch / self.distance[:, None]


def find_contacts(
    packing: Packing, model: ContactModel, nlist: NeighborList | None = None
) -> Contacts:
    """All overlapping pairs of ``packing`` (a fresh neighbour list is built when none is given)
    and its wall contacts.

    Raises :class:`~athermal.errors.InputError` naming two particles whose centres coincide."""
    if nlist is None:
        from .neighbors import build_neighbor_list

        nlist = build_neighbor_list(packing.positions, packing.radii, packing.cell, skin=0.0)
    sep = nlist.separations(packing.positions, packing.cell)
    dist = row_norms(sep)
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
    walls = None
    if packing.cell.walls:
        kwall = model.kwall[typeid]
        walls = find_wall_contacts(packing.positions, packing.radii, kwall, model.law, packing.cell)
    return Contacts(
        i,
        j,
        sep[hit],
        dist[hit],
        overlap[hit],
        model.kmat[typeid[i], typeid[j]],
        model.law,
        walls,
    )


def total_energy(contacts: Contacts) -> float:
    """Sum of the contact energies (walls' included)."""
    walls = 0.0 if contacts.walls is None else float(contacts.walls.energy.sum())
    return float(contacts.energy.sum()) + walls


def gradient(contacts: Contacts, n: int) -> NDArray[np.float64]:
    """``dE/dx`` ``(N, d)`` from a contact set (vectorized reference of the compiled kernel)."""
    f = contacts.force
    grad = np.zeros((n, f.shape[1]))
    for axis in range(f.shape[1]):
        grad[:, axis] = np.bincount(contacts.j, f[:, axis], n) - np.bincount(
            contacts.i, f[:, axis], n
        )
    if contacts.walls is not None:
        grad += wall_gradient(contacts.walls, n)
    return grad


def contact_blocks(contacts: Contacts) -> NDArray[np.float64]:
    """Second derivatives ``d^2 E_c / dx_i dx_i`` ``(M, d, d)`` (seed eq. for the Hessian).

    ``K = E'' n n^T - (f / l) (I - n n^T)``; the ``(i, j)`` block is ``-K`` and ``(j, j)`` is
    ``K``.
    """
    n = contacts.normal
    d = n.shape[1]
    pull = contacts.force_magnitude / contacts.distance
    nn = n[:, :, None] * n[:, None, :]
    return (contacts.normal_stiffness + pull)[:, None, None] * nn - pull[:, None, None] * np.eye(d)


def hessian_floor(contacts: Contacts, n: int) -> float:
    """A lower bound (<= 0) on the eigenvalues of the Hessian of ``contacts`` among ``n``
    particles, and so of every principal submatrix of it (the non-rattlers', pinned or not).

    A contact's block ``K = E'' n n^T - (f / l) (I - n n^T)`` is at least ``-m I`` with ``m =
    max(0, f / l, -E'')``, so the Hessian is at least ``-L_m`` (x the identity in the ``d``
    axes), ``L_m`` the graph Laplacian weighted by ``m``, whose largest eigenvalue is at most the
    largest ``w_i + w_j`` over the contacts (Anderson & Morley), ``w`` a particle's summed
    ``m``; a wall contact's entry ``E''`` adds ``max(0, -E'')`` to its particle's diagonal.
    """
    pull = contacts.force_magnitude / contacts.distance
    m = np.maximum(np.maximum(pull, -contacts.normal_stiffness), 0.0)
    w = np.bincount(contacts.i, m, n) + np.bincount(contacts.j, m, n)
    bound = float(np.max(w[contacts.i] + w[contacts.j], initial=0.0))
    if contacts.walls is not None:
        wall = np.maximum(-contacts.walls.normal_stiffness, 0.0)
        bound += float(np.max(np.bincount(contacts.walls.particle, wall, n), initial=0.0))
    return -bound


def assemble_blocks(
    i: NDArray[np.int64], j: NDArray[np.int64], blocks: NDArray[np.float64], n: int
) -> sp.csr_matrix:
    """Symmetric ``(N d, N d)`` matrix: ``+K`` on blocks (i,i), (j,j) and ``-K`` on (i,j), (j,i).

    Pairs of a particle with its own image (``i == j``) contribute nothing, as for the Hessian.
    """
    indptr, indices, data = block_csr(
        np.ascontiguousarray(i, dtype=np.int64),
        np.ascontiguousarray(j, dtype=np.int64),
        np.ascontiguousarray(blocks, dtype=np.float64),
        n,
    )
    size = n * blocks.shape[1]
    return sp.csr_matrix((data, indices, indptr), shape=(size, size))


def hessian(contacts: Contacts, n: int) -> sp.csr_matrix:
    """Sparse Hessian ``d^2 E / dx dx`` ``(N d, N d)``, symmetric, of the contact energy."""
    h = assemble_blocks(contacts.i, contacts.j, contact_blocks(contacts), n)
    if contacts.walls is not None and contacts.walls.particle.size:
        h = (h + wall_hessian(contacts.walls, n)).tocsr()
    return h


def strain_derivative(contacts: Contacts) -> NDArray[np.float64]:
    """``dE/d(epsilon)`` ``(d, d)`` under the homogeneous deformation ``x -> (I + epsilon) x``.

    ``dE/d(epsilon_ab) = -sum_c f_a l_b`` (cell, walls and positions deformed together; a wall
    contact's ``l`` from the wall to the centre); it equals ``-V sigma``.
    """
    out = -outer_sum(contacts.force, contacts.branch)
    if contacts.walls is not None:
        out -= outer_sum(contacts.walls.force, contacts.walls.branch)
    return out


def packing_energy(packing: Packing, model: ContactModel) -> float:
    """Energy of ``packing`` (convenience; builds a neighbour list)."""
    return total_energy(find_contacts(packing, model))


@dataclass(frozen=True, eq=False)
class HessianOperator:
    """The Hessian ``H`` ``(N d, N d)`` at one configuration as a linear operator: matrix-free
    products for iterative solves, and the sparse matrix for factorizations.

    A contact's block (:func:`contact_blocks`) is written ``K = a b b^T - c I`` with ``b`` the
    branch vector ``x_i - x_j`` (``l = |b|``), ``a = (E'' + f/l) / l^2`` and ``c = f/l``;
    ``pairs (M, 2)``, ``sep (M, d)``
    (= ``b``) and ``coef (M, 2)`` = ``(a, c)`` hold the ``M`` contacts of ``n`` particles
    (:meth:`athermal.model.objective.Objective.hessian` fills them by a compiled pass). ``walls``:
    the wall contacts' diagonal entries, particle, axis and value ``(W,)`` each
    (:meth:`athermal.model.walls.WallContacts.hessian_terms`).
    """

    n: int
    pairs: NDArray[np.int64]
    sep: NDArray[np.float64]
    coef: NDArray[np.float64]
    walls: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]] = (
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        np.zeros(0),
    )

    @property
    def shape(self) -> tuple[int, int]:
        size = self.n * self.sep.shape[1]
        return size, size

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """``H v`` for a flat ``v`` ``(N d,)``, by one compiled pass over the contacts."""
        d = self.sep.shape[1]
        out = np.empty(self.n * d)
        hessian_product(
            self.pairs,
            self.sep,
            self.coef,
            np.ascontiguousarray(v, dtype=np.float64).reshape(self.n, d),
            out.reshape(self.n, d),
        )
        particle, axis, value = self.walls
        if particle.size:
            index = particle * d + axis
            np.add.at(out, index, value * np.asarray(v)[index])
        return out

    def _wall_diagonal(self) -> NDArray[np.float64]:
        """The walls' part of the diagonal ``(N d,)``."""
        particle, axis, value = self.walls
        d = self.sep.shape[1]
        return np.bincount(particle * d + axis, value, self.n * d).astype(np.float64)

    def contact_blocks(self, rows: NDArray[np.int64] | None = None) -> NDArray[np.float64]:
        """Each contact's block ``K = a b b^T - c I`` ``(M, d, d)``, or those of the contacts
        ``rows`` only."""
        if rows is None:
            rows = np.arange(self.pairs.shape[0])
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        out = np.empty((rows.size, self.sep.shape[1], self.sep.shape[1]))
        pair_blocks(self.sep, self.coef, rows, out)
        return out

    def lowest_block_eigenvalue(self) -> float:
        """The smallest eigenvalue of the ``d x d`` diagonal blocks of ``H`` (``>= 0`` when it
        has none): ``H`` is indefinite where it is negative (its value is then an upper bound on
        the smallest eigenvalue of ``H``)."""
        d = self.sep.shape[1]
        diagonal = np.empty((self.n, d, d))
        diagonal_blocks(self.pairs, self.sep, self.coef, diagonal)
        if self.walls[0].size:
            diagonal[:, range(d), range(d)] += self._wall_diagonal().reshape(self.n, d)
        return float(np.linalg.eigvalsh(diagonal)[:, 0].min()) if self.n else 0.0

    def matrix(self) -> sp.csr_matrix:
        """``H`` as a symmetric sparse matrix (for a factorization)."""
        blocks = self.contact_blocks()
        h = assemble_blocks(self.pairs[:, 0], self.pairs[:, 1], blocks, self.n)
        if self.walls[0].size:
            h = (h + sp.diags(self._wall_diagonal())).tocsr()
        return h
