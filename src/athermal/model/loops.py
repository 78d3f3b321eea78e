"""The compiled pair loops of the contact energy, each calling the contact law's numba form
(:class:`~athermal.model.law.NumbaForm`): energy and gradient (by dimension, and by slabs on the
threads), the walls' part, the count of overlaps, the Hessian's terms, products and blocks, and
the one evaluation every caller uses (:func:`evaluate`). :func:`kernels` gives them for a law of
one's own, compiled once more.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np
from numba import prange
from numpy.typing import NDArray

from .._jit import _jit, _jit_parallel, rebound, threads_usable
from ..errors import InputError
from .law import ContactLaw, PowerContact
from .law import power_curvature as _law_curvature
from .law import power_pair as _law_pair
from .law import power_total as _law_total
from .neighbors import NeighborList

ONE_THREAD = np.zeros(0, dtype=np.int64)
"""The ``slabs`` argument of :func:`evaluate` that sums pair by pair (writable, as the slabs of a
list are: numba compiles read-only arrays as another type)."""
NO_WALLS = (np.zeros(0, dtype=np.int64), np.zeros(0))
"""The walled axes and half lengths (:data:`Walls`) of a periodic cell."""
PARALLEL_PAIRS = 100_000
"""Listed pairs from which the energy and gradient run on the threads (:func:`parallel_slabs`;
measured in ``docs/decisions.md``, "The kernels on many cores")."""


def parallel_slabs(nlist: NeighborList) -> tuple[NDArray[np.int64], bool]:
    """The ``slabs`` and ``threads`` arguments of :func:`evaluate` for ``nlist``: its slabs when
    it lists at least :data:`PARALLEL_PAIRS` pairs (else empty: pair by pair), and whether the
    threads can sum them (more than one numba thread and allowed core, and the main thread:
    numba's default threading layer takes one caller at a time). Either way the sum is the
    same bits: the order is the list's, not the machine's."""
    if nlist.n_pairs < PARALLEL_PAIRS or not nlist.slabs.size:
        return ONE_THREAD, False
    return nlist.slabs, threads_usable()


# A plain scatter loop, a branch-free overlap test (``max(delta, 0)``) and no species lookup for a
# uniform stiffness: the fastest written (docs/decisions.md, "Measured behind the code").
@_jit
def energy_gradient_2d(x, radii, first, second, code, shift, typeid, kmat, alpha, grad):  # type: ignore[no-untyped-def]
    """Energy ``sum E(delta)`` over pairs (the law's ``pair`` and ``total``, :class:`~athermal.
    model.law.NumbaForm`) and the number of overlapping pairs
    (``|x_i - x_j + shift|^2 < (r_i + r_j)^2``); gradient written into ``grad (N, 2)``."""
    grad[:] = 0.0
    twice, contacts = _pairs_2d(
        x, radii, first, second, code, shift, typeid, kmat, alpha, grad, 0, first.size
    )
    return _law_total(twice, alpha), contacts


@_jit
def _pairs_2d(x, radii, first, second, code, shift, typeid, kmat, alpha, grad, lo, hi):  # type: ignore[no-untyped-def]
    """Pairs ``lo ... hi - 1`` of :func:`energy_gradient_2d`: their gradient added into
    ``grad``; the sum of their energy terms (the law's ``pair``), and their overlapping pairs."""
    energy = 0.0
    contacts = 0
    uniform = kmat.size == 1
    k = kmat[0, 0]
    for p in range(lo, hi):
        i = first[p]
        j = second[p]
        c = code[p]
        dx = x[i, 0] - x[j, 0] + shift[c, 0]
        dy = x[i, 1] - x[j, 1] + shift[c, 1]
        dist_sq = dx * dx + dy * dy
        reach = radii[i] + radii[j]
        contacts += dist_sq < reach * reach
        dist = np.sqrt(dist_sq)
        delta = max(reach - dist, 0.0)
        if not uniform:
            k = kmat[typeid[i], typeid[j]]
        e, f = _law_pair(delta, k, alpha)
        energy += e
        s = f / dist
        fx = s * dx
        fy = s * dy
        grad[i, 0] -= fx
        grad[i, 1] -= fy
        grad[j, 0] += fx
        grad[j, 1] += fy
    return energy, contacts


@_jit
def energy_gradient_3d(x, radii, first, second, code, shift, typeid, kmat, alpha, grad):  # type: ignore[no-untyped-def]
    """3D twin of :func:`energy_gradient_2d` (``grad (N, 3)``)."""
    grad[:] = 0.0
    twice, contacts = _pairs_3d(
        x, radii, first, second, code, shift, typeid, kmat, alpha, grad, 0, first.size
    )
    return _law_total(twice, alpha), contacts


@_jit
def _pairs_3d(x, radii, first, second, code, shift, typeid, kmat, alpha, grad, lo, hi):  # type: ignore[no-untyped-def]
    """3D twin of :func:`_pairs_2d`."""
    energy = 0.0
    contacts = 0
    uniform = kmat.size == 1
    k = kmat[0, 0]
    for p in range(lo, hi):
        i = first[p]
        j = second[p]
        c = code[p]
        dx = x[i, 0] - x[j, 0] + shift[c, 0]
        dy = x[i, 1] - x[j, 1] + shift[c, 1]
        dz = x[i, 2] - x[j, 2] + shift[c, 2]
        dist_sq = dx * dx + dy * dy + dz * dz
        reach = radii[i] + radii[j]
        contacts += dist_sq < reach * reach
        dist = np.sqrt(dist_sq)
        delta = max(reach - dist, 0.0)
        if not uniform:
            k = kmat[typeid[i], typeid[j]]
        e, f = _law_pair(delta, k, alpha)
        energy += e
        s = f / dist
        fx = s * dx
        fy = s * dy
        fz = s * dz
        grad[i, 0] -= fx
        grad[i, 1] -= fy
        grad[i, 2] -= fz
        grad[j, 0] += fx
        grad[j, 1] += fy
        grad[j, 2] += fz
    return energy, contacts


@_jit
def _slab(  # type: ignore[no-untyped-def]
    x, radii, first, second, code, shift, typeid, kmat, alpha, grad, slabs, s, energies, overlapping
):
    """The pairs of slab ``s``: their gradient added into ``grad``, their energy terms' sum
    into ``energies[s]`` and their overlapping pairs into ``overlapping[s]``."""
    lo, hi = slabs[s], slabs[s + 1]
    if x.shape[1] == 2:
        e, c = _pairs_2d(x, radii, first, second, code, shift, typeid, kmat, alpha, grad, lo, hi)
    else:
        e, c = _pairs_3d(x, radii, first, second, code, shift, typeid, kmat, alpha, grad, lo, hi)
    energies[s] = e
    overlapping[s] = c


@_jit
def _slab_total(energies, overlapping, alpha):  # type: ignore[no-untyped-def]
    """The slabs' energy (their energy terms summed in slab order, then the law's ``total``)
    and their overlapping pairs."""
    energy = 0.0
    for s in range(energies.size):
        energy += energies[s]
    return _law_total(energy, alpha), overlapping.sum()


@_jit_parallel
def energy_gradient_slabs(x, radii, first, second, code, shift, typeid, kmat, alpha, grad, slabs):  # type: ignore[no-untyped-def]
    """:func:`energy_gradient_2d` (or 3d) on the threads: the pairs of the even slabs of the
    list (:attr:`~athermal.model.neighbors.NeighborList.slabs`) at once, then those of the odd ones
    (slabs of one parity share no particle, so no two threads add into one row of ``grad``).
    Every row of ``grad`` gets its terms in one order whatever the number of threads, and the
    slabs' energies are summed in slab order: the same bits as :func:`energy_gradient_slabs_serial`
    on one thread."""
    count = slabs.size - 1
    energies = np.zeros(count)
    overlapping = np.zeros(count, dtype=np.int64)
    grad[:] = 0.0
    for parity in range(2):
        for half in prange(count // 2):
            _slab(
                x, radii, first, second, code, shift, typeid, kmat, alpha, grad, slabs,
                2 * half + parity, energies, overlapping,
            )  # fmt: skip
    return _slab_total(energies, overlapping, alpha)


@_jit
def energy_gradient_slabs_serial(  # type: ignore[no-untyped-def]
    x, radii, first, second, code, shift, typeid, kmat, alpha, grad, slabs
):
    """:func:`energy_gradient_slabs` on the calling thread alone, in the same order (even slabs,
    then odd ones): where the threads cannot run, a large packing still gets their bits."""
    count = slabs.size - 1
    energies = np.zeros(count)
    overlapping = np.zeros(count, dtype=np.int64)
    grad[:] = 0.0
    for parity in range(2):
        for half in range(count // 2):
            _slab(
                x, radii, first, second, code, shift, typeid, kmat, alpha, grad, slabs,
                2 * half + parity, energies, overlapping,
            )  # fmt: skip
    return _slab_total(energies, overlapping, alpha)


@_jit
def count_overlaps(x, radii, first, second, code, shift):  # type: ignore[no-untyped-def]
    """Number of listed pairs that overlap (``|x_i - x_j + shift| < r_i + r_j``)."""
    count = 0
    d = x.shape[1]
    for p in range(first.size):
        i = first[p]
        j = second[p]
        r2 = 0.0
        for a in range(d):
            t = x[i, a] - x[j, a] + shift[code[p], a]
            r2 += t * t
        reach = radii[i] + radii[j]
        if r2 < reach * reach:
            count += 1
    return count


@_jit
def hessian_terms(x, radii, first, second, code, shift, typeid, kmat, alpha, pairs, sep, coef):  # type: ignore[no-untyped-def]
    """The overlapping pairs' Hessian blocks ``K = a b b^T - c I`` (``b`` the separation
    ``x_i - x_j + shift``, ``l = |b|``): ``a = (E'' + f/l) / l^2`` and ``c = f/l`` (the law's
    ``curvature``). Writes ``pairs (P, 2)``,
    ``sep (P, d)`` and ``coef (P, 2)`` = ``(a, c)`` for the first M rows; returns M."""
    d = x.shape[1]
    uniform = kmat.size == 1
    k = kmat[0, 0]
    m = 0
    for p in range(first.size):
        i = first[p]
        j = second[p]
        if i == j:  # a particle and its own image: no relative displacement, no block
            continue
        dist_sq = 0.0
        for a in range(d):
            t = x[i, a] - x[j, a] + shift[code[p], a]
            sep[m, a] = t
            dist_sq += t * t
        reach = radii[i] + radii[j]
        if not dist_sq < reach * reach:
            continue
        dist = np.sqrt(dist_sq)
        delta = reach - dist
        if not uniform:
            k = kmat[typeid[i], typeid[j]]
        a, c = _law_curvature(delta, dist, k, alpha)
        pairs[m, 0] = i
        pairs[m, 1] = j
        coef[m, 0] = a / dist_sq
        coef[m, 1] = c
        m += 1
    return m


@_jit
def hessian_product(pairs, sep, coef, v, out):  # type: ignore[no-untyped-def]
    """``out = H v`` ``(N, d)`` from the blocks of :func:`hessian_terms`: each adds
    ``K (v_i - v_j)`` to ``out_i`` and subtracts it from ``out_j``."""
    out[:] = 0.0
    d = v.shape[1]
    for p in range(pairs.shape[0]):
        i = pairs[p, 0]
        j = pairs[p, 1]
        bu = 0.0
        for a in range(d):
            bu += sep[p, a] * (v[i, a] - v[j, a])
        a_n = coef[p, 0] * bu
        c_t = coef[p, 1]
        for a in range(d):
            ku = a_n * sep[p, a] - c_t * (v[i, a] - v[j, a])
            out[i, a] += ku
            out[j, a] -= ku


@_jit
def _block_entry(sep, coef, p, x, y):  # type: ignore[no-untyped-def]
    """Entry ``(x, y)`` of pair ``p``'s block ``K = a b b^T - c I`` (:func:`hessian_terms`):
    ``a (b_x b_y) - c delta_xy``, as NumPy's broadcast forms it."""
    return coef[p, 0] * (sep[p, x] * sep[p, y]) - coef[p, 1] * (1.0 if x == y else 0.0)


@_jit
def pair_blocks(sep, coef, rows, out):  # type: ignore[no-untyped-def]
    """The blocks of the pairs ``rows`` into ``out`` ``(len(rows), d, d)``."""
    d = sep.shape[1]
    for q in range(rows.size):
        for x in range(d):
            for y in range(d):
                out[q, x, y] = _block_entry(sep, coef, rows[q], x, y)


@_jit
def diagonal_blocks(pairs, sep, coef, out):  # type: ignore[no-untyped-def]
    """``out`` ``(N, d, d)`` = each particle's diagonal block of ``H``: the sum of its pairs'
    blocks (a pair with its own image adds nothing), first over the pairs where it is the
    first particle, then where it is the second, each in pair order (the sums ``np.add.at``
    forms)."""
    d = sep.shape[1]
    out[:] = 0.0
    for end in range(2):
        for p in range(pairs.shape[0]):
            if pairs[p, 0] == pairs[p, 1]:
                continue
            i = pairs[p, end]
            for x in range(d):
                for y in range(d):
                    out[i, x, y] += _block_entry(sep, coef, p, x, y)


@_jit
def block_csr(first, second, blocks, n):  # type: ignore[no-untyped-def]
    """The symmetric ``(n d, n d)`` matrix with ``+K_p`` on blocks ``(i, i)`` and ``(j, j)`` and
    ``-K_p`` on ``(i, j)`` and ``(j, i)`` of each pair ``p`` (``i = first[p]``, ``j =
    second[p]``; pairs with ``i == j`` skipped), from symmetric ``blocks`` ``(M, d, d)``: CSR
    ``(indptr, indices, data)`` with sorted columns, every diagonal block stored. Duplicate
    pairs (two images) are summed in pair order on both sides, so the matrix is exactly
    symmetric."""
    d = blocks.shape[1]
    degree = np.ones(n, dtype=np.int64)  # the diagonal block, then one per pair end
    for p in range(first.size):
        if first[p] != second[p]:
            degree[first[p]] += 1
            degree[second[p]] += 1
    start = np.zeros(n + 1, dtype=np.int64)
    for a in range(n):
        start[a + 1] = start[a] + degree[a]
    neighbours = np.empty(start[n], dtype=np.int64)
    fill = start[:n].copy()
    for a in range(n):
        neighbours[fill[a]] = a
        fill[a] += 1
    for p in range(first.size):
        i, j = first[p], second[p]
        if i != j:
            neighbours[fill[i]] = j
            fill[i] += 1
            neighbours[fill[j]] = i
            fill[j] += 1
    # each particle's distinct neighbours, sorted: the block pattern
    bptr = np.zeros(n + 1, dtype=np.int64)
    for a in range(n):
        row = neighbours[start[a] : start[a + 1]]
        for k in range(1, row.size):  # insertion sort: a handful of neighbours
            value = row[k]
            q = k - 1
            while q >= 0 and row[q] > value:
                row[q + 1] = row[q]
                q -= 1
            row[q + 1] = value
        count = 1
        for k in range(1, row.size):
            if row[k] != row[count - 1]:
                row[count] = row[k]
                count += 1
        bptr[a + 1] = bptr[a] + count
    bcols = np.empty(bptr[n], dtype=np.int64)
    for a in range(n):
        for k in range(bptr[a + 1] - bptr[a]):
            bcols[bptr[a] + k] = neighbours[start[a] + k]
    bvals = np.zeros((bptr[n], d, d))
    for p in range(first.size):
        i, j = first[p], second[p]
        if i == j:
            continue
        for end in range(4):
            a = i if end % 2 == 0 else j  # blocks (i, i), (j, j), (i, j), (j, i)
            b = a if end < 2 else (j if end == 2 else i)
            k = bptr[a]
            while bcols[k] != b:
                k += 1
            sign = 1.0 if end < 2 else -1.0
            for r in range(d):
                for c in range(d):
                    bvals[k, r, c] += sign * blocks[p, r, c]
    indptr = np.empty(n * d + 1, dtype=np.int64)
    indices = np.empty(bptr[n] * d * d, dtype=np.int64)
    data = np.empty(bptr[n] * d * d)
    indptr[0] = 0
    for a in range(n):
        width = (bptr[a + 1] - bptr[a]) * d
        for r in range(d):
            q = bptr[a] * d * d + r * width
            indptr[a * d + r + 1] = q + width
            for k in range(bptr[a], bptr[a + 1]):
                for c in range(d):
                    indices[q] = bcols[k] * d + c
                    data[q] = bvals[k, r, c]
                    q += 1
    return indptr, indices, data


@_jit
def evaluate(  # type: ignore[no-untyped-def]
    points,
    gradient,
    radii,
    first,
    second,
    images,
    shift,
    typeid,
    kmat,
    alpha,
    walls,
    half,
    kwall,
    slabs,
    threads,
):
    """The contact energy and overlapping pairs at ``points`` ``(N, d)``, its gradient written
    into ``gradient`` ``(N, d)``, by the kernel of the dimension (arguments as
    :func:`energy_gradient_2d`), in the order of the list's slabs when ``slabs`` holds them
    (:func:`energy_gradient_slabs` on the threads when ``threads``, else its one-thread twin;
    empty: pair by pair), then the walls' (:func:`wall_energy_gradient`): the one evaluation
    every caller uses, so that the energy at a point is the same bits from Python and from
    compiled loops, and on any number of threads."""
    args = (radii, first, second, images, shift, typeid, kmat, alpha, gradient)
    if slabs.size and threads:
        energy, contacts = energy_gradient_slabs(points, *args, slabs)
    elif slabs.size:
        energy, contacts = energy_gradient_slabs_serial(points, *args, slabs)
    elif points.shape[1] == 2:
        energy, contacts = energy_gradient_2d(points, *args)
    else:
        energy, contacts = energy_gradient_3d(points, *args)
    if walls.size:
        e_wall, c_wall = wall_energy_gradient(
            points, radii, typeid, walls, half, kwall, alpha, gradient
        )
        energy += e_wall
        contacts += c_wall
    return energy, contacts


@_jit
def wall_energy_gradient(x, radii, typeid, walls, half, kwall, alpha, grad):  # type: ignore[no-untyped-def]
    """Energy ``sum E(delta)`` (the law's, stiffness ``k_w``) of the particles' overlaps with
    the walls and
    their number, the gradient added into ``grad (N, d)``. Along axis ``a = walls[w]`` the walls
    lie at ``x_a = -half[w]`` and ``+half[w]``; a particle overlaps them by
    ``delta = r_i - (x_ia + half)`` and ``r_i - (half - x_ia)`` (flat and frictionless: the
    force is along the axis). ``kwall (T,)`` by species ``typeid``."""
    energy = 0.0
    contacts = 0
    for i in range(x.shape[0]):
        k = kwall[typeid[i]]
        for w in range(walls.size):
            a = walls[w]
            low = radii[i] - (x[i, a] + half[w])
            if low > 0.0:
                e, f = _law_pair(low, k, alpha)
                energy += e
                grad[i, a] -= f
                contacts += 1
            high = radii[i] - (half[w] - x[i, a])
            if high > 0.0:
                e, f = _law_pair(high, k, alpha)
                energy += e
                grad[i, a] += f
                contacts += 1
    return _law_total(energy, alpha), contacts


_LAW_LOOPS = (
    _pairs_2d,
    _pairs_3d,
    energy_gradient_2d,
    energy_gradient_3d,
    _slab,
    _slab_total,
    energy_gradient_slabs,
    energy_gradient_slabs_serial,
    wall_energy_gradient,
    evaluate,
    hessian_terms,
)
"""The compiled loops that call the contact law, and those that call them."""


@cache
def kernels(law: ContactLaw) -> dict[str, Any]:
    """The compiled loops of :data:`_LAW_LOOPS` for ``law``, by name (``evaluate``,
    ``hessian_terms``, ...): this module's own (cached on disk) for the power law, else the
    same loops compiled for the law's :class:`~athermal.model.law.NumbaForm` on first use.
    Raises :class:`InputError` for a law without one."""
    form = law.numba
    if form is None:
        raise InputError(f"law {law.name}: it has no numba form; the numba engine cannot relax it")
    if form == PowerContact.numba:
        return {loop.py_func.__name__: loop for loop in _LAW_LOOPS}
    return rebound(
        _LAW_LOOPS,
        {"_law_pair": form.pair, "_law_total": form.total, "_law_curvature": form.curvature},
    )
