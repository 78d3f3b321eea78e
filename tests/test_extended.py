"""Double-double arithmetic and the contact sums in it, against Python's decimal at 60 digits (an
independent implementation: exact conversion of each float64, correctly rounded operations)."""

from decimal import Decimal

import numba
import numpy as np
import pytest

from athermal import _double as dd
from athermal.certify import extended
from athermal.errors import InputError
from athermal.model.cell import Cell
from athermal.model.contact import ContactModel
from athermal.model.law import PowerContact
from athermal.model.neighbors import build_neighbor_list
from athermal.model.packing import Packing, random_packing
from decimal_reference import decimal_sums, exact


def pair(value: Decimal) -> tuple[float, float]:
    """``value`` rounded to a double-double."""
    hi = float(value)
    return hi, float(value - Decimal(hi))


@numba.njit
def operations(ah, al, bh, bl):
    return (
        dd.add(ah, al, bh, bl),
        dd.mul(ah, al, bh, bl),
        dd.div(ah, al, bh, bl),
        dd.sqrt(abs(ah), al if ah > 0 else -al),
    )


def test_the_operations_are_accurate_to_double_double():
    rng = np.random.default_rng(7)
    worst = np.zeros(4)
    for _ in range(2000):
        a = Decimal(rng.uniform(-1, 1)) * Decimal(10) ** int(rng.integers(-12, 4))
        b = Decimal(rng.uniform(0.1, 1)) * Decimal(10) ** int(rng.integers(-12, 4))
        a *= 1 + Decimal(rng.uniform(-1, 1)) * Decimal(2) ** -70  # bits beyond float64
        b *= 1 + Decimal(rng.uniform(-1, 1)) * Decimal(2) ** -70
        (ah, al), (bh, bl) = pair(a), pair(b)
        a, b = exact(ah, al), exact(bh, bl)
        results = operations(ah, al, bh, bl)
        truths = (a + b, a * b, a / b, abs(a).sqrt())
        for k, ((h, low), truth) in enumerate(zip(results, truths, strict=True)):
            scale = abs(truth) if k else max(abs(a), abs(b))  # a sum: relative to its terms
            worst[k] = max(worst[k], float(abs(exact(h, low) - truth) / scale))
    assert np.all(worst < 1e-31), worst


@numba.njit
def products(a, b):
    return dd.two_prod(a, b), dd.two_sum(a, b)


def test_two_prod_and_two_sum_are_exact():
    rng = np.random.default_rng(3)
    for a, b in rng.uniform(-1e3, 1e3, size=(500, 2)):
        (p, e), (s, f) = products(a, b)
        assert exact(p, e) == Decimal(a) * Decimal(b)
        assert exact(s, f) == Decimal(a) + Decimal(b)


@pytest.mark.parametrize(("dim", "alpha"), [(2, 2.0), (2, 2.5), (3, 2.0), (3, 3.0)])
def test_contact_sums_match_decimal_arithmetic(dim, alpha):
    packing = random_packing(24, 0.9 if dim == 2 else 0.7, dim=dim, seed=5)
    tilt = np.eye(dim)
    tilt[0, 1] = 0.3  # a sheared cell: images with a tilt component
    packing = Packing(packing.positions @ tilt.T, packing.radii, Cell(packing.cell.h @ tilt))
    model = ContactModel(alpha)
    nlist = build_neighbor_list(packing.positions, packing.radii, packing.cell, skin=0.05)
    first, second = nlist.first.astype(np.int64), nlist.second.astype(np.int64)
    images = np.ascontiguousarray(nlist.images[nlist.code])
    k = np.ones(first.size)
    rng = np.random.default_rng(11)
    xh = packing.positions.copy()
    xl = rng.uniform(-1, 1, xh.shape) * np.spacing(np.abs(xh)) / 4  # low parts that matter
    p, n = first.size, packing.n
    overlap = (np.empty(p), np.empty(p))
    grad = (np.empty((n, dim)), np.empty((n, dim)))
    virial = (np.empty((dim, dim)), np.empty((dim, dim)))
    h = np.ascontiguousarray(packing.cell.h)
    energy = extended.contact_sums(
        xh, xl, packing.radii, first, second, images, h, k, np.zeros(first.size, dtype=bool),
        PowerContact(alpha).half_steps(), alpha,
        *overlap, *grad, *virial,
    )  # fmt: skip
    truth = decimal_sums(xh, xl, packing.radii, h, first, second, images, k, model.alpha)
    touching = [o for o in truth[0] if o > 0]
    assert len(touching) >= 10
    force_scale = max(touching) ** Decimal(alpha - 1)
    for q in range(p):
        assert abs(exact(overlap[0][q], overlap[1][q]) - truth[0][q]) < Decimal("1e-30")
    for i in range(n):
        for a in range(dim):
            error = abs(exact(grad[0][i, a], grad[1][i, a]) - truth[1][i][a])
            assert error < Decimal("1e-29") * force_scale
    for a in range(dim):
        for b in range(dim):
            error = abs(exact(virial[0][a, b], virial[1][a, b]) - truth[2][a][b])
            assert error < Decimal("1e-29") * force_scale
    assert abs(exact(*energy) - truth[3]) < Decimal("1e-28") * truth[3]


def test_only_half_integer_powers_are_taken():
    assert [PowerContact(a).half_steps() for a in (2.0, 2.5, 3.0)] == [2, 3, 4]
    with pytest.raises(InputError, match="alpha"):
        PowerContact(2.2).half_steps()


def test_displace_adds_in_double_double():
    xh, xl = np.array([[1.0, 0.5]]), np.zeros((1, 2))
    extended.displace(xh, xl, np.array([[1e-20, -3e-25]]))
    np.testing.assert_array_equal(xh, [[1.0, 0.5]])
    np.testing.assert_array_equal(xl, [[1e-20, -3e-25]])


def test_a_bonded_pair_apart_pulls_as_a_spring():
    """Two disks ~1e-9 apart in a large cell: bonded, the pair is a spring of rest length
    r_i + r_j in tension (force k delta along the branch, delta < 0); not bonded, nothing."""
    xh = np.array([[0.0, 0.0], [1.0 + 1e-9, 0.0]])
    xl = np.zeros_like(xh)
    radii, h = np.array([0.5, 0.5]), 10.0 * np.eye(2)
    pair = (np.array([0]), np.array([1]), np.zeros((1, 2)), h, np.array([2.0]))
    gap = Decimal(xh[1, 0]) - 1  # exactly
    for bonded in (True, False):
        overlap = (np.empty(1), np.empty(1))
        grad = (np.empty((2, 2)), np.empty((2, 2)))
        virial = (np.empty((2, 2)), np.empty((2, 2)))
        energy = extended.contact_sums(
            xh, xl, radii, *pair, np.array([bonded]), 2, 2.0, *overlap, *grad, *virial
        )
        assert abs(exact(overlap[0][0], overlap[1][0]) + gap) < Decimal("1e-30")
        if bonded:  # dE/dx_i = -f_i = -k delta n with n = -e_x, delta = -gap: -2 gap
            assert exact(grad[0][0, 0], grad[1][0, 0]) == pytest.approx(-2 * gap, rel=1e-25)
            assert grad[0][1, 0] == -grad[0][0, 0]
            assert exact(*energy) == pytest.approx(gap * gap, rel=1e-25)
        else:
            assert not grad[0].any() and exact(*energy) == 0
