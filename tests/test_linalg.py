"""The sparse symmetric factorizations: CHOLMOD, SuperLU as its fallback, and IC(0)."""

import numpy as np
import pytest
import scipy.sparse as sp

from athermal import linalg
from athermal.errors import InputError


def laplacian_1d(n, shift):
    main = np.full(n, 2.0 + shift)
    return sp.diags([main, -np.ones(n - 1), -np.ones(n - 1)], [0, -1, 1]).tocsr()


@pytest.mark.parametrize(("cholespy", "cholmod"), [(True, True), (False, True), (True, False)])
def test_cholesky_solves_spd_matrices_and_refuses_indefinite_ones(monkeypatch, cholespy, cholmod):
    """cholespy missing, or ``cholmod=False`` (failures expected: CHOLMOD's would keep their
    memory), the fallback: SuperLU without pivoting, pivots tested."""
    if not cholespy:
        monkeypatch.setattr(linalg, "available", lambda module: module != "cholespy")
    spd = laplacian_1d(50, 0.01)
    factor = linalg.cholesky(spd, cholmod=cholmod)
    assert factor is not None
    assert factor.backend == ("cholespy" if cholespy and cholmod else "splu")
    b = np.random.default_rng(0).normal(size=(50, 2))
    np.testing.assert_allclose(spd @ factor.solve(b), b, atol=1e-10)
    assert linalg.cholesky(laplacian_1d(50, -0.5), cholmod=cholmod) is None  # lowest ~ -0.5


def laplacian_2d(side, shift):
    """The 5-point Laplacian of a periodic side x side grid plus ``shift`` I: an M-matrix."""
    one = sp.diags([np.ones(side - 1), np.ones(side - 1)], [-1, 1], shape=(side, side)).tolil()
    one[0, side - 1] = one[side - 1, 0] = 1.0
    eye = sp.identity(side)
    adjacency = sp.kron(one, eye) + sp.kron(eye, one)
    return (sp.identity(side * side) * (4.0 + shift) - adjacency).tocsr()


def test_incomplete_cholesky_is_exact_without_fill():
    """A tridiagonal matrix has a Cholesky factor with no fill: IC(0) is the exact factor."""
    spd = laplacian_1d(40, 0.05)
    factor = linalg.factorize(spd, "ic0", 1, np.ones((40, 1)))
    assert factor.backend == "ic0" and factor.shift == 0.0
    b = np.random.default_rng(1).normal(size=(40, 3))
    np.testing.assert_allclose(spd @ factor.solve(b), b, atol=1e-12)


def test_incomplete_cholesky_matches_the_matrix_on_its_pattern_and_is_spd():
    """The defining property of IC(0): L L^T equals A wherever A is non-zero (fill dropped),
    and the two triangular solves are the SPD map (L L^T)^-1."""
    a = laplacian_2d(9, 0.01)
    factor = linalg.IncompleteCholeskyFactor(a)
    n = a.shape[0]
    lower = sp.csr_matrix((factor._lower, factor._indices, factor._indptr), shape=(n, n))
    product = (lower @ lower.T).toarray()
    pattern = a.toarray() != 0.0
    np.testing.assert_allclose(product[pattern], a.toarray()[pattern], atol=1e-12)
    assert np.abs(product[~pattern]).max() > 1e-3  # the fill it leaves out is real
    u, w = np.random.default_rng(2).normal(size=(2, n, 2))
    np.testing.assert_allclose(lower @ (lower.T @ factor.solve(u)), u, atol=1e-10)
    assert np.sum(u * factor.solve(w)) == pytest.approx(np.sum(w * factor.solve(u)), rel=1e-12)
    assert np.all(np.sum(u * factor.solve(u), axis=0) > 0.0)


@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_incomplete_cholesky_solves_any_number_of_columns_as_one_at_a_time(k):
    """Columns are solved in interleaved pairs, an odd last one alone: the result is each
    column's own solve."""
    factor = linalg.IncompleteCholeskyFactor(laplacian_2d(7, 0.05))
    b = np.random.default_rng(4).normal(size=(49, k))
    together = factor.solve(b)
    for c in range(k):
        np.testing.assert_allclose(together[:, c], factor.solve(b[:, c : c + 1])[:, 0], rtol=1e-14)
    np.testing.assert_allclose(factor.solve(b[:, 0]), together[:, 0], rtol=1e-14)  # a vector


def test_incomplete_cholesky_shifts_a_matrix_whose_pivot_vanishes():
    """Kershaw's SPD matrix (no M-matrix) loses a pivot in IC(0); the factor of
    A + s diag(A) is taken instead, and an indefinite matrix is refused."""
    kershaw = np.array([[3.0, -2, 0, 2], [-2, 3, -2, 0], [0, -2, 3, -2], [2, 0, -2, 3]])
    assert np.linalg.eigvalsh(kershaw).min() > 0.17
    factor = linalg.IncompleteCholeskyFactor(sp.csr_matrix(kershaw))
    assert factor.shift > 0.0
    u = np.random.default_rng(3).normal(size=(4, 5))
    assert np.all(np.sum(u * factor.solve(u), axis=0) > 0.0)
    with pytest.raises(linalg.NotPositiveDefinite):
        linalg.IncompleteCholeskyFactor(laplacian_1d(5, -3.0))
    with pytest.raises(InputError, match="diagonal"):
        linalg.IncompleteCholeskyFactor(sp.csr_matrix(np.array([[1.0, 0.5], [0.5, 0.0]])))


def test_cg_with_a_nearby_factor_solves_in_a_few_iterations_and_finds_indefiniteness():
    """The factor of a nearby matrix (a small shift and one stiff bond apart) makes CG converge
    in a few iterations; too few iterations give None, a direction of negative curvature
    raises, and a zero right-hand side is solved by zero."""
    near = laplacian_2d(20, 1e-3)
    factor = linalg.cholesky(near)
    bond = sp.coo_matrix(([5.0, -5.0, -5.0, 5.0], ([3, 3, 4, 4], [3, 4, 3, 4])), shape=near.shape)
    matrix = (near * (1.0 + 1e-4) + bond).tocsr()
    b = np.random.default_rng(1).normal(size=near.shape[0])
    y, residual = linalg.factor_cg(matrix, b, factor, 1e-12, 8)
    assert residual <= 1e-12
    np.testing.assert_allclose(matrix @ y, b, rtol=0, atol=1e-11 * np.linalg.norm(b))
    assert linalg.factor_cg(matrix, b, factor, 1e-12, 1) is None
    with pytest.raises(linalg.NotPositiveDefinite):
        linalg.factor_cg(laplacian_2d(20, -0.05), b, factor, 1e-12, 50)
    zero, residual = linalg.factor_cg(matrix, np.zeros_like(b), factor, 1e-12, 8)
    assert residual == 0.0 and not zero.any()


def lattice_3d(side):
    """The points of a periodic simple cubic lattice of ``side^3`` sites (spacing 1) and its
    nearest-neighbour edges, each once."""
    grid = np.indices((side, side, side)).reshape(3, -1).T
    index = np.arange(side**3).reshape(side, side, side)
    first, second = [], []
    for axis in range(3):
        first.append(index.ravel())
        second.append(np.roll(index, -1, axis=axis).ravel())
    return grid.astype(float), np.concatenate(first), np.concatenate(second)


def test_the_supernodal_factor_solves_as_cholmod_does_and_refuses_indefinite_matrices():
    """cvxopt's CHOLMOD (the machine's BLAS) against cholespy's, in any row order; an
    indefinite matrix raises (``supernodal_cholesky``: None); cvxopt missing, cholespy's."""
    spd = laplacian_2d(20, 1e-3)
    b = np.random.default_rng(2).normal(size=(spd.shape[0], 3))
    expected = linalg.CholeskyFactor(spd).solve(b)
    for order in (None, np.random.default_rng(3).permutation(spd.shape[0])):
        factor = linalg.SupernodalFactor(spd, order)
        assert factor.backend == "cvxopt"
        np.testing.assert_allclose(factor.solve(b), expected, rtol=1e-9)
        np.testing.assert_allclose(factor.solve(b[:, :1]), expected[:, :1], rtol=1e-9)
    with pytest.raises(linalg.NotPositiveDefinite):
        linalg.SupernodalFactor(laplacian_2d(20, -0.05))
    assert linalg.supernodal_cholesky(laplacian_2d(20, -0.05)) is None


def test_supernodal_cholesky_without_cvxopt_is_cholespys(monkeypatch):
    monkeypatch.setattr(linalg, "available", lambda module: module != "cvxopt")
    factor = linalg.supernodal_cholesky(laplacian_1d(30, 0.01))
    assert factor is not None and factor.backend == "cholespy"


def test_nested_dissection_orders_a_periodic_lattice_with_less_fill():
    """On the Laplacian of a periodic 24^3 lattice, factored in exactly that order (CHOLMOD's
    own AMD turned off), the dissection's order fills in less than 0.4 times what the
    lexicographic order does and at most 1.2 times what AMD's does (AMD's best case: a lattice;
    on the networks of large 3D packings the dissection does better, ``docs/decisions.md``);
    each particle's coordinates come together in ``row_order``."""
    from cvxopt import cholmod

    side = 24
    points, first, second = lattice_3d(side)
    rank = linalg.dissection_order(points + 0.5, np.full(3, float(side)), first, second)
    assert np.array_equal(np.sort(rank), np.arange(side**3))
    n = side**3
    adjacency = sp.coo_matrix((np.ones(first.size), (first, second)), shape=(n, n))
    matrix = (sp.identity(n) * 6.1 - adjacency - adjacency.T).tocsr()

    def fill(order, only=True):
        saved = dict(cholmod.options)
        if only:
            cholmod.options["nmethods"] = 1  # the order given, no other
        try:
            return linalg.SupernodalFactor(matrix, order).nonzeros
        finally:
            cholmod.options.clear()
            cholmod.options.update(saved)

    dissected = fill(np.argsort(rank))
    assert dissected < 0.4 * fill(np.arange(n))
    assert dissected <= 1.2 * fill(None, only=False)
    dofs = np.array([0, 1, 2, 6, 7, 8, 9, 10, 11])  # particles 0, 2 and 3 of a 3D packing
    rows = linalg.row_order(np.array([2, 9, 0, 1]), dofs, 3)
    assert np.array_equal(dofs[rows], [6, 7, 8, 9, 10, 11, 0, 1, 2])
