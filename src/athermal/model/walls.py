"""Contacts of particles with the flat frictionless walls of a cell (:attr:`Cell.walls
<athermal.model.cell.Cell.walls>`): their forces, Hessian terms, stress and the force per unit area
on each wall.

Along a walled axis ``a`` the walls lie at ``x_a = -L_a / 2`` (the lower one) and
``+L_a / 2`` (the upper one). A particle of radius ``r`` whose centre is ``l`` from a wall
overlaps it by ``delta = r - l`` and stores the particles' contact law's ``E(delta)`` (wall
stiffness :attr:`ContactModel.kwall <athermal.model.contact.ContactModel.kwall>`; the
compiled kernel is :func:`athermal.model.loops.wall_energy_gradient`); the force
on it, ``f(delta)``, is along the wall's normal into the cell. In the stress
``sigma = (1/V) sum_c l_c (x) f_c`` a wall contact's branch ``l_c`` runs from the contact point
on the wall to the centre (``l n``): then at mechanical equilibrium ``sigma_aa`` equals the
force per unit area on the walls normal to ``a`` (:func:`wall_pressures`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .._portable import outer_sum
from .cell import AXES, Cell
from .law import ContactLaw, LawContacts


@dataclass(frozen=True, eq=False)
class WallContacts(LawContacts):
    """The overlaps of particles with walls, W of them.

    ``particle``, ``axis`` ``(W,)`` int64; ``side`` ``(W,)`` +1 for the lower wall of its axis
    (normal ``+e_a`` into the cell), -1 for the upper one; ``distance`` ``(W,)`` from the wall
    to the centre, ``overlap`` ``(W,)`` = ``r - distance`` > 0, ``stiffness`` ``(W,)`` ``k_w``;
    the contact ``law``; ``dim``.
    """

    particle: NDArray[np.int64]
    axis: NDArray[np.int64]
    side: NDArray[np.float64]
    distance: NDArray[np.float64]
    overlap: NDArray[np.float64]
    stiffness: NDArray[np.float64]
    law: ContactLaw
    dim: int

    def subset(self, keep: NDArray[np.bool_]) -> WallContacts:
        """The wall contacts where ``keep`` ``(W,)`` is True."""
        return WallContacts(
            self.particle[keep],
            self.axis[keep],
            self.side[keep],
            self.distance[keep],
            self.overlap[keep],
            self.stiffness[keep],
            self.law,
            self.dim,
        )

    @property
    def normal(self) -> NDArray[np.float64]:
        """The walls' unit normals into the cell ``(W, d)``."""
        n = np.zeros((self.particle.size, self.dim))
        n[np.arange(self.particle.size), self.axis] = self.side
        return n

    @property
    def branch(self) -> NDArray[np.float64]:
        """From the contact point on the wall to the centre, ``distance x normal`` ``(W, d)``."""
        return self.distance[:, None] * self.normal

    def overlaps_in(
        self, positions: NDArray[np.float64], radii: NDArray[np.float64], cell: Cell
    ) -> NDArray[np.float64]:
        """The overlaps ``(W,)`` of these particles with these walls at ``positions`` in
        ``cell`` (negative where a particle has left its wall)."""
        half = 0.5 * cell.h[self.axis, self.axis]
        return radii[self.particle] - _wall_distance(
            positions[self.particle, self.axis], half, self.side
        )

    def hessian_terms(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
        """Each contact's one Hessian entry: particle, axis and ``E''(delta)`` at
        ``(particle d + axis)`` on the diagonal (a flat wall: no other)."""
        return self.particle, self.axis, self.normal_stiffness


def _wall_distance(
    coordinate: NDArray[np.float64],
    half: NDArray[np.float64] | float,
    side: NDArray[np.float64] | float,
) -> NDArray[np.float64]:
    """The distances from centres at ``coordinate`` along a wall's axis to the lower
    (``side`` +1) or upper (-1) wall of a cell ``2 half`` wide along it."""
    return half + side * coordinate


def find_wall_contacts(
    positions: NDArray[np.float64],
    radii: NDArray[np.float64],
    stiffness: NDArray[np.float64],
    law: ContactLaw,
    cell: Cell,
) -> WallContacts:
    """The wall contacts of particles at ``positions`` ``(N, d)`` with ``radii`` and wall
    stiffnesses ``stiffness`` ``(N,)`` in ``cell`` (none in a periodic one)."""
    particles, axes, sides, distances = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [], []
    for a in cell.walls:
        half = 0.5 * cell.h[a, a]
        for side in (1.0, -1.0):
            distance = _wall_distance(positions[:, a], half, side)
            hit = np.flatnonzero(distance < radii)
            particles.append(hit)
            axes.append(np.full(hit.size, a))
            sides.append(np.full(hit.size, side))
            distances.append(distance[hit])
    particle = np.concatenate(particles).astype(np.int64)
    distance = np.concatenate([np.zeros(0), *distances])
    return WallContacts(
        particle,
        np.concatenate(axes).astype(np.int64),
        np.concatenate([np.zeros(0), *sides]),
        distance,
        radii[particle] - distance,
        stiffness[particle],
        law,
        cell.dim,
    )


def wall_gradient(walls: WallContacts, n: int) -> NDArray[np.float64]:
    """The walls' part of ``dE/dx`` ``(N, d)``."""
    grad = np.zeros((n, walls.dim))
    np.add.at(grad, walls.particle, -walls.force)
    return grad


def wall_hessian(walls: WallContacts, n: int) -> sp.csr_matrix:
    """The walls' part of the Hessian ``(N d, N d)``: diagonal."""
    particle, axis, coef = walls.hessian_terms()
    diagonal = np.bincount(particle * walls.dim + axis, coef, n * walls.dim)
    return sp.diags(diagonal, format="csr")


def wall_stress(walls: WallContacts, cell: Cell) -> NDArray[np.float64]:
    """The wall contacts' part of the stress, ``(1/V) sum_c l_c (x) f_c`` ``(d, d)``."""
    return outer_sum(walls.branch, walls.force) / cell.volume


def wall_pressures(walls: WallContacts, cell: Cell) -> dict[str, float]:
    """The force per unit area (per unit length in 2D) the particles exert on each wall, by
    name: ``"y-"`` the lower wall normal to ``y``, ``"y+"`` the upper one."""
    out = {}
    for a in cell.walls:
        area = cell.volume / cell.h[a, a]
        for side, sign in (("-", 1.0), ("+", -1.0)):
            on = (walls.axis == a) & (walls.side == sign)
            out[AXES[a] + side] = float(walls.force_magnitude[on].sum() / area)
    return out


def wall_layers(
    positions: NDArray[np.float64], cell: Cell, axis: int, layer: float
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The particles whose centres ``(N, d)`` lie within ``layer`` of the lower and of the upper
    wall normal to ``axis``: masks ``(N,)`` each, the rough walls of plane shear (particles
    glued to a wall and moved with it)."""
    half = 0.5 * cell.h[axis, axis]
    return positions[:, axis] < layer - half, positions[:, axis] > half - layer
