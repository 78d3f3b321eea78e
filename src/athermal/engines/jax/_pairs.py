"""The pairs of a packing on the device and what they give: the contact energy, its gradient,
the stress and the contact count, as pure functions of the positions ``(N, d)``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np
from numpy.typing import NDArray

from ...model.cell import Cell
from ...model.contact import ContactModel
from ...model.law import ContactLaw
from ...model.neighbors import build_neighbor_list


def capacity_for(count: int, current: int = 0) -> int:
    """The padded length for ``count`` entries: ``current`` if it holds them, else ``1.1
    count`` rounded up to an eighth of its power of two (at least 16): the jitted loops compile
    again only when a list grows by a tenth, and padding stays below a quarter."""
    if count <= current:
        return current
    target = max(int(np.ceil(1.1 * count)), 16)
    step = max(1 << (target.bit_length() - 4), 2)
    return -(-target // step) * step


def padded(values: NDArray[Any], size: int, spread: int = 0) -> Any:
    """``values`` on the device, padded along the first axis to ``size``: with zeros, or for
    indices (``spread`` rows) with ``0, 1, ..., spread - 1`` cyclically, so that the padding's
    zero contributions are scattered over many rows (an accelerator serializes atomic adds to
    one address)."""
    extra = size - values.shape[0]
    if spread:
        pad = (np.arange(extra) % spread).astype(values.dtype)
    else:
        pad = np.zeros((extra, *values.shape[1:]), dtype=values.dtype)
    return jnp.asarray(np.concatenate([values, pad]))


@dataclass(frozen=True)
class Pairs:
    """A Verlet list on the device, padded to ``capacity`` pairs: ends ``first``, ``second``
    ``(capacity,)``, image shifts ``shift`` ``(capacity, d)``, radius sums ``radius_sum``
    ``(capacity,)`` (0 for padding: a padding pair joins a particle to itself and contributes
    nothing) and stiffnesses ``stiffness`` ``(capacity,)``; ``count`` real pairs, built at
    ``reference`` ``(N, d)`` with skin ``skin``."""

    first: Any
    second: Any
    shift: Any
    radius_sum: Any
    stiffness: Any
    count: int
    capacity: int
    reference: NDArray[np.float64]
    skin: float

    @property
    def arrays(self) -> tuple[Any, ...]:
        """``(first, second, shift, radius_sum, stiffness)``, as the kernels take them."""
        return self.first, self.second, self.shift, self.radius_sum, self.stiffness


def device_pairs(
    positions: NDArray[np.float64],
    radii: NDArray[np.float64],
    cell: Cell,
    model: ContactModel,
    typeid: NDArray[np.int64],
    skin: float,
    capacity: int = 0,
) -> Pairs:
    """The Verlet list (skin ``skin``, length units) of ``positions`` ``(N, d)`` with ``radii``
    in ``cell``, built on the host (:func:`~athermal.model.neighbors.build_neighbor_list`, exact in
    any sheared cell), on the device padded to :func:`capacity_for` ``(count, capacity)``: the
    engine's list where its cell is too small for the device's cell list."""
    nlist = build_neighbor_list(positions, radii, cell, skin)
    count = int(nlist.first.size)
    size = capacity_for(count, capacity)
    kmat = np.asarray(model.kmat, dtype=np.float64)
    n = positions.shape[0]
    return Pairs(
        padded(nlist.first.astype(np.int64), size, n),
        padded(nlist.second.astype(np.int64), size, n),
        padded(nlist.shifts(cell)[nlist.code], size),
        padded(radii[nlist.first] + radii[nlist.second], size),
        padded(kmat[typeid[nlist.first], typeid[nlist.second]], size),
        count,
        size,
        np.array(nlist.reference, copy=True),
        float(skin),
    )


def _overlaps(x: Any, first: Any, second: Any, shift: Any, radius_sum: Any) -> tuple[Any, ...]:
    """Per pair: the separation ``x_i - x_j + shift`` ``(P, d)``, its length (1 where it is 0)
    and the overlap ``max(r_i + r_j - l, 0)`` (0 for coincident centres and padding)."""
    sep = x[first] - x[second] + shift
    length_sq = jnp.sum(sep * sep, axis=1)
    length = jnp.sqrt(jnp.where(length_sq > 0.0, length_sq, 1.0))
    overlap = jnp.where(length_sq > 0.0, jnp.maximum(radius_sum - length, 0.0), 0.0)
    return sep, length, overlap


def energy_gradient(x: Any, pairs: tuple[Any, ...], law: ContactLaw) -> tuple[Any, Any]:
    """The contact energy ``sum_c E(delta)`` and its gradient ``(N, d)`` at positions ``x``
    ``(N, d)`` over the padded pairs (:attr:`Pairs.arrays`) by the ``law``'s JAX form
    (static)."""
    first, second, shift, radius_sum, stiffness = pairs
    sep, length, overlap = _overlaps(x, first, second, shift, radius_sum)
    terms, force = law.jax_pair(overlap, stiffness)  # force on first, along +sep
    energy = law.jax_total(jnp.sum(terms))
    pull = (force / length)[:, None] * sep
    grad = jnp.zeros_like(x).at[first].add(-pull).at[second].add(pull)
    return energy, grad


def stress_contacts(
    x: Any, pairs: tuple[Any, ...], law: ContactLaw, volume: float
) -> tuple[Any, Any]:
    """The contact stress ``sigma = (1/V) sum_c l_c (x) f_c`` ``(d, d)`` (the convention of
    :func:`athermal.analysis.observables.stress`: positive pressure under compression) over a cell
    of ``volume``, and the number of overlapping pairs, at ``x`` ``(N, d)`` over the padded pairs
    (:attr:`Pairs.arrays`)."""
    first, second, shift, radius_sum, stiffness = pairs
    sep, length, overlap = _overlaps(x, first, second, shift, radius_sum)
    _, force = law.jax_pair(overlap, stiffness)
    weight = force / length
    stress = jnp.einsum("c,ca,cb->ab", weight, sep, sep) / volume
    return stress, jnp.sum(overlap > 0.0)


def block_max(v: Any) -> Any:
    """The largest Euclidean norm of a row of ``v`` ``(N, d)``."""
    return jnp.sqrt(jnp.max(jnp.sum(v * v, axis=1)))
