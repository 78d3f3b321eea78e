"""Compiled (numba) kernels: the cell-list pair search, the energy+gradient loops (which also
count the overlapping pairs), the L-BFGS direction's vector loops and the incomplete Cholesky
factor with its triangular solves.

Pair convention everywhere: pair ``p`` joins ``first[p] <= second[p]``
with the image table index ``code[p]``; the separation is ``x[first] - x[second] + shift[code]``
where ``shift = images @ h.T``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

_jit = nb.njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
# Reassociation, contraction and approximate functions only; NaN and inf keep their meaning. No
# reciprocal rewriting ("arcp"): LLVM applied it differently where a kernel was inlined into a
# compiled loop than where it ran on its own, and the energy at one point differed by an ulp
# between the two (alpha = 2.5).
_jit_fast = nb.njit(
    cache=True,
    nogil=True,
    error_model="numpy",
    boundscheck=False,
    fastmath={"nsz", "contract", "afn", "reassoc"},
)


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
    nb0, nb1, nb2 = nbins[0], nbins[1], nbins[2]
    bin_of = np.empty(n, dtype=np.int64)
    for i in range(n):
        s2 = hinv[2, 2] * x[i, 2]
        s1 = hinv[1, 1] * x[i, 1] + hinv[1, 2] * x[i, 2]
        s0 = hinv[0, 0] * x[i, 0] + hinv[0, 1] * x[i, 1] + hinv[0, 2] * x[i, 2]
        k0 = min(np.int64((s0 - np.floor(s0)) * nb0), nb0 - 1)
        k1 = min(np.int64((s1 - np.floor(s1)) * nb1), nb1 - 1)
        k2 = min(np.int64((s2 - np.floor(s2)) * nb2), nb2 - 1)
        bin_of[i] = (k2 * nb1 + k1) * nb0 + k0
    bin_start, member = _counting_sort(bin_of, nb0 * nb1 * nb2)
    xs = np.empty((n, 3))
    fs = np.empty((n, 3), dtype=np.int64)
    rs = np.empty(n)
    for m in range(n):
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
    return bin_start, member, xs, rs, fs


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
    bin_from,
    count,
):
    """Half-stencil pair search over bins ``bin_from, ...`` for cells >= 3 bins wide per axis.

    ``offsets (S, 3)`` holds the zero offset first, then one of each pair ``+-o``, so each pair is
    checked once. Pairs go into the caller's buffers from index ``count`` with ``first <= second``
    and ``code = sum_a (n_a + m) weights[a]`` for the image ``n`` of the separation
    ``x_first - x_second + h n``. Returns ``(count, bin)``: ``bin`` is the number of bins when all
    are done, else the first bin that did not fit (the buffers are then to be grown and the call
    resumed from it). The buffers are never reallocated here: numba would then reference-count
    them in the inner loop (measured 2x slower).
    """
    nb0, nb1, nb2 = nbins[0], nbins[1], nbins[2]
    capacity = first.size
    for b in range(bin_from, nb0 * nb1 * nb2):
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
    return count, nb0 * nb1 * nb2


@_jit
def _pair_force(delta, k, alpha):  # type: ignore[no-untyped-def]
    """Force magnitude ``k delta^(alpha-1)`` with fast paths for alpha = 2, 2.5, 3."""
    if alpha == 2.0:
        return k * delta
    if alpha == 2.5:
        return k * delta * np.sqrt(delta)
    if alpha == 3.0:
        return k * delta * delta
    return k * delta ** (alpha - 1.0)


# Measured on this kind of machine: a plain scatter loop beat per-row register accumulation, a
# branch-free overlap test (``max(delta, 0)``) is no slower and avoids mispredictions at large N,
# and skipping the species lookup for a uniform stiffness saves ~3 ns per pair.
@_jit_fast
def energy_gradient_2d(x, radii, first, second, code, shift, typeid, kmat, alpha, grad):  # type: ignore[no-untyped-def]
    """Energy ``sum k delta^alpha / alpha`` over pairs and the number of overlapping pairs
    (``|x_i - x_j + shift|^2 < (r_i + r_j)^2``); gradient written into ``grad (N, 2)``."""
    energy = 0.0
    contacts = 0
    grad[:] = 0.0
    uniform = kmat.size == 1
    k = kmat[0, 0]
    for p in range(first.size):
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
        f = _pair_force(delta, k, alpha)
        energy += f * delta
        s = f / dist
        fx = s * dx
        fy = s * dy
        grad[i, 0] -= fx
        grad[i, 1] -= fy
        grad[j, 0] += fx
        grad[j, 1] += fy
    return energy / alpha, contacts


@_jit_fast
def energy_gradient_3d(x, radii, first, second, code, shift, typeid, kmat, alpha, grad):  # type: ignore[no-untyped-def]
    """3D twin of :func:`energy_gradient_2d` (``grad (N, 3)``)."""
    energy = 0.0
    contacts = 0
    grad[:] = 0.0
    uniform = kmat.size == 1
    k = kmat[0, 0]
    for p in range(first.size):
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
        f = _pair_force(delta, k, alpha)
        energy += f * delta
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
    return energy / alpha, contacts


@_jit_fast
def _row_norm_sq(v, p, dim):  # type: ignore[no-untyped-def]
    """``|v_p|^2`` of the ``dim``-vector at flat offset ``p``, under the kernels' ``fastmath``
    (the largest gradient and the step cap keep the bits they always had)."""
    s = 0.0
    for k in range(dim):
        s += v[p + k] * v[p + k]
    return s


@_jit
def _row_gap_sq(u, v, a, w, p, dim):  # type: ignore[no-untyped-def]
    """``|(u + a v) - w|^2`` of the ``dim``-vectors at flat offset ``p``, without ``fastmath``:
    ``u + a v`` rounds as the trial points of :func:`~athermal._wolfe.energy_search` do, so
    that the compiled and the Python reach tests agree on the point evaluated."""
    s = 0.0
    for k in range(dim):
        t = (u[p + k] + a * v[p + k]) - w[p + k]
        s += t * t
    return s


@_jit
def _row_place_sq(u, v, a, w, out, p, dim):  # type: ignore[no-untyped-def]
    """:func:`_row_gap_sq`, writing ``u + a v`` into ``out`` on the way (the same bits)."""
    s = 0.0
    for k in range(dim):
        t = u[p + k] + a * v[p + k]
        out[p + k] = t
        t = t - w[p + k]
        s += t * t
    return s


NORM, GAP, PLACE = range(3)
"""Modes of :func:`max_row_sq`: the rows' norms, their gaps, their gaps with the points
written."""


@_jit
def _row_sq(u, v, a, w, out, p, dim, mode):  # type: ignore[no-untyped-def]
    """:func:`_row_norm_sq` of ``u``, :func:`_row_gap_sq` or :func:`_row_place_sq` by
    ``mode``."""
    if mode == PLACE:
        return _row_place_sq(u, v, a, w, out, p, dim)
    if mode == GAP:
        return _row_gap_sq(u, v, a, w, p, dim)
    return _row_norm_sq(u, p, dim)


@_jit
def _max_row_sq(u, v, a, w, out, dim, mode):  # type: ignore[no-untyped-def]
    """``max_i`` of :func:`_row_sq` over the ``dim``-vectors of the flat arrays, four rows at a
    time: four running maxima, where one waits on the last comparison (measurements:
    ``docs/decisions.md``, section "Compiled kernels"). Called with a literal ``dim`` and
    ``mode``, which the compiler folds in."""
    rows = u.size // dim
    b0 = b1 = b2 = b3 = 0.0
    i = 0
    while i + 4 <= rows:
        p = i * dim
        b0 = max(b0, _row_sq(u, v, a, w, out, p, dim, mode))
        b1 = max(b1, _row_sq(u, v, a, w, out, p + dim, dim, mode))
        b2 = max(b2, _row_sq(u, v, a, w, out, p + 2 * dim, dim, mode))
        b3 = max(b3, _row_sq(u, v, a, w, out, p + 3 * dim, dim, mode))
        i += 4
    while i < rows:
        b0 = max(b0, _row_sq(u, v, a, w, out, i * dim, dim, mode))
        i += 1
    return max(max(b0, b1), max(b2, b3))


@_jit
def max_row_sq(u, v, a, w, out, dim, mode):  # type: ignore[no-untyped-def]
    """By ``mode``: ``max_i |u_i|^2`` (:data:`NORM`), ``max_i |(u_i + a v_i) - w_i|^2``
    (:data:`GAP`), or that with ``u + a v`` written into ``out`` (:data:`PLACE`), over the
    ``dim``-vectors of the flat arrays (:func:`_max_row_sq`, with ``dim`` 2 and 3 as
    compile-time constants)."""
    if dim == 2:
        return _max_row_sq(u, v, a, w, out, 2, mode)
    if dim == 3:
        return _max_row_sq(u, v, a, w, out, 3, mode)
    return _max_row_sq(u, v, a, w, out, dim, mode)


@_jit
def max_displacement_sq(x, reference):  # type: ignore[no-untyped-def]
    """Largest squared displacement ``max_i |x_i - reference_i|^2`` over the rows of ``x`` and
    ``reference`` ``(N, d)`` (C-contiguous)."""
    flat = x.reshape(x.size)
    return max_row_sq(flat, flat, 0.0, reference.reshape(reference.size), flat, x.shape[1], GAP)


@_jit
def same_values(a, b):  # type: ignore[no-untyped-def]
    """True when the flat arrays ``a`` and ``b`` (same size) hold equal values; stops at the
    first difference (NaN equals nothing)."""
    for p in range(a.size):
        if a[p] != b[p]:
            return False
    return True


@_jit
def max_row_norm(v, d):  # type: ignore[no-untyped-def]
    """``max_i |v_i|`` over the ``d``-vectors of a flat ``(N d,)`` array."""
    return np.sqrt(max_row_sq(v, v, 0.0, v, v, d, NORM))


@_jit
def step_limit(max_step, direction, d):  # type: ignore[no-untyped-def]
    """Largest ``a`` for which ``a direction`` moves no ``d``-vector more than ``max_step``;
    ``inf`` for a zero direction."""
    longest = max_row_norm(direction, d)
    return max_step / longest if longest > 0.0 else np.inf


@_jit
def energy_noise(scale, alpha, energy):  # type: ignore[no-untyped-def]
    """``scale (alpha max(E, 0))^(1 - 1/alpha)``: the round-off of a contact energy ``E``
    (:meth:`athermal.objective.Objective.energy_noise` says why)."""
    return scale * (alpha * max(energy, 0.0)) ** (1.0 - 1.0 / alpha)


_CHUNK = 1024
"""Entries of a vector per block of the L-BFGS loops: two 8 kB blocks stay in L1 cache."""


@_jit_fast
def lbfgs_direction(grad, z, s_mem, py_mem, y_new, fresh, sy_mat, ypy_mat, gamma, order, work, out):  # type: ignore[no-untyped-def]
    """The L-BFGS step ``out = -H grad`` in compact form (Byrd, Nocedal & Schnabel 1994),
    ``H0 = gamma_newest P^-1``, in two blocked passes over the stored vectors.

    ``H grad = gamma z + S p - gamma PY w`` with ``z = P^-1 grad``, ``w = R^-1 S^T grad`` and
    ``p = R^-T (D w + gamma (Y^T P^-1 Y) w - gamma PY^T grad)``, where ``R`` is the upper
    triangle of ``S^T Y`` (pairs oldest first) and ``D`` its diagonal; ``Y^T P^-1 y =
    PY^T y`` since ``P`` is symmetric. It equals the two-loop recursion's step, reading the
    pairs' ``s`` and ``P^-1 y`` twice in all instead of ``s``, ``y`` and ``P^-1 y`` about
    five times.

    Pairs are the rows ``order`` (oldest first) of ``s_mem`` and ``py_mem`` ``(m + 1, n)``;
    ``sy_mat[a, b] = s_a.y_b`` (``a`` no newer than ``b``) and ``ypy_mat[a, b] = y_a.P^-1 y_b``
    ``(m + 1, m + 1)``. When ``fresh``, the newest pair's column of both (its dot products
    with ``y_new``, the newest ``y``) is computed in the first pass and written. ``work``
    ``(4, m + 1)`` is scratch; ``out`` ``(n,)`` receives the step.
    """
    n = grad.size
    count = order.size
    if count == 0:
        for p in range(n):
            out[p] = -z[p]
        return
    u = work[0]
    v = work[1]
    col_sy = work[2]
    col_ypy = work[3]
    for t in range(count):
        u[t] = 0.0
        v[t] = 0.0
        col_sy[t] = 0.0
        col_ypy[t] = 0.0
    for lo in range(0, n, _CHUNK):
        hi = min(n, lo + _CHUNK)
        g_blk = grad[lo:hi]
        y_blk = y_new[lo:hi]
        for t in range(count):
            s_blk = s_mem[order[t], lo:hi]
            py_blk = py_mem[order[t], lo:hi]
            a = 0.0
            b = 0.0
            if fresh:
                c = 0.0
                e = 0.0
                for p in range(hi - lo):
                    a += s_blk[p] * g_blk[p]
                    b += py_blk[p] * g_blk[p]
                    c += s_blk[p] * y_blk[p]
                    e += py_blk[p] * y_blk[p]
                col_sy[t] += c
                col_ypy[t] += e
            else:
                for p in range(hi - lo):
                    a += s_blk[p] * g_blk[p]
                    b += py_blk[p] * g_blk[p]
            u[t] += a
            v[t] += b
    newest = order[count - 1]
    if fresh:
        for t in range(count):
            sy_mat[order[t], newest] = col_sy[t]
            ypy_mat[order[t], newest] = col_ypy[t]
            ypy_mat[newest, order[t]] = col_ypy[t]
    scale = gamma[newest]
    # w = R^-1 u (back substitution), into u
    for i in range(count - 1, -1, -1):
        acc = u[i]
        for j in range(i + 1, count):
            acc -= sy_mat[order[i], order[j]] * u[j]
        u[i] = acc / sy_mat[order[i], order[i]]
    # r = D w + gamma (Y^T P^-1 Y) w - gamma v, into v
    for i in range(count):
        acc = 0.0
        for j in range(count):
            acc += ypy_mat[order[i], order[j]] * u[j]
        v[i] = sy_mat[order[i], order[i]] * u[i] + scale * (acc - v[i])
    # p = R^-T r (forward substitution), into v
    for i in range(count):
        acc = v[i]
        for j in range(i):
            acc -= sy_mat[order[j], order[i]] * v[j]
        v[i] = acc / sy_mat[order[i], order[i]]
    for lo in range(0, n, _CHUNK):
        hi = min(n, lo + _CHUNK)
        o_blk = out[lo:hi]
        z_blk = z[lo:hi]
        for p in range(hi - lo):
            o_blk[p] = -scale * z_blk[p]
        for t in range(count):
            s_blk = s_mem[order[t], lo:hi]
            py_blk = py_mem[order[t], lo:hi]
            cs = -v[t]
            cp = scale * u[t]
            for p in range(hi - lo):
                o_blk[p] += cs * s_blk[p] + cp * py_blk[p]


@_jit_fast
def lbfgs_pair(x, x_new, g, g_new, z, z_new, s, y, py):  # type: ignore[no-untyped-def]
    """One L-BFGS pair in one pass: ``s = x_new - x``, ``y = g_new - g``, ``py = z_new - z``
    (written into the given rows; when ``py`` is ``y`` itself, ``z`` must be ``g`` and ``py``
    is not written, so that no write aliases another and the loop vectorizes as it does with
    separate rows). Returns ``(s.y, y.py)``."""
    separate = py.ctypes.data != y.ctypes.data
    sy = 0.0
    ypy = 0.0
    for p in range(x.size):
        sp = x_new[p] - x[p]
        yp = g_new[p] - g[p]
        pyp = z_new[p] - z[p]
        s[p] = sp
        y[p] = yp
        if separate:
            py[p] = pyp
        sy += sp * yp
        ypy += yp * pyp
    return sy, ypy


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


@_jit_fast
def hessian_terms(x, radii, first, second, code, shift, typeid, kmat, alpha, pairs, sep, coef):  # type: ignore[no-untyped-def]
    """The overlapping pairs' Hessian blocks ``K = a b b^T - c I`` (``b`` the separation
    ``x_i - x_j + shift``, ``l = |b|``): ``a = kappa (alpha - 1 + delta/l) / l^2``,
    ``c = kappa delta/l`` with ``kappa = k delta^(alpha-2)``. Writes ``pairs (P, 2)``,
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
        if alpha == 2.0:
            kappa = k
        elif alpha == 2.5:
            kappa = k * np.sqrt(delta)
        else:
            kappa = k * delta ** (alpha - 2.0)
        ratio = delta / dist
        pairs[m, 0] = i
        pairs[m, 1] = j
        coef[m, 0] = kappa * (alpha - 1.0 + ratio) / dist_sq
        coef[m, 1] = kappa * ratio
        m += 1
    return m


@_jit_fast
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
def incomplete_cholesky(indptr, indices, data, shift):  # type: ignore[no-untyped-def]
    """IC(0) of a symmetric matrix from its lower triangle in CSR (sorted columns, the
    diagonal last in each row, every diagonal present), diagonal scaled by ``1 + shift``: the
    values of ``L`` on that pattern (``L L^T`` equals the matrix there), and whether every
    pivot was positive (the factor is meaningless otherwise)."""
    n = indptr.size - 1
    lower = data.copy()
    for i in range(n):
        a, b = indptr[i], indptr[i + 1]
        for p in range(a, b - 1):  # L_ij, j < i: the entries of rows i and j left of j
            j = indices[p]
            value = lower[p]
            q, r, r_end = a, indptr[j], indptr[j + 1] - 1
            while q < p and r < r_end:
                if indices[q] == indices[r]:
                    value -= lower[q] * lower[r]
                    q += 1
                    r += 1
                elif indices[q] < indices[r]:
                    q += 1
                else:
                    r += 1
            lower[p] = value / lower[indptr[j + 1] - 1]
        pivot = lower[b - 1] * (1.0 + shift)
        for p in range(a, b - 1):
            pivot -= lower[p] * lower[p]
        if not pivot > 0.0:
            return lower, False
        lower[b - 1] = np.sqrt(pivot)
    return lower, True


@_jit
def cholesky_solve_columns(indptr, indices, lower, inverse_diagonal, rhs, out):  # type: ignore[no-untyped-def]
    """``out = (L L^T)^-1 rhs`` for every column of ``rhs`` ``(n, k)``, in interleaved pairs
    (:func:`cholesky_solve_pair`; an odd last column alone)."""
    last = rhs.shape[1] - 1
    for c in range(0, last + 1, 2):
        cholesky_solve_pair(indptr, indices, lower, inverse_diagonal, rhs, out, c, min(c + 1, last))


@_jit
def cholesky_solve_pair(  # type: ignore[no-untyped-def]
    indptr, indices, lower, inverse_diagonal, rhs, out, c0, c1
):
    """Columns ``c0`` and ``c1`` of ``out = (L L^T)^-1 rhs`` (``rhs``, ``out`` ``(n, k)``), ``L``
    lower triangular in CSR (diagonal last in each row, ``inverse_diagonal`` its reciprocal):
    forward substitution by rows, then back substitution by the same rows read as the columns
    of ``L^T``. Two interleaved columns keep two independent chains in flight (a substitution
    is latency-bound: one column costs about as much as two); ``c0 == c1`` solves one."""
    n = rhs.shape[0]
    for i in range(n):
        s0, s1 = rhs[i, c0], rhs[i, c1]
        for p in range(indptr[i], indptr[i + 1] - 1):
            j, value = indices[p], lower[p]
            s0 -= value * out[j, c0]
            s1 -= value * out[j, c1]
        out[i, c0], out[i, c1] = s0 * inverse_diagonal[i], s1 * inverse_diagonal[i]
    for i in range(n - 1, -1, -1):
        s0, s1 = out[i, c0] * inverse_diagonal[i], out[i, c1] * inverse_diagonal[i]
        out[i, c0], out[i, c1] = s0, s1
        if c1 == c0:  # one column: its updates below must not be applied twice
            s1 = 0.0
        for p in range(indptr[i], indptr[i + 1] - 1):
            j, value = indices[p], lower[p]
            out[j, c0] -= value * s0
            out[j, c1] -= value * s1
