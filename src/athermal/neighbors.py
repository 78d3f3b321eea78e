"""Verlet pair lists in any periodic cell: an O(N) cell-list build and a brute-force twin.

A :class:`NeighborList` holds every pair ``(i, j)`` closer than ``r_i + r_j + skin`` once, as
flat arrays in spatial (bin) order with ``j >= i`` (``j == i`` only for a particle's own image
in a cell narrower than the cut-off), each with an image code. The separation of a pair is
``x_i - x_j + shift[code]`` where ``shift = images @ h.T`` are lattice translations, so the list
stays exact for unwrapped positions, any tilt and deformation of the cell (shifts follow ``h``).
It stays complete while no particle has moved more than ``skin / 2`` since the build.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np
from numpy.typing import NDArray

from . import _kernels
from .cell import Cell
from .errors import InputError

DEFAULT_SKIN_FACTOR = 0.2
_MAX_IMAGE_CODES = np.iinfo(np.int16).max


def default_skin(radii: NDArray[np.float64]) -> float:
    """Verlet skin used when none is given: 0.2 times the mean radius (length units)."""
    return DEFAULT_SKIN_FACTOR * float(np.mean(radii))


@dataclass(frozen=True, eq=False)
class NeighborList:
    """Pairs within ``r_i + r_j + skin`` (half list with lattice image codes).

    Attributes
    ----------
    first : ``(P,)`` int32, the ``i`` of each pair.
    second : ``(P,)`` int32, the ``j`` of each pair (``j >= i``).
    code : ``(P,)`` int16, index into ``images``.
    images : ``(C, d)`` float64, integer lattice vectors ``n``; shift = ``h n``.
    skin : Verlet skin (length units).
    reference : ``(N, d)`` positions at the build.
    """

    first: NDArray[np.int32]
    second: NDArray[np.int32]
    code: NDArray[np.int16]
    images: NDArray[np.float64]
    skin: float
    reference: NDArray[np.float64]

    @property
    def n_pairs(self) -> int:
        """Number of listed pairs P."""
        return int(self.second.size)

    def shifts(self, cell: Cell) -> NDArray[np.float64]:
        """Lattice translations ``(C, d)`` of the image codes in ``cell``."""
        return np.ascontiguousarray(self.images @ cell.h.T)

    def separations(self, positions: NDArray[np.float64], cell: Cell) -> NDArray[np.float64]:
        """Separation vectors ``x_i - x_j + shift`` ``(P, d)`` of all listed pairs."""
        x = np.asarray(positions)
        # np.take gathers rows ~8x faster than fancy indexing here
        return (
            np.take(x, self.first, axis=0)
            - np.take(x, self.second, axis=0)
            + np.take(self.shifts(cell), self.code, axis=0)
        )

    @property
    def reach_sq(self) -> float:
        """Squared displacement from :attr:`reference` up to which the list holds,
        ``(skin / 2)^2``."""
        return 0.25 * self.skin * self.skin

    def is_current(self, positions: NDArray[np.float64]) -> bool:
        """True while no particle has moved more than ``skin / 2`` since the build."""
        moved = _kernels.max_displacement_sq(
            np.ascontiguousarray(positions, dtype=np.float64), self.reference
        )
        return bool(moved <= self.reach_sq)


def _bin_layout(cell: Cell, cutoff: float, n: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    widths = cell.widths
    nbins = np.maximum(1, np.floor(widths / cutoff)).astype(np.int64)
    while np.prod(nbins) > 4 * n + 64:
        nbins = np.maximum(1, nbins // 2)
    reach = np.floor(cutoff * nbins / widths).astype(np.int64) + 1
    return nbins, reach


def _half_stencil(dim: int) -> NDArray[np.int64]:
    """Bin offsets ``(S, 3)``: zero first, then one of each pair ``+-o`` (5 in 2D, 14 in 3D)."""
    half = [o for o in product((-1, 0, 1), repeat=dim) if any(o) and o > tuple(-v for v in o)]
    offsets = np.zeros((len(half) + 1, 3), dtype=np.int64)
    offsets[1:, :dim] = half
    return offsets


def _half_stencil_search(
    x: NDArray[np.float64],
    r: NDArray[np.float64],
    cell: Cell,
    skin: float,
    nbins: NDArray[np.int64],
) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.int16], NDArray[np.float64]]:
    """Pairs by :func:`_kernels.collect_pairs` (2D embedded in 3D with ``z = 0`` and one bin)."""
    d, n = cell.dim, r.size
    x3 = np.zeros((n, 3))
    x3[:, :d] = x
    h3, hinv3 = np.eye(3), np.eye(3)
    h3[:d, :d], hinv3[:d, :d] = cell.h, cell.inverse
    nb3 = np.ones(3, dtype=np.int64)
    nb3[:d] = nbins
    bin_start, member, xs, rs, fs = _kernels.bin_particles(x3, h3, hinv3, nb3, r)
    m = int(np.ptp(fs, axis=0).max()) + 1 if n else 1  # bound on |image| components
    side = 2 * m + 1
    if side**d > _MAX_IMAGE_CODES:
        raise InputError("positions: particles lie too many cells outside the box; wrap them first")
    weights = np.zeros(3, dtype=np.int64)
    weights[:d] = side ** np.arange(d)
    offsets = _half_stencil(d)
    capacity = (4 if d == 2 else 7) * n + 16
    first = np.empty(capacity, dtype=np.int32)
    second = np.empty(capacity, dtype=np.int32)
    code = np.empty(capacity, dtype=np.int16)
    count, done = 0, 0
    total = int(np.prod(nb3))
    while True:
        count, done = _kernels.collect_pairs(
            bin_start,
            member,
            xs,
            rs,
            fs,
            h3,
            nb3,
            offsets,
            skin,
            weights,
            m,
            first,
            second,
            code,
            done,
            count,
        )
        if done == total:
            break
        first, second, code = (np.concatenate([a, np.empty_like(a)]) for a in (first, second, code))
    return first[:count], second[:count], code[:count], _image_table(m, d)


def _image_table(m: int, dim: int) -> NDArray[np.float64]:
    """Integer lattice vectors ``(C, d)``, row ``c`` = image with code ``sum (n_a + m) side^a``."""
    table = np.array(list(product(range(-m, m + 1), repeat=dim)), dtype=np.float64)[:, ::-1]
    return np.ascontiguousarray(table)


def _encode_images(
    image: NDArray[np.int32], dim: int
) -> tuple[NDArray[np.int16], NDArray[np.float64]]:
    m = int(np.abs(image).max()) if image.size else 0
    side = 2 * m + 1
    if side**dim > _MAX_IMAGE_CODES:
        raise InputError("positions: particles lie too many cells outside the box; wrap them first")
    weights = side ** np.arange(dim)
    code = ((image + m) @ weights).astype(np.int16)
    return code, _image_table(m, dim)


def build_neighbor_list(
    positions: NDArray[np.float64],
    radii: NDArray[np.float64],
    cell: Cell,
    skin: float | None = None,
) -> NeighborList:
    """Cell-list build of all pairs with ``|x_i - x_j + h n| < r_i + r_j + skin``, O(N).

    Parameters
    ----------
    positions : ``(N, d)`` float64, wrapped or not.
    radii : ``(N,)`` float64.
    cell : the periodic cell (any tilt).
    skin : Verlet skin in length units; default :func:`default_skin`.
    """
    x = np.ascontiguousarray(positions, dtype=np.float64)
    r = np.ascontiguousarray(radii, dtype=np.float64)
    skin = default_skin(r) if skin is None else float(skin)
    if not skin >= 0.0:
        raise InputError(f"skin: must be >= 0, got {skin}")
    cutoff = 2.0 * float(r.max()) + skin
    nbins, reach = _bin_layout(cell, cutoff, r.size)
    if np.all(nbins >= 3) and np.all(reach == 1):
        first, second, code, table = _half_stencil_search(x, r, cell, skin, nbins)
    else:  # cells narrower than three cut-offs: search every image
        h, hinv = np.ascontiguousarray(cell.h), np.ascontiguousarray(cell.inverse)
        first, second, image = _kernels.cell_list_pairs(x, r, h, hinv, skin, nbins, reach)
        code, table = _encode_images(image, cell.dim)
    return NeighborList(first, second, code, table, skin, x.copy())


def brute_force_pairs(
    positions: NDArray[np.float64], radii: NDArray[np.float64], cell: Cell, skin: float
) -> set[tuple[int, int, tuple[int, ...]]]:
    """Every pair ``(i, j, n)`` with ``i <= j`` and ``|x_i - x_j + h n| < r_i + r_j + skin``.

    O(N^2 x images), for testing :func:`build_neighbor_list`; a particle's own images count
    once (``n`` with its last non-zero component positive).
    """
    x = np.asarray(positions, dtype=np.float64)
    r = np.asarray(radii, dtype=np.float64)
    reach = np.ceil((2 * r.max() + skin) / cell.widths).astype(int) + 1
    fl = np.floor(cell.fractional(x))
    found: set[tuple[int, int, tuple[int, ...]]] = set()
    ranges = [range(-int(k), int(k) + 1) for k in reach]
    for n_rel in product(*ranges):
        rel = np.array(n_rel, dtype=np.float64)
        for i in range(r.size):
            # images relative to the wrapped copies, made absolute below
            n_abs = fl - fl[i] + rel
            sep = x[i] - x + n_abs @ cell.h.T
            dist = np.sqrt(np.einsum("ij,ij->i", sep, sep))
            close = np.nonzero(dist < r[i] + r + skin)[0]
            for j in close:
                n = tuple(int(v) for v in n_abs[j])
                if j < i or (j == i and not _positive(n)):
                    continue
                found.add((i, int(j), n))
    return found


def _positive(n: tuple[int, ...]) -> bool:
    for v in reversed(n):
        if v:
            return v > 0
    return False


def pair_set(nlist: NeighborList) -> set[tuple[int, int, tuple[int, ...]]]:
    """The listed pairs as ``(i, j, n)`` tuples, for comparison with :func:`brute_force_pairs`."""
    img = nlist.images[nlist.code].astype(int)
    return {
        (int(i), int(j), tuple(int(v) for v in n))
        for i, j, n in zip(nlist.first, nlist.second, img, strict=True)
    }
