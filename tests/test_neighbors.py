import numpy as np
import pytest

from athermal.model.cell import Cell, isotropic, pure_shear, simple_shear
from athermal.model.neighbors import brute_force_pairs, build_neighbor_list, pair_set
from athermal.model.packing import random_packing


def deformations(dim):
    yield "none", np.eye(dim)
    yield "shear 0.3", simple_shear(0.3, dim)
    yield "shear past one box", simple_shear(1.35, dim)
    yield "shear -2.6", simple_shear(-2.6, dim)
    yield "pure shear", pure_shear(0.2, dim)
    yield "compressed", isotropic(0.9, dim) @ simple_shear(0.4, dim)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", range(6))
def test_cell_list_equals_brute_force(dim, seed):
    base = random_packing(150 if dim == 2 else 120, 0.75 if dim == 2 else 0.5, dim=dim, seed=seed)
    rng = np.random.default_rng(seed)
    for name, d_mat in deformations(dim):
        p = base.deform(d_mat)
        skin = rng.uniform(0.0, 1.0) * p.radii.mean()
        nl = build_neighbor_list(p.positions, p.radii, p.cell, skin)
        assert pair_set(nl) == brute_force_pairs(p.positions, p.radii, p.cell, skin), name
        assert np.all(nl.second >= nl.first)


@pytest.mark.parametrize("dim", [2, 3])
def test_unwrapped_positions_give_the_same_physical_pairs(dim):
    p = random_packing(200, 0.7, dim=dim, seed=9).deform(simple_shear(0.7, dim))
    jumps = np.random.default_rng(1).integers(-2, 3, size=(p.n, dim)).astype(float)
    moved = p.positions + jumps @ p.cell.h.T
    a = build_neighbor_list(p.positions, p.radii, p.cell, 0.01)
    b = build_neighbor_list(moved, p.radii, p.cell, 0.01)
    assert pair_set(b) == brute_force_pairs(moved, p.radii, p.cell, 0.01)

    def key(nl, x):
        sep = nl.separations(x, p.cell)
        return sorted(
            zip(nl.first.tolist(), nl.second.tolist(), np.round(sep, 12).tolist(), strict=True)
        )

    assert key(a, p.positions) == key(b, moved)


@pytest.mark.parametrize("dim", [2, 3])
def test_large_skin_grows_the_pair_buffers_and_resumes(dim):
    p = random_packing(300, 0.8 if dim == 2 else 0.55, dim=dim, seed=8)
    skin = 2.5 * p.radii.mean()
    nl = build_neighbor_list(p.positions, p.radii, p.cell, skin)
    assert nl.n_pairs > (4 if dim == 2 else 7) * p.n  # more than the first buffer holds
    assert pair_set(nl) == brute_force_pairs(p.positions, p.radii, p.cell, skin)


def test_tiny_cell_finds_every_periodic_image():
    cell = Cell(np.array([[0.5, 0.2], [0.0, 0.45]]))
    x = np.array([[0.0, 0.0], [0.1, 0.2]])
    r = np.array([0.2, 0.2])
    skin = 0.3
    nl = build_neighbor_list(x, r, cell, skin)
    expect = brute_force_pairs(x, r, cell, skin)
    assert pair_set(nl) == expect
    assert any(i == j for i, j, _ in expect)  # a particle sees its own images
    assert len({n for i, j, n in expect if (i, j) == (0, 1)}) > 1


def test_rebuild_rule_on_maximal_displacement():
    p = random_packing(100, 0.6, seed=2)
    nl = build_neighbor_list(p.positions, p.radii, p.cell, skin=0.02)
    x = np.array(p.positions)
    x[5, 0] += 0.0099
    assert nl.is_current(x)
    x[5, 0] += 0.0002
    assert not nl.is_current(x)
    assert not nl.is_current(np.asfortranarray(x))  # any memory layout


def test_list_built_with_skin_stays_complete_within_half_skin():
    p = random_packing(400, 0.8, seed=4)
    skin = 0.2 * p.radii.mean()
    nl = build_neighbor_list(p.positions, p.radii, p.cell, skin)
    rng = np.random.default_rng(0)
    step = rng.normal(size=p.positions.shape)
    step *= 0.499 * skin / np.linalg.norm(step, axis=1).max()
    moved = p.positions + step
    assert nl.is_current(moved)
    listed = {(i, j, n) for i, j, n in pair_set(nl)}
    touching = brute_force_pairs(moved, p.radii, p.cell, 0.0)
    assert touching <= listed


@pytest.mark.parametrize("dim", [1, 2, 3, 4])
@pytest.mark.parametrize("rows", [1, 3, 4, 9, 1027])
def test_row_maxima_match_numpy(dim, rows):
    """The compiled row maxima (four rows at a time, 2D and 3D specialized) against numpy, for
    row counts that leave every remainder of four."""
    from athermal import _blocks
    from athermal.model.objective import _place_trial

    rng = np.random.default_rng(rows * dim)
    x, direction = rng.normal(size=(2, rows * dim))
    reference = rng.normal(size=(rows, dim))
    flat = x.reshape(rows, dim)
    assert _blocks.max_row_norm(x, dim) == pytest.approx(np.linalg.norm(flat, axis=1).max())
    moved = ((flat - reference) ** 2).sum(axis=1).max()
    assert _blocks.max_displacement_sq(flat, reference) == pytest.approx(moved)
    moved = ((flat + 0.3 * direction.reshape(rows, dim) - reference) ** 2).sum(axis=1).max()
    trial = np.empty_like(x)
    assert _place_trial(x, direction, 0.3, reference, trial) == pytest.approx(moved)
    assert _blocks.step_limit(0.5, x, dim) == pytest.approx(
        0.5 / np.linalg.norm(flat, axis=1).max()
    )
    # the search writes the point numpy computes (no fused multiply-add) and its reach test
    # sees that very point, so that the compiled and the Python reach tests agree to the bit
    for a in rng.uniform(0.0, 2.0, 50):
        point = x + a * direction
        reach = _place_trial(x, direction, a, reference, trial)
        assert np.array_equal(trial, point)
        assert reach == _blocks.max_displacement_sq(point.reshape(rows, dim), reference)


@pytest.mark.parametrize("dim, walls", [(2, ()), (3, ()), (2, (1,)), (3, (2,))])
def test_the_threaded_search_lists_the_same_pairs_in_the_same_order(monkeypatch, dim, walls):
    """Above ``PARALLEL_BUILD`` the search runs chunk by chunk on the threads; the list, its
    order and its slabs are those of the one-thread search, also when chunks overflow their
    part of the buffer and are searched again (forced here by a tiny first capacity)."""
    import athermal.model.neighbors as neighbors

    cell = Cell(np.eye(dim), walls)
    p = random_packing(6000 if dim == 2 else 4000, 0.86 if dim == 2 else 0.64, dim=dim, seed=2,
                       cell=cell)  # fmt: skip
    serial = build_neighbor_list(p.positions, p.radii, p.cell)
    monkeypatch.setattr(neighbors, "PARALLEL_BUILD", 0)
    monkeypatch.setattr(neighbors, "threads_usable", lambda: True)
    searched = []
    chunked = neighbors.collect_chunks

    def spy(*args):
        searched.append(args[-1].size - 1)
        return chunked(*args)

    monkeypatch.setattr(neighbors, "collect_chunks", spy)
    for per_particle in (neighbors.PAIRS_PER_PARTICLE[dim], 0.5):
        monkeypatch.setitem(neighbors.PAIRS_PER_PARTICLE, dim, per_particle)
        threaded = build_neighbor_list(p.positions, p.radii, p.cell)
        for name in ("first", "second", "code", "slabs", "images"):
            np.testing.assert_array_equal(getattr(threaded, name), getattr(serial, name))
    assert len(searched) == 2 and min(searched) >= 2  # chunks searched on the threads
