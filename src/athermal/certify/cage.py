"""Where a particle fits in its cage: the nearest point that keeps it clear of fixed neighbours.

A rattler's neighbours exclude a ball each (radius the sum of the two radii) from the places its
centre may take; the free region is what the balls leave. The point of that region nearest to
the rattler lies on its boundary: the radial projection onto one sphere, the point nearest to the
rattler on the circle where two spheres meet (two points in 2D), or, in 3D, a point where three
spheres meet. :func:`nearest_clear` lists those candidates and keeps the nearest one that is
clear of every neighbour, which is exact for one particle among fixed neighbours;
:func:`free_place` keeps the nearest one that a straight move reaches without passing through
a neighbour (:func:`reached`: not closer to an overlapping neighbour than now, nor into another),
so that a rattler stays in its cage. Pushing a squeezed particle straight out of each overlap
cannot do this: held between two neighbours on a line, it goes back and forth between them,
while its free places lie to the side, where the two spheres meet.

Rattlers that touch each other may have room only when moved together (two of them squeezed in
one cage): :func:`free_places` minimizes their squared overlaps
(:func:`athermal.minimize.minimize`) until they vanish, from rest and then from random starts (a
particle squeezed on a line sits on a saddle of that energy).
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import combinations

import numpy as np
from numpy.typing import NDArray

from .._portable import row_dots, vdot, vnorm
from ..minimize import minimize

CLEARANCE = 1e-14
"""A placed particle keeps ``CLEARANCE x`` the sum of the radii clear of the neighbours whose
spheres define its place: well above the round-off of offsets rounded once from double-double,
below the overlaps of a packing bracketed to 1e-12 (``docs/decisions.md``, "Jamming below
float64's resolution")."""
TRIES = 8
"""Starts of :func:`free_places`: from rest, then random."""


def free_place(
    offsets: NDArray[np.float64], reach: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """The displacement ``(d,)`` of a particle (2D or 3D) to its nearest place at least
    ``reach`` ``(m,)`` (and :data:`CLEARANCE`) from each neighbour at ``offsets`` ``(m, d)``
    (relative to the particle; the neighbours held fixed) that a straight move reaches without
    passing through a neighbour (:func:`reached`): zero when it is there already, None when the
    cage leaves no such place."""
    offsets, reach = np.asarray(offsets, np.float64), np.asarray(reach, np.float64)
    inside = _clear_places(offsets, reach, lambda p: reached(p, offsets, reach))
    return min(inside, key=lambda p: vdot(p, p)) if inside else None


def nearest_clear(
    offsets: NDArray[np.float64], reach: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """The shortest displacement ``(d,)`` that puts the particle at least ``reach`` ``(m,)``
    (and :data:`CLEARANCE`) from each neighbour at ``offsets`` ``(m, d)``, wherever it lies,
    through neighbours or not (None: no candidate is clear)."""
    points = _clear_places(np.asarray(offsets, np.float64), np.asarray(reach, np.float64))
    return min(points, key=lambda p: vdot(p, p)) if points else None


def _clear_places(
    offsets: NDArray[np.float64],
    reach: NDArray[np.float64],
    keep: Callable[[NDArray[np.float64]], bool] = lambda p: True,
) -> list[NDArray[np.float64]]:
    """The candidates ``(d,)`` (module docstring) that are clear of every neighbour and that
    ``keep`` keeps, in order: only the origin when it is clear by :data:`CLEARANCE` already.
    Those where two spheres meet come only from spheres whose surface passes within the nearest
    kept radial candidate of the origin, and those where three meet from spheres within the
    nearest kept candidate of one or two: a candidate lies on each of its spheres, so one from
    another sphere is farther, and the nearest candidate is never left out."""
    dim = offsets.shape[1]
    target = reach * (1.0 + CLEARANCE)
    length = np.linalg.norm(offsets, axis=1)
    if np.all(length >= target):
        return [np.zeros(dim)]
    surface = np.abs(length - target)  # how near each sphere passes to the origin
    places = _kept(_radial(offsets, target), offsets, reach, keep)
    bound = min((vnorm(p) for p in places), default=np.inf)
    near = np.flatnonzero(surface <= bound)
    two = [
        _circle(offsets[j], offsets[k], target[j], target[k], dim) for j, k in combinations(near, 2)
    ]
    places += _kept(np.concatenate([np.empty((0, dim)), *two]), offsets, reach, keep)
    if dim == 3:
        bound = min((vnorm(p) for p in places), default=np.inf)
        near = np.flatnonzero(surface <= bound)
        triples = np.array(list(combinations(near, 3)), dtype=np.intp).reshape(-1, 3)
        places += _kept(_three(offsets[triples], target[triples]), offsets, reach, keep)
    return places


def _kept(
    points: NDArray[np.float64],
    offsets: NDArray[np.float64],
    reach: NDArray[np.float64],
    keep: Callable[[NDArray[np.float64]], bool],
) -> list[NDArray[np.float64]]:
    """The ``points`` ``(c, d)`` at least ``reach`` from every neighbour that ``keep`` keeps."""
    return [p for p in points[_clear(points, offsets, reach)] if keep(p)]


def _clear(
    points: NDArray[np.float64], offsets: NDArray[np.float64], reach: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """Which of ``points`` ``(c, d)`` are at least ``reach`` from every neighbour."""
    return np.all(np.linalg.norm(points[:, None, :] - offsets[None, :, :], axis=2) >= reach, axis=1)


def reached(
    move: NDArray[np.float64],
    offsets: NDArray[np.float64],
    reach: NDArray[np.float64],
    slack: float = 0.0,
) -> bool:
    """Whether the straight ``move`` ``(d,)`` comes no closer to any neighbour at ``offsets``
    ``(m, d)`` than ``min(its distance now, its reach) - slack``: it passes through none."""
    length_sq = max(vdot(move, move), np.finfo(float).tiny)
    t = np.clip(row_dots(offsets, move[None, :]) / length_sq, 0.0, 1.0)  # each nearest point
    nearest = np.linalg.norm(t[:, None] * move[None, :] - offsets, axis=1)
    allowed = np.minimum(np.linalg.norm(offsets, axis=1), reach)
    return bool(np.all(nearest >= allowed * (1.0 - CLEARANCE) - slack))


def _radial(offsets: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each sphere's point nearest to the origin."""
    length = np.linalg.norm(offsets, axis=1)
    keep = length > 0.0
    return offsets[keep] * (1.0 - target[keep] / length[keep])[:, None]


def _circle(
    a: NDArray[np.float64], b: NDArray[np.float64], ra: float, rb: float, dim: int
) -> NDArray[np.float64]:
    """The points nearest to the origin where the spheres ``(a, ra)`` and ``(b, rb)`` meet: the
    two crossings in 2D, the circle's nearest point in 3D; none when they do not meet."""
    axis = b - a
    length = vnorm(axis)
    if length == 0.0:
        return np.empty((0, dim))
    axis = axis / length
    along = (length * length + (ra - rb) * (ra + rb)) / (2.0 * length)
    across_sq = (ra - along) * (ra + along)
    if across_sq < 0.0:
        return np.empty((0, dim))
    centre = a + along * axis
    across = np.sqrt(across_sq)
    if dim == 2:
        side = np.array([-axis[1], axis[0]])
        return np.array([centre + across * side, centre - across * side])
    toward = -centre - vdot(-centre, axis) * axis
    norm = vnorm(toward)
    if norm == 0.0:  # the origin on the axis: every point of the circle is as near
        toward = np.cross(axis, [1.0, 0.0, 0.0])
        if vnorm(toward) < 0.5:
            toward = np.cross(axis, [0.0, 1.0, 0.0])
        norm = vnorm(toward)
    return (centre + across * toward / norm)[None, :]


def _three(centres: NDArray[np.float64], radii: NDArray[np.float64]) -> NDArray[np.float64]:
    """The points where three spheres meet, for ``T`` triples of centres ``(T, 3, 3)`` and
    radii ``(T, 3)``: up to two a triple, in the triples' order ``(c, 3)``."""
    c0, c1, c2 = centres[:, 0], centres[:, 1], centres[:, 2]
    a0, a1 = c1 - c0, c2 - c0
    squared = row_dots(c0, c0)
    r0, r1, r2 = radii[:, 0], radii[:, 1], radii[:, 2]
    rhs0 = 0.5 * (row_dots(c1, c1) - squared - (r1 - r0) * (r1 + r0))
    rhs1 = 0.5 * (row_dots(c2, c2) - squared - (r2 - r0) * (r2 + r0))
    normal = np.cross(a0, a1)
    nn = row_dots(normal, normal)
    # on the line where the three planes a x = rhs meet: the least-norm x = a^T (a a^T)^-1 rhs
    g00, g01, g11 = row_dots(a0, a0), row_dots(a0, a1), row_dots(a1, a1)
    with np.errstate(divide="ignore", invalid="ignore"):
        det = g00 * g11 - g01 * g01
        y0, y1 = (g11 * rhs0 - g01 * rhs1) / det, (g00 * rhs1 - g01 * rhs0) / det
        rel = (y0[:, None] * a0 + y1[:, None] * a1) - c0
        rel = rel - (row_dots(rel, normal) / nn)[:, None] * normal  # nearest the first centre
        s_sq = (r0 * r0 - row_dots(rel, rel)) / nn
    meet = (nn != 0.0) & (s_sq >= 0.0)
    point, normal = (c0 + rel)[meet], normal[meet] * np.sqrt(s_sq[meet])[:, None]
    return np.stack([point + normal, point - normal], axis=1).reshape(-1, 3)


def free_places(
    first: NDArray[np.int64],
    second: NDArray[np.int64],
    offsets: NDArray[np.float64],
    reach: NDArray[np.float64],
    movers: int,
    seed: int = 0,
) -> tuple[NDArray[np.float64], bool] | None:
    """Displacements ``(movers, d)`` that put ``movers`` particles, moved together, at least
    ``reach`` ``(p,)`` apart in each pair, and whether they do: pair ``k`` joins mover
    ``first[k]`` to ``second[k]`` (a mover, or -1 for a fixed neighbour), ``offsets[k]``
    ``(p, d)`` the second's position less the first's. Where no start reaches zero overlap, the
    least overlapping place found (the particles bear load there); None when every move found
    passes through a fixed neighbour (:func:`reached`, with the largest overlap now as slack:
    loaded, a particle may come that much closer to a neighbour)."""
    dim = offsets.shape[1]
    target = reach * (1.0 + CLEARANCE)
    overlap = target - np.linalg.norm(offsets, axis=1)
    if not np.any(overlap > 0.0):
        return np.zeros((movers, dim)), True
    scale = float(np.sqrt(reach.mean() * overlap.max()))  # a sideways step out of a squeeze
    fixed = second < 0
    other = np.where(fixed, 0, second)
    ends = np.concatenate([first, other[~fixed]])  # the particles each pair pushes, in turn

    def energy(v: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        u = v.reshape(movers, dim) * scale
        sep = offsets + np.where(fixed[:, None], 0.0, u[other]) - u[first]
        length = np.linalg.norm(sep, axis=1)
        over = np.maximum(target - length, 0.0) / scale
        push = (2.0 * over / length)[:, None] * sep  # d energy / d u_first, per pair
        terms = np.concatenate([push, -push[~fixed]])
        grad = [np.bincount(ends, terms[:, a], movers) for a in range(dim)]
        return vdot(over, over), np.stack(grad, axis=1, dtype=np.float64).reshape(-1)

    rng = np.random.default_rng(seed)
    best: tuple[float, NDArray[np.float64]] | None = None
    for attempt in range(TRIES):
        start = np.zeros(movers * dim) if attempt == 0 else rng.normal(size=movers * dim)
        result = minimize(energy, start, gtol=1e-14, etol=0.0, maxiter=2000)
        moves = result.x.reshape(movers, dim) * scale
        if not all(
            reached(
                moves[i],
                offsets[fixed & (first == i)],
                reach[fixed & (first == i)],
                float(overlap.max()),
            )
            for i in range(movers)
        ):
            continue
        if result.fun <= 0.0:
            return moves, True
        if best is None or result.fun < best[0]:
            best = (result.fun, moves)
    return None if best is None else (best[1], False)
