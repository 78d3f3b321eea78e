"""Verlet pair lists in any periodic cell (none across a cell's walls): an O(N) cell-list build
and a brute-force twin.

A :class:`NeighborList` holds every pair ``(i, j)`` closer than ``r_i + r_j + skin`` once, as
flat arrays in spatial (bin) order with ``j >= i`` (``j == i`` only for a particle's own image
in a cell narrower than the cut-off), each with an image code. The separation of a pair is
``x_i - x_j + shift[code]`` where ``shift = images @ h.T`` are lattice translations, so the list
stays exact for unwrapped positions, any tilt and deformation of the cell (shifts follow ``h``).
It stays complete while no particle has moved more than ``skin / 2`` since the build.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import product
from typing import Any

import numba
import numpy as np
from numba import prange
from numpy.typing import NDArray

from .. import _blocks
from .._jit import _jit, _jit_parallel, threads_usable
from .._portable import transform
from ..errors import InputError
from .cell import Cell

SLABS = 32
"""Slabs of a neighbour list at most (:attr:`NeighborList.slabs`): 16 of each parity for 16
threads, each long enough that few of its rows border another (``docs/decisions.md``, "The
kernels on many cores")."""
PARALLEL_BUILD = 50_000
"""Particles from which the cell-list build runs on the threads (:func:`bin_particles_threads`,
:func:`collect_chunks`; measured in ``docs/decisions.md``, "The kernels on many cores")."""
PAIRS_PER_PARTICLE = {2: 4.0, 3: 7.0}
"""Pairs per particle a search first makes room for (a bound on the usual count at the default
skin); a search that needs more grows its buffers and goes on."""
CHUNKS_PER_THREAD = 4
"""Chunks of rows of bins per thread in the threaded search (uneven chunks balance out)."""
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
    slabs : ``(S + 1,)`` int64 offsets into the pairs of ``S`` slabs (S even, >= 4), or empty:
        slab ``s`` holds the pairs whose ``first`` was binned in ``s``'s rows of bins along the
        last binned axis, at least two rows each; its pairs touch particles of those rows and
        of the rows next to them, so slabs of one parity share no particle and their pairs can
        be summed at once (:func:`~athermal.model.loops.energy_gradient_slabs`).
    """

    first: NDArray[np.int32]
    second: NDArray[np.int32]
    code: NDArray[np.int16]
    images: NDArray[np.float64]
    skin: float
    reference: NDArray[np.float64]
    slabs: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def n_pairs(self) -> int:
        """Number of listed pairs P."""
        return int(self.second.size)

    def shifts(self, cell: Cell) -> NDArray[np.float64]:
        """Lattice translations ``(C, d)`` of the image codes in ``cell``."""
        return transform(self.images, cell.h)

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
        moved = _blocks.max_displacement_sq(
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
) -> tuple[
    NDArray[np.int32], NDArray[np.int32], NDArray[np.int16], NDArray[np.float64], NDArray[np.int64]
]:
    """Pairs by :func:`collect_pairs` (2D embedded in 3D with ``z = 0`` and one bin), and their
    slabs (:attr:`NeighborList.slabs`)."""
    d, n = cell.dim, r.size
    x3 = np.zeros((n, 3))
    x3[:, :d] = x
    h3, hinv3 = np.eye(3), np.eye(3)
    h3[:d, :d], hinv3[:d, :d] = cell.h, cell.inverse
    nb3 = np.ones(3, dtype=np.int64)
    nb3[:d] = nbins
    rows = int(nb3[d - 1])
    chunks = min(CHUNKS_PER_THREAD * numba.get_num_threads(), rows // 2)
    threaded = n >= PARALLEL_BUILD and chunks >= 2 and threads_usable()
    if threaded:
        bin_start, member, xs, rs, fs = bin_particles_threads(x3, h3, hinv3, nb3, r, chunks)
    else:
        bin_start, member, xs, rs, fs = bin_particles(x3, h3, hinv3, nb3, r)
    m = int(np.ptp(fs, axis=0).max()) + 1 if n else 1  # bound on |image| components
    side = 2 * m + 1
    if side**d > _MAX_IMAGE_CODES:
        raise InputError("positions: particles lie too many cells outside the box; wrap them first")
    weights = np.zeros(3, dtype=np.int64)
    weights[:d] = side ** np.arange(d)
    offsets = _half_stencil(d)
    row_start = np.zeros(rows + 1, dtype=np.int64)
    search = (bin_start, member, xs, rs, fs, h3, nb3, offsets, skin, weights, m)
    if threaded:
        first, second, code = _search_chunks(search, rows, chunks, d, row_start)
    else:
        first, second, code = _search_bins(search, 0, int(np.prod(nb3)), n, d, row_start)
    row_start[rows] = first.size
    return first, second, code, _image_table(m, d), _slabs(row_start)


def _search_bins(
    search: tuple[Any, ...], lo: int, hi: int, particles: int, dim: int, row_start: Any
) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.int16]]:
    """The pairs of bins ``lo ... hi - 1`` (``particles`` in them) by :func:`collect_pairs` on
    ``search`` (its arguments up to ``m``), buffers grown until they fit; ``row_start`` gets the
    rows' first pairs, counted from this search's first."""
    capacity = int(PAIRS_PER_PARTICLE[dim] * particles) + 16
    first = np.empty(capacity, dtype=np.int32)
    second = np.empty(capacity, dtype=np.int32)
    code = np.empty(capacity, dtype=np.int16)
    count, done = 0, lo
    while True:
        count, done = collect_pairs(  # type: ignore[call-arg]
            *search, first, second, code, row_start, done, count, hi, first.size
        )
        if done == hi:
            return first[:count], second[:count], code[:count]
        first, second, code = (np.concatenate([a, np.empty_like(a)]) for a in (first, second, code))


def _search_chunks(
    search: tuple[Any, ...], rows: int, chunks: int, dim: int, row_start: Any
) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.int16]]:
    """The pairs of :func:`_search_bins` over all bins, the rows cut into ``chunks`` searched on
    the threads (:func:`collect_chunks`), each into its own part of one buffer; a chunk whose
    part overflows is searched again on its own. The pairs come out in the order and with the
    ``row_start`` of the one-thread search."""
    bin_start, nbins = search[0], search[6]
    row_size = int(np.prod(nbins)) // rows
    edges = (np.arange(chunks + 1) * rows) // chunks
    bins = edges * row_size
    held = np.diff(bin_start[bins])
    room = 1.25 * PAIRS_PER_PARTICLE[dim] * held
    base = np.concatenate([[0], np.cumsum(room.astype(np.int64) + 64)])
    first = np.empty(base[-1], dtype=np.int32)
    second = np.empty(base[-1], dtype=np.int32)
    code = np.empty(base[-1], dtype=np.int16)
    counts, stops = collect_chunks(*search, first, second, code, row_start, bins, base)  # type: ignore[call-arg]
    parts = []
    offset = 0
    for k in range(chunks):
        rows_k = slice(edges[k], edges[k + 1])
        if stops[k] == bins[k + 1]:
            part = tuple(a[base[k] : counts[k]] for a in (first, second, code))
            row_start[rows_k] += offset - base[k]
        else:  # overflowed its part: on its own, buffers grown as needed
            lo, hi = int(bins[k]), int(bins[k + 1])
            part = _search_bins(search, lo, hi, int(held[k]), dim, row_start)
            row_start[rows_k] += offset
        parts.append(part)
        offset += part[0].size
    return tuple(np.concatenate([p[a] for p in parts]) for a in range(3))  # type: ignore[return-value]


def _slabs(row_start: NDArray[np.int64]) -> NDArray[np.int64]:
    """Pair offsets of an even number (4 ... :data:`SLABS`) of slabs of >= 2 rows each, from
    the rows' pair offsets ``row_start`` ``(R + 1,)``; empty when there are fewer than 8 rows."""
    rows = row_start.size - 1
    count = min(SLABS, 2 * (rows // 4))
    if count < 4:
        return np.zeros(0, dtype=np.int64)
    edges = (np.arange(count + 1) * rows) // count  # >= 2 rows each
    return np.ascontiguousarray(row_start[edges])


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
    cell : the cell (any tilt); no pair is listed across its walls.
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
        first, second, code, table, slabs = _half_stencil_search(x, r, cell, skin, nbins)
    else:  # cells narrower than three cut-offs: search every image
        h, hinv = np.ascontiguousarray(cell.h), np.ascontiguousarray(cell.inverse)
        first, second, image = cell_list_pairs(x, r, h, hinv, skin, nbins, reach)
        code, table = _encode_images(image, cell.dim)
        slabs = np.zeros(0, dtype=np.int64)
    if cell.walls:  # no pair across a wall
        inside = ~np.any(table[:, list(cell.walls)] != 0.0, axis=1)[code]
        first, second, code = first[inside], second[inside], code[inside]
        kept = np.concatenate([[0], np.cumsum(inside)])
        slabs = np.ascontiguousarray(kept[slabs])
    return NeighborList(first, second, code, table, skin, x.copy(), slabs)


def brute_force_pairs(
    positions: NDArray[np.float64], radii: NDArray[np.float64], cell: Cell, skin: float
) -> set[tuple[int, int, tuple[int, ...]]]:
    """Every pair ``(i, j, n)`` with ``i <= j`` and ``|x_i - x_j + h n| < r_i + r_j + skin``
    (``n`` zero along the cell's walled axes).

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
                if j < i or (j == i and not _positive(n)) or any(n[a] for a in cell.walls):
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


@_jit
def _counting_sort(bin_of, total_bins):  # type: ignore[no-untyped-def]
    """Particles grouped by bin: ``bin_start (B+1,)`` offsets and ``member (N,)`` indices."""
    n = bin_of.size
    bin_start = np.zeros(total_bins + 1, dtype=np.int64)
    for i in range(n):
        bin_start[bin_of[i] + 1] += 1
    for b in range(total_bins):
        bin_start[b + 1] += bin_start[b]
    fill = bin_start[:-1].copy()
    member = np.empty(n, dtype=np.int64)
    for i in range(n):
        member[fill[bin_of[i]]] = i
        fill[bin_of[i]] += 1
    return bin_start, member


@_jit
def cell_list_pairs(x, radii, h, hinv, skin, nbins, reach):  # type: ignore[no-untyped-def]
    """Half list of pairs closer than ``r_i + r_j + skin`` by a cell list in any periodic cell.

    Returns ``first (P,)``, ``second (P,)`` int32 (sorted by ``first``; this general search
    also handles cells narrower than three cut-offs) and ``image (P, d)``
    int32 lattice images.
    ``reach[k]`` bins are searched on each side along axis k (> 1 only for tiny cells).
    """
    n, d = x.shape
    frac = np.empty((n, d))
    floor_s = np.empty((n, d), dtype=np.int64)
    bin_of = np.zeros(n, dtype=np.int64)
    for i in range(n):
        lin = 0
        for a in range(d - 1, -1, -1):
            s = 0.0
            for b in range(d):
                s += hinv[a, b] * x[i, b]
            f = np.floor(s)
            floor_s[i, a] = np.int64(f)
            frac[i, a] = s - f
            k = np.int64(frac[i, a] * nbins[a])
            if k >= nbins[a]:
                k = nbins[a] - 1
            lin = lin * nbins[a] + k
        bin_of[i] = lin
    total_bins = 1
    for a in range(d):
        total_bins *= nbins[a]
    bin_start, members = _counting_sort(bin_of, total_bins)

    n_offsets = 1
    for a in range(d):
        n_offsets *= 2 * reach[a] + 1
    capacity = max(16, 8 * n)
    partner = np.empty(capacity, dtype=np.int32)
    image = np.empty((capacity, d), dtype=np.int32)
    start = np.zeros(n + 1, dtype=np.int64)
    count = 0
    cb = np.empty(d, dtype=np.int64)
    nb_bin = np.empty(d, dtype=np.int64)
    wrap = np.empty(d, dtype=np.int64)
    ds = np.empty(d)
    for i in range(n):
        rem = bin_of[i]
        for a in range(d):
            cb[a] = rem % nbins[a]
            rem //= nbins[a]
        for off in range(n_offsets):
            rem = off
            lin = 0
            for a in range(d):
                o = rem % (2 * reach[a] + 1) - reach[a]
                rem //= 2 * reach[a] + 1
                t = cb[a] + o
                w = t // nbins[a]
                wrap[a] = w
                nb_bin[a] = t - w * nbins[a]
            for a in range(d - 1, -1, -1):
                lin = lin * nbins[a] + nb_bin[a]
            self_image_ok = False
            for a in range(d - 1, -1, -1):
                if wrap[a] != 0:
                    self_image_ok = wrap[a] < 0  # stored image is -wrap: keep n > 0
                    break
            for m in range(bin_start[lin], bin_start[lin + 1]):
                j = members[m]
                if j < i or (j == i and not self_image_ok):
                    continue
                for a in range(d):
                    ds[a] = frac[i, a] - frac[j, a] - wrap[a]
                r2 = 0.0
                for a in range(d):
                    c = 0.0
                    for b in range(a, d):
                        c += h[a, b] * ds[b]
                    r2 += c * c
                cut = radii[i] + radii[j] + skin
                if r2 >= cut * cut:
                    continue
                if count == capacity:
                    capacity *= 2
                    grown = np.empty(capacity, dtype=np.int32)
                    grown[:count] = partner[:count]
                    partner = grown
                    grown_img = np.empty((capacity, d), dtype=np.int32)
                    grown_img[:count] = image[:count]
                    image = grown_img
                partner[count] = j
                for a in range(d):
                    image[count, a] = floor_s[j, a] - floor_s[i, a] - wrap[a]
                count += 1
        start[i + 1] = count
    first = np.empty(count, dtype=np.int32)
    for i in range(n):
        first[start[i] : start[i + 1]] = i
    return first, partner[:count].copy(), image[:count].copy()


@_jit
def bin_particles(x, h, hinv, nbins, radii):  # type: ignore[no-untyped-def]
    """Sort particles into the bins of a cell list (three components; 2D padded with ``z = 0``).

    Returns ``bin_start (B+1,)``, ``member (N,)`` (particle of each slot, bin by bin), and per
    slot the wrapped coordinates ``xs (N, 3)``, radius ``rs (N,)`` and the lattice cell
    ``fs (N, 3)`` int64 the particle was wrapped from (``x = h (s + fs)``).
    """
    n = x.shape[0]
    bin_of = np.empty(n, dtype=np.int64)
    _bins_of(x, hinv, nbins, bin_of, 0, n)
    bin_start, member = _counting_sort(bin_of, nbins[0] * nbins[1] * nbins[2])
    xs, fs, rs = np.empty((n, 3)), np.empty((n, 3), dtype=np.int64), np.empty(n)
    _fill_slots(x, h, hinv, radii, member, xs, fs, rs, 0, n)
    return bin_start, member, xs, rs, fs


@_jit_parallel
def bin_particles_threads(x, h, hinv, nbins, radii, chunks):  # type: ignore[no-untyped-def]
    """:func:`bin_particles` with its two passes over the particles on the threads, in
    ``chunks`` ranges each (the counting sort between them stays on one thread); the same
    result."""
    n = x.shape[0]
    bin_of = np.empty(n, dtype=np.int64)
    for k in prange(chunks):
        _bins_of(x, hinv, nbins, bin_of, k * n // chunks, (k + 1) * n // chunks)
    bin_start, member = _counting_sort(bin_of, nbins[0] * nbins[1] * nbins[2])
    xs, fs, rs = np.empty((n, 3)), np.empty((n, 3), dtype=np.int64), np.empty(n)
    for k in prange(chunks):
        lo, hi = k * n // chunks, (k + 1) * n // chunks
        _fill_slots(x, h, hinv, radii, member, xs, fs, rs, lo, hi)
    return bin_start, member, xs, rs, fs


@_jit
def _bins_of(x, hinv, nbins, bin_of, lo, hi):  # type: ignore[no-untyped-def]
    """The bin of particles ``lo ... hi - 1`` into ``bin_of``."""
    nb0, nb1, nb2 = nbins[0], nbins[1], nbins[2]
    for i in range(lo, hi):
        s2 = hinv[2, 2] * x[i, 2]
        s1 = hinv[1, 1] * x[i, 1] + hinv[1, 2] * x[i, 2]
        s0 = hinv[0, 0] * x[i, 0] + hinv[0, 1] * x[i, 1] + hinv[0, 2] * x[i, 2]
        k0 = min(np.int64((s0 - np.floor(s0)) * nb0), nb0 - 1)
        k1 = min(np.int64((s1 - np.floor(s1)) * nb1), nb1 - 1)
        k2 = min(np.int64((s2 - np.floor(s2)) * nb2), nb2 - 1)
        bin_of[i] = (k2 * nb1 + k1) * nb0 + k0


@_jit
def _fill_slots(x, h, hinv, radii, member, xs, fs, rs, lo, hi):  # type: ignore[no-untyped-def]
    """Slots ``lo ... hi - 1`` of :func:`bin_particles`' ``xs``, ``fs`` and ``rs``."""
    for m in range(lo, hi):
        i = member[m]
        s2 = hinv[2, 2] * x[i, 2]
        s1 = hinv[1, 1] * x[i, 1] + hinv[1, 2] * x[i, 2]
        s0 = hinv[0, 0] * x[i, 0] + hinv[0, 1] * x[i, 1] + hinv[0, 2] * x[i, 2]
        f0, f1, f2 = np.floor(s0), np.floor(s1), np.floor(s2)
        fs[m, 0], fs[m, 1], fs[m, 2] = np.int64(f0), np.int64(f1), np.int64(f2)
        s0 -= f0
        s1 -= f1
        s2 -= f2
        xs[m, 0] = h[0, 0] * s0 + h[0, 1] * s1 + h[0, 2] * s2
        xs[m, 1] = h[1, 1] * s1 + h[1, 2] * s2
        xs[m, 2] = h[2, 2] * s2
        rs[m] = radii[i]


@_jit
def collect_pairs(  # type: ignore[no-untyped-def]
    bin_start,
    member,
    xs,
    rs,
    fs,
    h,
    nbins,
    offsets,
    skin,
    weights,
    m,
    first,
    second,
    code,
    row_start,
    bin_from,
    count,
    bin_to,
    capacity,
):
    """Half-stencil pair search over bins ``bin_from ... bin_to - 1`` for cells >= 3 bins wide
    per axis.

    ``offsets (S, 3)`` holds the zero offset first, then one of each pair ``+-o``, so each pair is
    checked once. Pairs go into the caller's buffers from index ``count`` up to ``capacity``
    with ``first <= second`` and ``code = sum_a (n_a + m) weights[a]`` for the image ``n`` of the
    separation ``x_first - x_second + h n``. Returns ``(count, bin)``: ``bin`` is ``bin_to``
    when all are done, else the first bin that did not fit (the buffers are then to be grown
    and the call resumed from it). The buffers are never reallocated here: numba would then
    reference-count them in the inner loop (slower: ``docs/decisions.md``, "Measured behind the
    code"). ``row_start[r]`` gets the first pair of row ``r`` of bins along the last binned axis
    (z, or y in 2D).
    """
    nb0, nb1, nb2 = nbins[0], nbins[1], nbins[2]
    row_size = nb0 * nb1 if nb2 > 1 else nb0
    for b in range(bin_from, bin_to):
        if b % row_size == 0:
            row_start[b // row_size] = count
        c0 = b % nb0
        c1 = (b // nb0) % nb1
        c2 = b // (nb0 * nb1)
        count_at_bin = count
        for o in range(offsets.shape[0]):
            t0, t1, t2 = c0 + offsets[o, 0], c1 + offsets[o, 1], c2 + offsets[o, 2]
            w0 = -1 if t0 < 0 else (1 if t0 >= nb0 else 0)
            w1 = -1 if t1 < 0 else (1 if t1 >= nb1 else 0)
            w2 = -1 if t2 < 0 else (1 if t2 >= nb2 else 0)
            nb_lin = ((t2 - w2 * nb2) * nb1 + (t1 - w1 * nb1)) * nb0 + (t0 - w0 * nb0)
            sx = h[0, 0] * w0 + h[0, 1] * w1 + h[0, 2] * w2
            sy = h[1, 1] * w1 + h[1, 2] * w2
            sz = h[2, 2] * w2
            for mi in range(bin_start[b], bin_start[b + 1]):
                xi, yi, zi, ri = xs[mi, 0] - sx, xs[mi, 1] - sy, xs[mi, 2] - sz, rs[mi]
                lo = mi + 1 if o == 0 else bin_start[nb_lin]
                for mj in range(lo, bin_start[nb_lin + 1]):
                    dx = xi - xs[mj, 0]
                    dy = yi - xs[mj, 1]
                    dz = zi - xs[mj, 2]
                    cut = ri + rs[mj] + skin
                    if dx * dx + dy * dy + dz * dz >= cut * cut:
                        continue
                    if count == capacity:
                        return count_at_bin, b
                    i = member[mi]
                    j = member[mj]
                    # image of the separation x_i - x_j + h n: n = fs_j - fs_i - wrap
                    n0 = fs[mj, 0] - fs[mi, 0] - w0
                    n1 = fs[mj, 1] - fs[mi, 1] - w1
                    n2 = fs[mj, 2] - fs[mi, 2] - w2
                    if j < i:
                        i, j = j, i
                        n0, n1, n2 = -n0, -n1, -n2
                    first[count] = i
                    second[count] = j
                    n0 = (n0 + m) * weights[0] + (n1 + m) * weights[1] + (n2 + m) * weights[2]
                    code[count] = n0
                    count += 1
    return count, bin_to


@_jit_parallel
def collect_chunks(  # type: ignore[no-untyped-def]
    bin_start,
    member,
    xs,
    rs,
    fs,
    h,
    nbins,
    offsets,
    skin,
    weights,
    m,
    first,
    second,
    code,
    row_start,
    bins,
    base,
):
    """:func:`collect_pairs` on the threads: chunk ``k`` (bins ``bins[k] ... bins[k+1] - 1``,
    whole rows) into the buffers' part ``base[k] ... base[k+1] - 1``. Returns each chunk's end
    ``(K,)`` in the buffers and where it stopped ``(K,)`` (``bins[k+1]`` when it fitted)."""
    chunks = bins.size - 1
    counts = np.zeros(chunks, dtype=np.int64)
    stops = np.zeros(chunks, dtype=np.int64)
    for k in prange(chunks):
        counts[k], stops[k] = collect_pairs(
            bin_start, member, xs, rs, fs, h, nbins, offsets, skin, weights, m,
            first, second, code, row_start, bins[k], base[k], bins[k + 1], base[k + 1],
        )  # fmt: skip
    return counts, stops
