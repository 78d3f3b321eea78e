import numpy as np
import pytest

from athermal.errors import InputError
from athermal.model.cell import Cell
from athermal.model.packing import Packing, bidisperse_radii, polydisperse_radii, random_packing


@pytest.mark.parametrize("dim", [2, 3])
def test_random_packing_hits_phi_and_the_bidisperse_recipe(dim):
    p = random_packing(1000, 0.6, dim=dim, seed=7)
    assert p.phi == pytest.approx(0.6, rel=1e-13)
    small, large = np.unique(p.radii)
    assert large / small == pytest.approx(1.4)
    assert np.sum(p.radii == small) == 500
    assert p.positions.dtype == np.float64 and p.positions.shape == (1000, dim)
    s = p.cell.fractional(p.positions)
    assert np.all(s >= -0.5) and np.all(s < 0.5)


def test_random_packing_is_reproducible_and_seed_dependent():
    a = random_packing(200, 0.8, seed=11)
    b = random_packing(200, 0.8, seed=11)
    c = random_packing(200, 0.8, seed=12)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.radii, b.radii)
    assert not np.array_equal(a.positions, c.positions)


def test_other_mixtures_and_polydisperse_radii():
    p = random_packing(100, 0.5, seed=1, size_ratio=2.0, large_fraction=0.3)
    assert np.sum(p.radii == p.radii.max()) == 30
    assert p.radii.max() / p.radii.min() == pytest.approx(2.0)
    rel = np.linspace(1.0, 1.5, 64)
    q = random_packing(phi=0.7, radii=rel, seed=2)
    assert q.n == 64 and q.phi == pytest.approx(0.7)
    np.testing.assert_allclose(np.sort(q.radii) / q.radii.min(), rel)
    typeid, names = q.types()
    assert len(names) == 16 and typeid.min() == 0 and typeid.max() == 15


def test_types_small_is_zero_large_is_one():
    p = random_packing(10, 0.5, seed=0)
    typeid, names = p.types()
    assert names == ["A", "B"]
    assert np.all(typeid[p.radii == p.radii.min()] == 0)
    assert np.all(typeid[p.radii == p.radii.max()] == 1)


def test_at_phi_scales_radii_only():
    p = random_packing(300, 0.8, seed=3)
    q = p.at_phi(0.85)
    assert q.phi == pytest.approx(0.85, rel=1e-13)
    assert np.array_equal(q.positions, p.positions)
    np.testing.assert_allclose(q.radii / p.radii, np.sqrt(0.85 / 0.8))


def test_spatial_order_is_a_permutation_that_groups_neighbours():
    p = random_packing(2000, 0.8, seed=5)
    shuffled = p.permuted(np.random.default_rng(0).permutation(p.n))
    order = shuffled.spatial_order()
    assert np.array_equal(np.sort(order), np.arange(p.n))
    step = lambda q: np.median(np.linalg.norm(np.diff(q.positions, axis=0), axis=1))  # noqa: E731
    assert step(shuffled.permuted(order)) < 0.2 * step(shuffled)


def test_deform_maps_positions_and_cell_together():
    p = random_packing(50, 0.5, seed=1)
    d_mat = np.array([[1.1, 0.2], [0.0, 0.9]])
    q = p.deform(d_mat)
    np.testing.assert_allclose(q.positions, p.positions @ d_mat.T)
    np.testing.assert_allclose(q.cell.h, d_mat @ p.cell.h)
    np.testing.assert_allclose(q.cell.fractional(q.positions), p.cell.fractional(p.positions))


@pytest.mark.parametrize(
    ("positions", "radii", "message"),
    [
        (np.array([[0.0, np.nan]]), np.array([0.1]), "positions: contains NaN"),
        (np.array([[0.0, np.inf]]), np.array([0.1]), "positions: contains NaN or infinite"),
        (np.zeros((2, 2)), np.array([0.1, -0.1]), "radii: must be > 0"),
        (np.zeros((2, 2)), np.array([0.1, 0.0]), "radii: must be > 0"),
        (np.zeros((2, 3)), np.array([0.1, 0.1]), "positions: expected shape"),
        (np.zeros((2, 2)), np.array([0.1]), "radii: expected shape"),
        (np.zeros((1, 2)), np.array([0.6]), "does not fit"),
        (np.zeros((0, 2)), np.zeros(0), "at least one particle"),
    ],
)
def test_bad_packings_are_rejected(positions, radii, message):
    with pytest.raises(InputError, match=message):
        Packing(positions, radii, Cell.box([1.0, 1.0]))


@pytest.mark.parametrize("phi", [1.0, 1.5, 0.0, -0.1, float("nan")])
def test_impossible_packing_fraction_is_rejected(phi):
    with pytest.raises(InputError, match="phi"):
        random_packing(10, phi)


def test_bad_mixture_arguments():
    with pytest.raises(InputError, match="size_ratio"):
        bidisperse_radii(10, size_ratio=-1.0)
    with pytest.raises(InputError, match="dim"):
        random_packing(10, 0.5, dim=4)


@pytest.mark.parametrize("kind", ["uniform", "lognormal"])
@pytest.mark.parametrize("width", [0.1, 0.3])
def test_polydisperse_radii_have_mean_one_and_the_asked_width(kind, width):
    r = polydisperse_radii(400_000, kind, width, np.random.default_rng(3))
    assert r.mean() == pytest.approx(1.0, abs=3e-3)
    assert r.std() / r.mean() == pytest.approx(width, rel=1e-2)
    if kind == "uniform":  # flat between 1 -+ sqrt(3) w
        assert r.min() >= 1.0 - np.sqrt(3.0) * width
        assert r.max() <= 1.0 + np.sqrt(3.0) * width
        counts, _ = np.histogram(r, bins=10)
        assert counts.min() > 0.97 * counts.mean()
    else:  # log r is normal with variance ln(1 + w^2)
        assert np.log(r).std() == pytest.approx(np.sqrt(np.log1p(width**2)), rel=1e-2)
        assert np.mean(np.log(r)) == pytest.approx(-np.log1p(width**2) / 2.0, abs=3e-3)


@pytest.mark.parametrize("dim", [2, 3])
def test_a_polydisperse_packing_is_seeded_and_places_particles_as_the_bidisperse_one(dim):
    kw = {"dim": dim, "seed": 11, "sizes": "lognormal", "polydispersity": 0.25}
    p, q = random_packing(500, 0.7, **kw), random_packing(500, 0.7, **kw)
    np.testing.assert_array_equal(p.positions, q.positions)
    np.testing.assert_array_equal(p.radii, q.radii)
    assert p.phi == pytest.approx(0.7, rel=1e-13)
    assert np.unique(p.radii).size == 500
    assert len(p.types()[1]) == 16  # binned types for OVITO
    other = random_packing(500, 0.7, **{**kw, "seed": 12})
    assert not np.array_equal(other.radii, p.radii)
    bi = random_packing(500, 0.7, dim=dim, seed=11)
    np.testing.assert_array_equal(bi.positions, p.positions)  # the same draws place them


@pytest.mark.parametrize(
    ("kind", "width", "message"),
    [
        ("uniform", 0.6, "uniform width must be > 0 and < 1/sqrt"),
        ("uniform", 0.0, "uniform width"),
        ("lognormal", 1.2, "lognormal width must be > 0 and <= 1"),
        ("lognormal", float("nan"), "lognormal width"),
        ("gamma", 0.2, "sizes: 'gamma' is not one of"),
    ],
)
def test_bad_size_distributions_are_refused(kind, width, message):
    with pytest.raises(InputError, match=message):
        random_packing(10, 0.5, sizes=kind, polydispersity=width)
