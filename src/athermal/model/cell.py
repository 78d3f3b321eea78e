"""Simulation cell: an immutable lattice ``h`` (d x d, lattice vectors as columns), periodic
along every axis or bounded by flat walls along some.

The cell is upper triangular, as in HOOMD-blue: ``a1 = (Lx, 0, 0)``, ``a2 = (xy Ly, Ly, 0)``,
``a3 = (xz Lz, yz Lz, Lz)``. Fractional coordinates ``s = h^-1 x`` of wrapped positions lie in
``[-1/2, 1/2)`` (the cell is centred on the origin, HOOMD's convention). Lengths are in the
user's length unit (the paper's unit cell: ``Lx = Ly = 1``).

Walls: along an axis in :attr:`Cell.walls` the cell is not periodic; its two faces
``x_a = -L_a / 2`` and ``x_a = +L_a / 2`` are flat frictionless walls (``L_a = h[a, a]``, the
axis untilted: row and column ``a`` of ``h`` off the diagonal are zero), so that the cell's
volume is the space between them and the box a GSD file stores is the container.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from itertools import product

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._portable import row_dots, row_norms, transform, upper_inverse
from .._validate import float_array
from ..errors import InputError

_TRIANGLE_TOL = 1e-14
AXES = "xyz"
"""The axes' names, ``--walls`` letters: ``x`` is axis 0."""


def tilted_wall(m: NDArray[np.float64], walls: tuple[int, ...]) -> int | None:
    """The first walled axis ``a`` whose row or column of ``m`` ``(d, d)`` has an entry off the
    diagonal (a cell or a deformation that tilts the walls normal to ``a``), else None."""
    for a in walls:
        if np.any(np.delete(m[a], a) != 0.0) or np.any(np.delete(m[:, a], a) != 0.0):
            return a
    return None


def wall_axes(names: str, dim: int) -> tuple[int, ...]:
    """The axes ``(a, ...)`` of ``names`` (``"y"``, ``"xy"``; ``""`` for none) in ``dim``
    dimensions, sorted."""
    axes = sorted({AXES.find(c) for c in names})
    if -1 in axes or len(axes) != len(names) or (axes and axes[-1] >= dim):
        raise InputError(
            f"walls: expected distinct axes among {AXES[:dim]!r} (e.g. 'y'), got {names!r}"
        )
    return tuple(axes)


@dataclass(frozen=True, eq=False)
class Cell:
    """Cell with lattice matrix ``h`` of shape ``(d, d)``, d = 2 or 3, and walls normal to the
    axes ``walls`` (sorted; default none: periodic along every axis).

    Examples
    --------
    >>> cell = Cell.box([1.0, 1.0])
    >>> cell.deform(simple_shear(0.1)).h.tolist()
    [[1.0, 0.1], [0.0, 1.0]]
    """

    h: NDArray[np.float64]
    walls: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        h = np.array(float_array(self.h, "cell", (None, None)))
        d = h.shape[0]
        if h.shape != (d, d) or d not in (2, 3):
            raise InputError(f"cell: expected a 2x2 or 3x3 matrix, got shape {h.shape}")
        lower = np.tril(h, -1)
        if np.any(np.abs(lower) > _TRIANGLE_TOL * np.abs(h).max()):
            raise InputError("cell: must be upper triangular (lattice vectors as columns)")
        h[np.tril_indices(d, -1)] = 0.0
        if np.any(np.diag(h) <= 0.0):
            raise InputError(
                f"cell: singular or inverted, diagonal {np.diag(h).tolist()} must be > 0"
            )
        if not isinstance(self.walls, tuple | list) or not all(
            isinstance(a, int | np.integer) and not isinstance(a, bool) for a in self.walls
        ):
            raise InputError(f"walls: expected a tuple of axes (e.g. (1,)), got {self.walls!r}")
        walls = tuple(sorted({int(a) for a in self.walls}))
        if walls and (walls[0] < 0 or walls[-1] >= d):
            raise InputError(f"walls: axes must lie in 0..{d - 1}, got {list(self.walls)}")
        a = tilted_wall(h, walls)
        if a is not None:
            raise InputError(
                f"cell: walls normal to {AXES[a]} need an untilted {AXES[a]} axis (no shear "
                f"across or along them; frictionless flat walls cannot carry one)"
            )
        h.setflags(write=False)
        object.__setattr__(self, "h", h)
        object.__setattr__(self, "walls", walls)

    @classmethod
    def box(cls, lengths: ArrayLike) -> Cell:
        """Orthogonal cell with the given side lengths ``(d,)``."""
        sides = float_array(lengths, "lengths", (None,))
        return cls(np.diag(sides))

    @classmethod
    def unit(cls, dim: int, walls: str = "") -> Cell:
        """The unit square (cube) in ``dim`` dimensions with walls normal to the axes named in
        ``walls`` (:func:`wall_axes`)."""
        return cls(np.eye(dim), wall_axes(walls, dim))

    @classmethod
    def from_hoomd(cls, box: ArrayLike, dim: int) -> Cell:
        """Cell from a HOOMD box ``[Lx, Ly, Lz, xy, xz, yz]`` in ``dim`` dimensions."""
        lx, ly, lz, xy, xz, yz = float_array(box, "box", (6,))
        if dim == 2:
            return cls(np.array([[lx, xy * ly], [0.0, ly]]))
        if dim == 3:
            return cls(np.array([[lx, xy * ly, xz * lz], [0.0, ly, yz * lz], [0.0, 0.0, lz]]))
        raise InputError(f"dimensions: must be 2 or 3, got {dim}")

    def to_hoomd(self) -> NDArray[np.float64]:
        """HOOMD box ``[Lx, Ly, Lz, xy, xz, yz]`` (``Lz = 1``, ``xz = yz = 0`` in 2D)."""
        h = self.h
        if self.dim == 2:
            return np.array([h[0, 0], h[1, 1], 1.0, h[0, 1] / h[1, 1], 0.0, 0.0])
        return np.array(
            [h[0, 0], h[1, 1], h[2, 2], h[0, 1] / h[1, 1], h[0, 2] / h[2, 2], h[1, 2] / h[2, 2]]
        )

    @property
    def dim(self) -> int:
        """Number of dimensions d."""
        return int(self.h.shape[0])

    @property
    def volume(self) -> float:
        """Area (2D) or volume (3D) of the cell."""
        return float(np.prod(np.diag(self.h)))

    @property
    def periodic_axes(self) -> int:
        """Number of periodic axes (``d`` minus the walled ones): the rigid translations."""
        return self.dim - len(self.walls)

    @cached_property
    def inverse(self) -> NDArray[np.float64]:
        """``h^-1``, shape ``(d, d)``; its rows are the reciprocal vectors."""
        inv = upper_inverse(self.h)
        inv.setflags(write=False)
        return inv

    @cached_property
    def widths(self) -> NDArray[np.float64]:
        """Distances between opposite faces ``(d,)``: ``1 / |row k of h^-1|``."""
        w = 1.0 / row_norms(self.inverse)
        w.setflags(write=False)
        return w

    @cached_property
    def narrowest_width(self) -> float:
        """The lattice's narrowest width: the smallest of the :attr:`widths` of the
        :meth:`reduced` cell.

        Unlike :attr:`widths` (the faces of ``h`` as written), it is a property of the lattice,
        the same for each of its upper-triangular bases: ``[[1, 7], [0, 1]]`` gives 1, as the
        unit square does. Sizes that must fit in the periodic cell are checked against it.
        """
        return float(self.reduced().widths.min())

    def fractional(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Fractional coordinates ``h^-1 x`` of positions or vectors ``(N, d)``."""
        return transform(x, self.inverse)

    def cartesian(self, s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Cartesian coordinates ``h s`` of fractional ``(N, d)``."""
        return transform(s, self.h)

    def wrap(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Positions ``(N, d)`` mapped into the cell: fractional coordinates in ``[-1/2, 1/2)``
        along the periodic axes (kept along walled ones)."""
        s = self.fractional(x)
        jump = np.floor(s + 0.5)
        jump[:, list(self.walls)] = 0.0
        return self.cartesian(s - jump)

    def minimum_image(self, dx: NDArray[np.float64]) -> NDArray[np.float64]:
        """Shortest periodic image of separation vectors ``(M, d)``, exact in any cell (none
        across walls).

        Fractional rounding alone fails in tilted cells, so it is done in the reduced basis of
        the same lattice and the neighbouring images of the rounded vector are searched too.
        """
        dx = np.atleast_2d(np.asarray(dx, dtype=np.float64))
        cell = self.reduced()
        s = cell.fractional(dx)
        jump = np.round(s)
        jump[:, list(self.walls)] = 0.0
        base = cell.cartesian(s - jump)
        best = base.copy()
        best_len = row_dots(base, base)
        for shift in product((-1, 0, 1), repeat=self.dim):
            if not any(shift) or any(shift[a] for a in self.walls):
                continue
            trial = base + transform(np.array([shift], dtype=np.float64), cell.h)
            length = row_dots(trial, trial)
            closer = length < best_len
            best[closer] = trial[closer]
            best_len[closer] = length[closer]
        return best

    def deform(self, deformation: ArrayLike) -> Cell:
        """Cell ``D h`` after the affine deformation ``D`` ``(d, d)``; ``D h`` must stay upper
        triangular."""
        d_mat = float_array(deformation, "deformation", (self.dim, self.dim))
        if np.linalg.det(d_mat) <= 0.0:
            raise InputError("deformation: determinant must be > 0")
        return Cell(transform(self.h.T, d_mat).T, self.walls)

    def reduced(self) -> Cell:
        """The same lattice with every tilt at most half the box length it leans along.

        Simple shear accumulated past half a box (Lees-Edwards) is mapped back by adding integer
        multiples of lower lattice vectors to higher ones; the periodic system is unchanged.
        """
        h = np.array(self.h)
        for col in range(1, self.dim):
            for row in range(col - 1, -1, -1):
                n = np.round(h[row, col] / h[row, row])
                h[:, col] -= n * h[:, row]
        return Cell(h, self.walls)

    def packing_fraction(self, radii: NDArray[np.float64]) -> float:
        """Sum of disk areas (2D) or sphere volumes (3D) over the cell volume."""
        return float(particle_volumes(radii, self.dim).sum() / self.volume)


def particle_volumes(radii: NDArray[np.float64], dim: int) -> NDArray[np.float64]:
    """Area ``pi r^2`` (2D) or volume ``4/3 pi r^3`` (3D) of each particle ``(N,)``."""
    r = np.asarray(radii, dtype=np.float64)
    out: NDArray[np.float64] = np.pi * r * r if dim == 2 else (4.0 / 3.0) * np.pi * (r * r * r)
    return out


def isotropic(scale: float, dim: int = 2) -> NDArray[np.float64]:
    """Deformation ``scale * I``: isotropic compression for ``scale < 1``."""
    return float(scale) * np.eye(dim)


def simple_shear(gamma: float, dim: int = 2) -> NDArray[np.float64]:
    """Simple shear ``x += gamma y`` (Lees-Edwards): ``D = [[1, gamma], [0, 1]]`` (padded in 3D)."""
    d_mat = np.eye(dim)
    d_mat[0, 1] = gamma
    return d_mat


def pure_shear(gamma: float, dim: int = 2) -> NDArray[np.float64]:
    """Volume-preserving pure shear ``D = diag(1 + gamma, 1 / (1 + gamma))`` (``z`` kept in 3D)."""
    d_mat = np.eye(dim)
    d_mat[0, 0] = 1.0 + gamma
    d_mat[1, 1] = 1.0 / (1.0 + gamma)
    return d_mat


def pure_shear_derivatives(dim: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``D'(0)``, ``D''(0)`` ``(d, d)`` of pure shear ``D = diag(1 + g, 1 / (1 + g))`` (``z``
    kept in 3D): ``diag(1, -1)`` and ``diag(0, 2)``."""
    d1, d2 = np.zeros((dim, dim)), np.zeros((dim, dim))
    d1[0, 0], d1[1, 1], d2[1, 1] = 1.0, -1.0, 2.0
    return d1, d2
