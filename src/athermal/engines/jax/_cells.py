"""The Verlet list built on the device: a cell list in fractional coordinates, valid in any
sheared cell, with fixed capacities that report their overflow.

Particles are binned by their wrapped fractional coordinates ``s = h^-1 x mod 1`` into
``nbins_a`` bins along each lattice direction, ``nbins_a = floor(W_a / cutoff)`` with ``W_a``
the distance between the cell's faces: a pair within the cut-off ``2 r_max + skin`` is then at
most one bin apart in each direction, so each particle's ``3^d`` neighbouring bins hold all its
partners, and with at least 3 bins per direction each image of a partner is met once. A bin
holds at most ``bin_capacity`` particles and the list at most ``pair_capacity`` pairs (the
half list ``i < j``, compacted in the order of ``i``); beyond either the build says so
(:func:`build`'s ``overflow``), and the caller builds again with larger capacities: an
overflowing list is never used. Each pair's shift is ``h (u_j - u_i - n)``, ``u`` the cells a
particle was wrapped by and ``n`` the image its bin stepped into, so that the separation is
``x_i - x_j + shift`` with the caller's unwrapped positions.
"""

from __future__ import annotations

import itertools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ...model.cell import Cell


def bins_for(cell: Cell, cutoff: float) -> tuple[int, ...] | None:
    """Bins per lattice direction for pairs within ``cutoff`` in ``cell``; None where a
    direction would hold fewer than 3 (a small or strongly sheared cell: the host's list)."""
    nbins = tuple(int(w // cutoff) for w in cell.widths)
    return nbins if min(nbins) >= 3 else None


def build(
    x: Any,
    radii: Any,
    typeid: Any,
    kmat: Any,
    h: Any,
    skin: float,
    nbins: tuple[int, ...],
    bin_capacity: int,
    pair_capacity: int,
) -> tuple[tuple[Any, ...], Any, Any, Any]:
    """The padded pairs (:attr:`~._pairs.Pairs.arrays`) of positions ``x`` ``(N, d)`` within
    ``r_i + r_j + skin``, their count, the fullest bin's count and whether a capacity
    overflowed (``nbins``, ``bin_capacity``, ``pair_capacity`` static; module docstring)."""
    n, dim = x.shape
    hinv = jnp.linalg.inv(h)
    raw = x @ hinv.T
    wrapped_by = jnp.floor(raw)
    s = raw - wrapped_by
    shape = jnp.asarray(nbins)
    b = jnp.minimum((s * shape).astype(jnp.int64), shape - 1)
    strides = np.cumprod((1, *nbins[:0:-1]))[::-1]  # row-major bin index
    bin_id = b @ jnp.asarray(strides)
    total = int(np.prod(nbins))
    order = jnp.argsort(bin_id)
    sorted_bins = bin_id[order]
    rank = jnp.arange(n) - jnp.searchsorted(sorted_bins, sorted_bins, side="left")
    fullest = jnp.max(rank) + 1
    table = jnp.full((total, bin_capacity), n).at[sorted_bins, rank].set(order, mode="drop")
    offsets = jnp.asarray(list(itertools.product((-1, 0, 1), repeat=dim)))  # (3^d, d)
    stepped = b[:, None, :] + offsets[None, :, :]  # (N, 3^d, d)
    image = jnp.floor_divide(stepped, shape)  # the image each neighbouring bin lies in
    neighbour = (stepped - image * shape) @ jnp.asarray(strides)  # (N, 3^d)
    partner = table[neighbour]  # (N, 3^d, capacity); n marks an empty slot
    j = partner.reshape(n, -1)
    crossed = jnp.repeat(image, bin_capacity, axis=1)  # (N, 3^d capacity, d)
    valid = j < n
    jj = jnp.where(valid, j, 0)
    lattice = wrapped_by[jj] - wrapped_by[:, None, :] - crossed  # u_j - u_i - n
    shift = lattice @ h.T
    sep = x[:, None, :] - x[jj] + shift
    reach = radii[:, None] + radii[jj] + skin
    first = jnp.arange(n)[:, None]
    keep = valid & (first < jj) & (jnp.sum(sep * sep, axis=2) < reach * reach)
    count = jnp.sum(keep)
    rows, slots = jnp.nonzero(keep, size=pair_capacity, fill_value=0)
    real = jnp.arange(pair_capacity) < count
    i_of = jnp.where(real, rows, jnp.arange(pair_capacity) % n)
    j_of = jnp.where(real, jj[rows, slots], i_of)
    pairs = (
        i_of,
        j_of,
        jnp.where(real[:, None], shift[rows, slots], 0.0),
        jnp.where(real, radii[i_of] + radii[j_of], 0.0),
        jnp.where(real, kmat[typeid[i_of], typeid[j_of]], 0.0),
    )
    overflow = (fullest > bin_capacity) | (count > pair_capacity)
    return pairs, count, fullest, overflow


build_compiled = jax.jit(build, static_argnums=(6, 7, 8))
