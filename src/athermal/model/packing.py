"""Frozen packing state (positions, radii, cell) and the constructors of random packings."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._portable import root, transform
from .._validate import choice, float_array, positive_scalar
from ..errors import InputError
from .cell import AXES, Cell, particle_volumes

_MAX_RADIUS_TYPES = 16

SizeDistribution = Literal["bidisperse", "uniform", "lognormal"]
"""The particle size distributions of :func:`random_packing`."""
SIZE_DISTRIBUTIONS: tuple[str, ...] = get_args(SizeDistribution)
POLYDISPERSITY = 0.2
"""Default width of the continuous distributions: standard deviation / mean of the radii."""
MAX_WIDTH = {"uniform": 1.0 / np.sqrt(3.0), "lognormal": 1.0}
"""Largest width of each continuous distribution (uniform: the smallest radius reaches 0)."""


@dataclass(frozen=True, eq=False)
class Packing:
    """Positions ``(N, d)`` float64, radii ``(N,)`` > 0 and a :class:`Cell` (periodic, or with
    walls: every centre between them).

    Positions are kept as given (not wrapped); :meth:`wrapped` maps them into the cell.
    """

    positions: NDArray[np.float64]
    radii: NDArray[np.float64]
    cell: Cell

    def __post_init__(self) -> None:
        if not isinstance(self.cell, Cell):
            object.__setattr__(self, "cell", Cell(np.asarray(self.cell)))
        d = self.cell.dim
        x = float_array(self.positions, "positions", (None, d))
        r = float_array(self.radii, "radii", (x.shape[0],))
        if x.shape[0] == 0:
            raise InputError("positions: a packing needs at least one particle")
        if np.any(r <= 0.0):
            raise InputError(f"radii: must be > 0 (found {int(np.sum(r <= 0.0))} that are not)")
        for a in self.cell.walls:
            if 2.0 * r.max() >= self.cell.h[a, a]:
                raise InputError(
                    f"walls: the gap between the walls normal to {AXES[a]} "
                    f"({self.cell.h[a, a]:.6g}) leaves no room for the largest particle "
                    f"(diameter {2 * r.max():.6g})"
                )
        if 2.0 * r.max() >= self.cell.narrowest_width:
            raise InputError(
                f"radii: largest diameter {2 * r.max():.6g} does not fit in the cell "
                f"(narrowest width {self.cell.narrowest_width:.6g})"
            )
        for a in self.cell.walls:
            beyond = np.flatnonzero(np.abs(x[:, a]) > 0.5 * self.cell.h[a, a])
            if beyond.size:
                raise InputError(
                    f"positions: particle {beyond[0]} lies beyond the walls normal to "
                    f"{AXES[a]} ({beyond.size} in all): the walls are at "
                    f"{AXES[a]} = -+{0.5 * self.cell.h[a, a]:.6g}"
                )
        object.__setattr__(self, "positions", x)
        object.__setattr__(self, "radii", r)

    @property
    def n(self) -> int:
        """Number of particles N."""
        return int(self.radii.shape[0])

    @property
    def dim(self) -> int:
        """Number of dimensions d."""
        return self.cell.dim

    @property
    def phi(self) -> float:
        """Packing fraction: particle areas (2D) or volumes (3D) over the cell volume."""
        return self.cell.packing_fraction(self.radii)

    def types(self) -> tuple[NDArray[np.int32], list[str]]:
        """Species ``typeid`` ``(N,)`` (0 = smallest radius) and their names.

        Distinct radii (up to 16) are one type each (``A``, ``B``, ...: bidisperse gives 0 =
        small, 1 = large); a broader polydisperse set is split into 16 bins of equal width.
        """
        values = np.unique(self.radii)
        if values.size <= _MAX_RADIUS_TYPES:
            typeid = np.searchsorted(values, self.radii).astype(np.int32)
            count = values.size
        else:
            edges = np.linspace(values[0], values[-1], _MAX_RADIUS_TYPES + 1)
            typeid = np.clip(
                np.searchsorted(edges, self.radii, side="right") - 1, 0, _MAX_RADIUS_TYPES - 1
            ).astype(np.int32)
            count = _MAX_RADIUS_TYPES
        return typeid, [chr(ord("A") + t) for t in range(count)]

    def with_positions(self, positions: ArrayLike) -> Packing:
        """Same radii and cell, new positions ``(N, d)``."""
        return Packing(np.asarray(positions), self.radii, self.cell)

    def wrapped(self) -> Packing:
        """Positions mapped into the cell (fractional coordinates in ``[-1/2, 1/2)``)."""
        return self.with_positions(self.cell.wrap(self.positions))

    def deform(self, deformation: ArrayLike) -> Packing:
        """Affine deformation ``x -> D x`` of positions and cell (radii kept)."""
        new_cell = self.cell.deform(deformation)
        d_mat = np.asarray(deformation, dtype=np.float64)
        return Packing(transform(self.positions, d_mat), self.radii, new_cell)

    def scale_radii(self, factor: float) -> Packing:
        """Radii multiplied by ``factor``; positions and cell kept."""
        return Packing(self.positions, self.radii * positive_scalar(factor, "factor"), self.cell)

    def radii_at(self, phi: float) -> NDArray[np.float64]:
        """The radii ``(N,)`` scaled uniformly to packing fraction ``phi``:
        ``r (phi / self.phi)^(1/d)`` (the protocols grow every step from one packing's radii,
        so that their radii do not drift by round-off)."""
        return self.radii * root(_check_phi(phi) / self.phi, self.dim)

    def at_phi(self, phi: float) -> Packing:
        """Radii scaled uniformly so that the packing fraction becomes ``phi``."""
        return Packing(self.positions, self.radii_at(phi), self.cell)

    def permuted(self, order: NDArray[np.intp]) -> Packing:
        """Reordered: particle ``k`` of the result is particle ``order[k]`` of this one."""
        return Packing(self.positions[order], self.radii[order], self.cell)

    def spatial_order(self) -> NDArray[np.intp]:
        """Permutation listing particles along a Z-order (Morton) curve through the cell.

        Neighbours in space become neighbours in memory, which speeds up the pair kernels.
        """
        bits = 16 if self.dim == 2 else 10
        s = self.cell.fractional(self.positions)
        s = s - np.floor(s)
        grid = np.minimum((s * (1 << bits)).astype(np.uint64), (1 << bits) - 1)
        key = np.zeros(self.n, dtype=np.uint64)
        for bit in range(bits):
            for axis in range(self.dim):
                plane = (grid[:, axis] >> np.uint64(bit)) & np.uint64(1)
                key |= plane << np.uint64(bit * self.dim + axis)
        return np.argsort(key, kind="stable")


def _check_phi(phi: float) -> float:
    value = float(phi)
    if not np.isfinite(value) or not 0.0 < value < 1.0:
        raise InputError(f"phi: packing fraction must lie in (0, 1), got {phi!r}")
    return value


def bidisperse_radii(
    n: int, *, size_ratio: float = 1.4, large_fraction: float = 0.5
) -> NDArray[np.float64]:
    """Radii ``(N,)`` of a bidisperse mixture: small radius 1, large ``size_ratio``.

    ``round(large_fraction * N)`` particles are large (number ratio 1:1 by default); small ones
    come first.
    """
    if int(n) < 1:
        raise InputError(f"n: need at least one particle, got {n}")
    ratio = positive_scalar(size_ratio, "size_ratio")
    if not 0.0 <= large_fraction <= 1.0:
        raise InputError(f"large_fraction: must lie in [0, 1], got {large_fraction}")
    n_large = round(large_fraction * n)
    return np.concatenate([np.ones(n - n_large), np.full(n_large, ratio)])


def polydisperse_radii(
    n: int, distribution: SizeDistribution, width: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """``n`` radii ``(N,)`` drawn from a continuous distribution of mean 1 and standard deviation
    ``width`` (the polydispersity: sd / mean of the radii).

    ``"uniform"``: flat on ``[1 - sqrt(3) w, 1 + sqrt(3) w]`` (``0 < w < 1/sqrt(3)``);
    ``"lognormal"``: ``exp(s Z - s^2 / 2)`` with ``Z`` standard normal and
    ``s^2 = ln(1 + w^2)`` (``0 < w <= 1``).
    """
    check_width(distribution, width)
    if distribution == "uniform":
        return 1.0 + np.sqrt(3.0) * width * (2.0 * rng.random(n) - 1.0)
    s = np.sqrt(np.log1p(width**2))
    return np.exp(s * rng.standard_normal(n) - s**2 / 2.0)


def check_width(distribution: str, width: float) -> float:
    """``width`` if it is a valid polydispersity for the continuous ``distribution``."""
    choice(distribution, "sizes", SIZE_DISTRIBUTIONS[1:])
    w = float(width)
    top = MAX_WIDTH[distribution]
    if not (np.isfinite(w) and 0.0 < w and (w <= top if distribution == "lognormal" else w < top)):
        bound = "<= 1" if distribution == "lognormal" else f"< 1/sqrt(3) = {top:.4f}"
        raise InputError(
            f"polydispersity: a {distribution} width must be > 0 and {bound}, got {width!r}"
        )
    return w


def random_packing(
    n: int = 1024,
    phi: float = 0.8,
    *,
    dim: int = 2,
    seed: int | np.random.SeedSequence = 0,
    size_ratio: float = 1.4,
    large_fraction: float = 0.5,
    sizes: SizeDistribution = "bidisperse",
    polydispersity: float = POLYDISPERSITY,
    radii: ArrayLike | None = None,
    cell: Cell | None = None,
) -> Packing:
    """Particles at uniformly random positions in ``cell``, radii scaled to fraction ``phi``.

    Parameters
    ----------
    n : number of particles (ignored when ``radii`` is given).
    phi : target packing fraction in (0, 1).
    dim : 2 (disks) or 3 (spheres); ignored when ``cell`` is given.
    seed : seed of the ``numpy.random.Generator`` that draws the positions.
    size_ratio, large_fraction : bidisperse mixture (default 1:1 by number, 1.4:1 in size).
    sizes : ``"bidisperse"`` (default), or a continuous distribution of the radii,
        ``"uniform"`` or ``"lognormal"`` (:func:`polydisperse_radii`), drawn by the same
        generator after the positions (so a seed places the particles alike in every case).
    polydispersity : standard deviation / mean of the radii of a continuous distribution.
    radii : relative radii ``(N,)`` of a polydisperse packing; only their ratios matter
        (overrides ``sizes``).
    cell : the cell, periodic or with walls (centres drawn between them); default the unit
        square (cube).

    Returns
    -------
    Packing sorted along a space-filling curve, positions wrapped into the cell.

    Examples
    --------
    >>> p = random_packing(256, 0.84, seed=1)
    >>> round(p.phi, 12)
    0.84
    """
    target = _check_phi(phi)
    if cell is None:
        if dim not in (2, 3):
            raise InputError(f"dim: must be 2 or 3, got {dim}")
        cell = Cell.box(np.ones(dim))
    choice(sizes, "sizes", SIZE_DISTRIBUTIONS)
    if radii is not None:
        base = np.array(float_array(radii, "radii", (None,)))
        if base.size == 0 or np.any(base <= 0.0):
            raise InputError("radii: need at least one radius, all > 0")
    elif sizes == "bidisperse":
        base = bidisperse_radii(n, size_ratio=size_ratio, large_fraction=large_fraction)
    else:
        if int(n) < 1:
            raise InputError(f"n: need at least one particle, got {n}")
        check_width(sizes, polydispersity)
        base = np.ones(int(n))
    rng = np.random.default_rng(seed)
    s = rng.random((base.size, cell.dim)) - 0.5
    if radii is None and sizes != "bidisperse":
        base = polydisperse_radii(base.size, sizes, polydispersity, rng)
    scale = root(target * cell.volume / particle_volumes(base, cell.dim).sum(), cell.dim)
    packing = Packing(cell.cartesian(s), base * scale, cell)
    return packing.permuted(packing.spatial_order())
