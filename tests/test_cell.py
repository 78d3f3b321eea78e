from itertools import product

import numpy as np
import pytest

from athermal.errors import InputError
from athermal.model.cell import Cell, isotropic, pure_shear, simple_shear


def tilted(dim: int, tilt: float) -> Cell:
    return Cell.box(np.ones(dim)).deform(simple_shear(tilt, dim))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("tilt", [0.0, 0.3, 1.2, -2.7])
def test_wrap_puts_fractional_coordinates_in_half_open_unit_interval(dim, tilt):
    cell = tilted(dim, tilt)
    x = np.random.default_rng(1).normal(scale=3.0, size=(500, dim))
    s = cell.fractional(cell.wrap(x))
    assert np.all(s >= -0.5) and np.all(s < 0.5)
    # wrapping moves by whole lattice vectors only
    n = cell.fractional(x - cell.wrap(x))
    np.testing.assert_allclose(n, np.round(n), atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("tilt", [0.0, 0.45, 1.3, 3.9])
def test_minimum_image_against_exhaustive_search(dim, tilt):
    cell = tilted(dim, tilt)
    dx = np.random.default_rng(2).uniform(-4, 4, size=(300, dim))
    got = cell.minimum_image(dx)
    # |dx| <= 4 with tilts up to 4 along x: x images up to +-30 cover every candidate
    ranges = [range(-30, 31)] + [range(-8, 9)] * (dim - 1)
    images = np.array(list(product(*ranges)), dtype=float) @ cell.h.T
    cand = dx[:, None, :] + images[None, :, :]
    best = np.min(np.linalg.norm(cand, axis=2), axis=1)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), best, rtol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_reduced_cell_is_the_same_lattice_with_small_tilts(dim):
    h = np.triu(np.random.default_rng(3).uniform(-3, 3, size=(dim, dim)), 1) + np.eye(dim)
    cell = Cell(h)
    red = cell.reduced()
    unimodular = np.linalg.solve(cell.h, red.h)
    np.testing.assert_allclose(unimodular, np.round(unimodular), atol=1e-12)
    assert abs(round(np.linalg.det(unimodular))) == 1
    for col in range(1, dim):
        for row in range(col):
            assert abs(red.h[row, col]) <= 0.5 * red.h[row, row] + 1e-12


def test_deformations_match_the_seed():
    cell = Cell.box([1.0, 1.0])
    np.testing.assert_array_equal(cell.deform(simple_shear(0.1)).h, [[1.0, 0.1], [0.0, 1.0]])
    sheared = cell.deform(pure_shear(0.25))
    np.testing.assert_allclose(sheared.h, [[1.25, 0.0], [0.0, 0.8]])
    assert sheared.volume == pytest.approx(1.0, rel=1e-15)
    assert cell.deform(isotropic(0.5)).volume == pytest.approx(0.25)


@pytest.mark.parametrize("dim", [2, 3])
def test_hoomd_box_round_trip(dim):
    h = np.triu(np.random.default_rng(4).uniform(-1, 1, size=(dim, dim)), 1) + np.diag(
        np.arange(1.0, dim + 1)
    )
    cell = Cell(h)
    back = Cell.from_hoomd(cell.to_hoomd(), dim)
    np.testing.assert_allclose(back.h, cell.h, rtol=1e-15, atol=1e-15)


def test_volume_widths_and_packing_fraction():
    cell = Cell(np.array([[2.0, 1.0], [0.0, 1.0]]))
    assert cell.volume == 2.0
    np.testing.assert_allclose(cell.widths, [2.0 / np.sqrt(2.0), 1.0])
    assert cell.packing_fraction(np.array([0.1, 0.2])) == pytest.approx(np.pi * 0.05 / 2.0)
    cube = Cell.box([1.0, 1.0, 1.0])
    assert cube.packing_fraction(np.array([0.5])) == pytest.approx(np.pi / 6.0)


@pytest.mark.parametrize(
    ("h", "message"),
    [
        (np.zeros((2, 2)), "singular"),
        (np.array([[1.0, 0.0], [0.2, 1.0]]), "upper triangular"),
        (np.array([[1.0, np.nan], [0.0, 1.0]]), "NaN"),
        (np.eye(4), "2x2 or 3x3"),
        (np.array([[-1.0, 0.0], [0.0, 1.0]]), "singular or inverted"),
    ],
)
def test_bad_cells_are_rejected_with_a_clear_message(h, message):
    with pytest.raises(InputError, match=message):
        Cell(h)


def test_cell_is_immutable():
    cell = Cell.box([1.0, 1.0])
    with pytest.raises(ValueError):
        cell.h[0, 0] = 2.0


@pytest.mark.parametrize(
    "h", [[[1.0, 7.0], [0.0, 1.0]], [[1.0, -3.0, 2.0], [0.0, 1.0, 5.0], [0.0, 0.0, 1.0]]]
)
def test_narrowest_width_is_the_lattice_s_whatever_its_basis(h):
    """A sheared copy of the unit cell (the same lattice) is as wide as the unit cell, though
    the faces of its ``h`` lie closer: a particle that fits one fits the other."""
    from athermal.model.packing import Packing

    sheared = Cell(np.array(h))
    assert sheared.widths.min() < 0.2
    assert sheared.narrowest_width == pytest.approx(1.0, abs=1e-15)
    Packing(np.zeros((1, sheared.dim)), np.array([0.45]), sheared)  # diameter 0.9 fits
    with pytest.raises(InputError, match="does not fit in the cell"):
        Packing(np.zeros((1, sheared.dim)), np.array([0.5]), sheared)
