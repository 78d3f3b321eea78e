"""Where a rattler fits in its cage: analytic squeezes, a brute-force twin, and a cage with no
room; then the certifier frees a rattler squeezed between two neighbours on a line."""

import numpy as np
import pytest

import athermal as at
from athermal.certify import GAP_REACH, free_rattlers
from athermal.certify.cage import CLEARANCE, free_place, free_places, nearest_clear, reached
from athermal.certify.extended import NearPairs


def clear(move, offsets, reach):
    return np.all(np.linalg.norm(offsets - move, axis=1) >= reach)


def test_a_particle_clear_of_its_neighbours_stays():
    offsets = np.array([[0.03, 0.0], [0.0, -0.04]])
    assert np.array_equal(free_place(offsets, np.full(2, 0.02)), np.zeros(2))


@pytest.mark.parametrize("dim", [2, 3])
def test_a_particle_squeezed_on_a_line_steps_to_the_side(dim):
    reach, squeeze = 0.02, 1e-8
    offsets = np.zeros((2, dim))
    offsets[0, 0], offsets[1, 0] = reach - squeeze, -(reach - squeeze)
    move = free_place(offsets, np.full(2, reach))
    target = reach * (1.0 + CLEARANCE)
    side = np.sqrt(target**2 - (reach - squeeze) ** 2)  # where the two spheres cross
    assert move[0] == pytest.approx(0.0, abs=1e-15)
    assert np.linalg.norm(move) == pytest.approx(side, rel=1e-9)
    assert clear(move, offsets, reach)


def test_a_particle_squeezed_by_three_neighbours_in_3d_goes_where_the_spheres_meet():
    reach = 0.02
    angles = 2 * np.pi * np.arange(3) / 3
    ring = (reach - 1e-7) * np.c_[np.cos(angles), np.sin(angles), np.zeros(3)]
    move = free_place(ring, np.full(3, reach))
    target = reach * (1.0 + CLEARANCE)
    assert abs(move[2]) == pytest.approx(np.sqrt(target**2 - (reach - 1e-7) ** 2), rel=1e-9)
    assert np.linalg.norm(move[:2]) < 1e-15
    assert clear(move, ring, reach)


def test_a_cage_with_no_room_is_reported():
    angles = 2 * np.pi * np.arange(6) / 6
    ring = 0.9 * 0.02 * np.c_[np.cos(angles), np.sin(angles)]
    assert free_place(ring, np.full(6, 0.02)) is None
    outside = nearest_clear(ring, np.full(6, 0.02))  # beyond a neighbour, out of the cage
    assert np.linalg.norm(outside) > 0.02


@pytest.mark.parametrize("dim", [2, 3])
def test_the_place_is_the_nearest_clear_point_of_a_brute_force_search(dim):
    rng = np.random.default_rng(7 + dim)
    checked = 0
    for _ in range(40):
        m = rng.integers(2, 6)
        direction = rng.normal(size=(m, dim))
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        reach = rng.uniform(0.8, 1.2, m)
        offsets = direction * (reach * rng.uniform(0.85, 1.05, m))[:, None]
        move = nearest_clear(offsets, reach)
        # brute force: the nearest clear point among many in a ball around the particle
        points = rng.normal(size=(200_000, dim))
        points *= (rng.uniform(size=200_000) ** (1 / dim) / np.linalg.norm(points, axis=1))[
            :, None
        ] * 0.6
        ok = np.all(np.linalg.norm(points[:, None, :] - offsets[None], axis=2) >= reach, axis=1)
        if not ok.any():
            continue
        nearest = np.linalg.norm(points[ok], axis=1).min()
        assert move is not None and clear(move, offsets, reach)
        assert np.linalg.norm(move) <= nearest + 1e-12
        checked += 1
    assert checked >= 20


def every_candidate(offsets, reach):
    """The candidates of every sphere, pair and triple, clear of every neighbour, in order."""
    from itertools import combinations

    from athermal.certify.cage import _circle, _radial, _three

    dim = offsets.shape[1]
    target = reach * (1.0 + CLEARANCE)
    found = [_radial(offsets, target)]
    for j, k in combinations(range(len(reach)), 2):
        found.append(_circle(offsets[j], offsets[k], target[j], target[k], dim))
    if dim == 3:
        for j, k, m in combinations(range(len(reach)), 3):
            found.append(_three(offsets[None, [j, k, m]], target[None, [j, k, m]]))
    points = np.concatenate(found).reshape(-1, dim)
    return [p for p in points if clear(p, offsets, reach)]


@pytest.mark.parametrize("dim", [2, 3])
def test_the_candidates_left_out_are_never_the_nearest(dim):
    """Among a dozen neighbours, a few overlapping by ~1e-9 (a trial's rattlers), the place
    from the spheres near the particle is the one from every sphere, pair and triple."""
    rng = np.random.default_rng(3 + dim)
    for _ in range(30):
        m = 12
        direction = rng.normal(size=(m, dim))
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        reach = rng.uniform(0.8, 1.2, m)
        gap = np.where(rng.uniform(size=m) < 0.3, -1e-9, rng.uniform(1e-9, 1e-2, m))
        offsets = direction * (reach * (1.0 + gap))[:, None]
        every = every_candidate(offsets, reach)
        reachable = [p for p in every if reached(p, offsets, reach)]
        want = min(reachable, key=lambda p: p @ p) if reachable else None
        got = free_place(offsets, reach)
        assert (got is None) == (want is None)
        if want is not None:
            assert np.array_equal(got, want)
        nearest = nearest_clear(offsets, reach)
        assert np.array_equal(nearest, min(every, key=lambda p: p @ p))


def overlap_energy(first, second, offsets, reach, moves):
    other = np.where(second < 0, 0, second)
    sep = offsets + np.where((second < 0)[:, None], 0.0, moves[other]) - moves[first]
    over = np.maximum(reach - np.linalg.norm(sep, axis=1), 0.0)
    return float(over @ over)


def test_two_particles_squeezed_on_a_line_get_free_together():
    """F - A - B - F on a line, each pair overlapping by 1e-8: the pair zig-zags out."""
    reach, squeeze = 0.02, 1e-8
    step = reach - squeeze
    first, second = np.array([0, 0, 1]), np.array([-1, 1, -1])
    offsets = np.array([[-step, 0.0], [step, 0.0], [step, 0.0]])
    moves, clear = free_places(first, second, offsets, np.full(3, reach), 2)
    assert clear
    assert overlap_energy(first, second, offsets, np.full(3, reach), moves) == 0.0
    assert np.abs(moves).max() < 10 * np.sqrt(reach * squeeze)  # a step to the side, no jump


def test_a_pair_with_no_room_is_left_where_it_overlaps_least():
    """A and B between neighbours on every side: they bear load; the place returned is a
    minimum of their overlaps."""
    reach, squeeze = 0.02, 1e-8
    step = reach - squeeze
    first = np.array([0, 0, 0, 0, 1, 1, 1])
    second = np.array([-1, -1, -1, 1, -1, -1, -1])
    offsets = np.array(
        [
            [-step, 0.0],
            [0.0, step],
            [0.0, -step],
            [step, 0.0],
            [0.0, step],
            [0.0, -step],
            [step - 2 * squeeze, 0.0],  # pushed in further on B's right
        ]
    )
    found = free_places(first, second, offsets, np.full(7, reach), 2)
    assert found is not None
    moves, clear = found
    assert not clear
    energy = overlap_energy(first, second, offsets, np.full(7, reach), moves)
    assert 0.0 < energy < overlap_energy(first, second, offsets, np.full(7, reach), 0 * moves)
    rng = np.random.default_rng(1)
    for _ in range(20):
        nudged = moves + 1e-10 * rng.normal(size=moves.shape)
        assert overlap_energy(first, second, offsets, np.full(7, reach), nudged) >= energy


def test_a_rattler_with_no_room_is_reported_as_bearing_load():
    r = 0.05
    angles = 2 * np.pi * np.arange(6) / 6
    ring = 0.5 + (2 * r - 1e-9) * np.c_[np.cos(angles), np.sin(angles)]
    positions = np.vstack([[0.5, 0.5], ring])
    packing = at.Packing(positions, np.full(7, r), at.Cell.unit(2))
    model = at.ContactModel(2.0)
    hi, lo = positions.copy(), np.zeros_like(positions)
    rattler = np.arange(7) == 0
    _, squeezed = free_rattlers(NearPairs(packing, model, GAP_REACH), hi, lo, rattler)
    assert squeezed.tolist() == [0]
    assert np.allclose(hi[0], [0.5, 0.5], atol=1e-12)  # the middle overlaps least


def test_the_certifier_frees_a_rattler_squeezed_between_two_neighbours():
    """Pushed straight out of two opposite overlaps, a particle goes nowhere; it leaves to the
    side, where the two neighbours' exclusion circles cross."""
    r, squeeze = 0.05, 1e-9
    positions = np.array([[0.5 - 2 * r + squeeze, 0.5], [0.5, 0.5], [0.5 + 2 * r - squeeze, 0.5]])
    packing = at.Packing(positions, np.full(3, r), at.Cell.unit(2))
    model = at.ContactModel(2.0)
    pairs = NearPairs(packing, model, GAP_REACH)
    hi, lo = positions.copy(), np.zeros_like(positions)
    rattler = np.array([False, True, False])
    sums, squeezed = free_rattlers(pairs, hi, lo, rattler)
    assert not squeezed.size and not np.any(sums.overlap[0] > 0.0)
    assert np.array_equal(hi[[0, 2]], positions[[0, 2]])  # the cage held
    assert abs(hi[1, 1] - 0.5) == pytest.approx(np.sqrt(4 * r * squeeze), rel=1e-3)
