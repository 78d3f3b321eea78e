"""The Hessian of a packing's contact network over its free coordinates, factored once: its
lowest nonzero eigenpair (the soft mode) and what the removal of one contact leaves of it.

The network is the contacts of the particles that are no rattlers; its free coordinates are
theirs, less those of particles held fixed (rough walls). Without held particles the
translations along the periodic axes are exact zero modes: the first particle is pinned along
them for the factor (:func:`~athermal.analysis.moduli.unpinned`), whose solves then apply the
pseudo-inverse ``H^+`` to vectors orthogonal to the translations.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from ..linalg import Factor, arpack_start, cholesky
from ..model.contact import Contacts, hessian_floor
from ..model.packing import Packing
from .moduli import lowest_eigenpairs, nonrattler_hessian, unit_translations, unpinned

DENSE_SOFT_MODE_DOFS = 400
"""Largest free Hessian whose soft mode is found by a dense ``eigh``; above it ARPACK on
``H^+`` (the factor's solves)."""


class NetworkHessian:
    """The Hessian ``h`` of ``contacts`` (the network of ``packing``'s particles that are
    neither ``rattler`` nor ``frozen``) over their free coordinates, the flat indices ``dofs``
    of its rows among the ``N d`` coordinates, its number of ``translations`` (zero modes along
    the periodic axes; none where particles are held), and its pinned Cholesky factor, built
    on first use."""

    def __init__(
        self,
        packing: Packing,
        contacts: Contacts,
        rattler: NDArray[np.bool_],
        frozen: NDArray[np.bool_] | None,
    ) -> None:
        dim = packing.dim
        h, dofs = nonrattler_hessian(contacts, rattler, dim)
        translations = packing.cell.periodic_axes
        if frozen is not None:  # the held particles pin the rest
            free = np.flatnonzero(~frozen[dofs // dim])
            h, dofs, translations = h[free][:, free].tocsr(), dofs[free], 0
        self.packing, self.contacts = packing, contacts
        self.h, self.dofs, self.translations = h, dofs, translations
        self.rows = np.arange(dofs.size)
        """The rows of ``h`` left when the first particle is pinned along the periodic axes
        (``dofs`` lists the first particle's coordinates first)."""
        if translations:
            self.rows = unpinned(dofs.size, dim, packing.cell.walls)

    @cached_property
    def factor(self) -> Factor | None:
        """The Cholesky factor of ``h`` with the first particle pinned, or None where that is
        not positive definite."""
        return cholesky(self.h[self.rows][:, self.rows].tocsr())

    def soft_mode(self) -> tuple[float, NDArray[np.float64]]:
        """The lowest nonzero eigenvalue of ``h`` (the translations skipped) and its unit mode
        ``(N, d)`` (zero on rattlers and held particles, the sign fixed by its largest
        component); infinity and a zero mode where nothing is stiff (no network). A dense
        ``eigh`` up to :data:`DENSE_SOFT_MODE_DOFS` rows; above, ARPACK on ``H^+`` (the
        eigenvalue ``1 / mu`` of its largest ``mu``), or in shift-invert mode
        (:func:`~athermal.analysis.moduli.lowest_eigenpairs`) where the factor failed."""
        n, dim = self.packing.n, self.packing.dim
        if self.dofs.size <= self.translations:
            return float("inf"), np.zeros((n, dim))
        if self.dofs.size > DENSE_SOFT_MODE_DOFS and self.factor is not None:
            value, vector = self._lowest_by_inverse()
        else:
            value, vector = self._lowest_whole()
        mode = np.zeros((n, dim))
        mode.reshape(-1)[self.dofs] = vector
        mode /= np.linalg.norm(mode)
        flat = mode.reshape(-1)
        if flat[np.argmax(np.abs(flat))] < 0.0:
            mode = -mode
        return value, mode

    def removal(self, which: int) -> float:
        """``k b^T H^-1 b`` for the contact ``which`` of the network (pairs, then wall
        contacts): ``b`` the gradient of its overlap (orthogonal to the translations), ``k`` the
        law's stiffness at zero overlap. At zero force the contact's term of ``H`` is
        ``k b b^T``, and ``H - k b b^T`` is positive definite if and only if this is below 1
        (``H`` positive definite); infinity where ``H`` is not."""
        if self.factor is None:
            return float("inf")
        contacts, dim = self.contacts, self.packing.dim
        b = np.zeros(self.packing.n * dim)
        pairs = contacts.i.size
        if which < pairs:
            normal = contacts.normal[which]
            b[contacts.i[which] * dim + np.arange(dim)] += normal
            b[contacts.j[which] * dim + np.arange(dim)] -= normal
            k = contacts.stiffness[which]
        else:
            assert contacts.walls is not None
            wall = which - pairs
            b[contacts.walls.particle[wall] * dim + contacts.walls.axis[wall]] = 1.0
            k = contacts.walls.stiffness[wall]
        column = b[self.dofs][self.rows]
        y = self.factor.solve(column[:, None])[:, 0]
        stiffness = float(contacts.law.stiffness(np.zeros(1), k)[0])
        return stiffness * float(np.sum(column * y))

    def _lowest_whole(self) -> tuple[float, NDArray[np.float64]]:
        """The lowest eigenpair of ``h`` that is no translation: dense, or shift-invert ARPACK
        on ``h`` itself."""
        k = self.translations + 1
        if self.dofs.size <= DENSE_SOFT_MODE_DOFS or k >= self.dofs.size - 1:
            values, vectors = np.linalg.eigh(self.h.toarray())
            values, vectors = values[:k], vectors[:, :k]
        else:
            floor = hessian_floor(self.contacts, self.packing.n)  # here the factor failed:
            values, vectors = lowest_eigenpairs(self.h, k, floor, saddle=True)  # not definite
        if self.translations:
            overlap = np.linalg.norm(
                unit_translations(self.dofs, self.packing.dim, self.packing.cell.walls).T @ vectors,
                axis=0,
            )
            keep = np.flatnonzero(overlap < 0.5)
            values, vectors = values[keep], vectors[:, keep]
        return float(values[0]), vectors[:, 0]

    def _lowest_by_inverse(self) -> tuple[float, NDArray[np.float64]]:
        """The lowest nonzero eigenpair of ``h`` from the largest of ``H^+`` (ARPACK from a
        fixed start): the solve with the pinned factor of a vector without translation,
        projected onto the vectors without translation."""
        factor, rows, size = self.factor, self.rows, self.dofs.size
        assert factor is not None
        along = (
            unit_translations(self.dofs, self.packing.dim, self.packing.cell.walls)
            if self.translations
            else np.zeros((size, 0))
        )

        def project(u: NDArray[np.float64]) -> NDArray[np.float64]:
            return u - along @ (along.T @ u)

        def inverse(u: NDArray[np.float64]) -> NDArray[np.float64]:
            out = np.zeros(size)
            out[rows] = factor.solve(project(np.ravel(u))[rows][:, None])[:, 0]
            return project(out)

        operator = spla.LinearOperator((size, size), matvec=inverse, dtype=np.float64)
        values, vectors = spla.eigsh(
            operator, k=1, which="LA", tol=1e-12, v0=project(arpack_start(size))
        )
        return 1.0 / float(values[0]), vectors[:, 0]
