"""The sparse symmetric factorizations: CHOLMOD, and SuperLU as its fallback."""

import numpy as np
import pytest
import scipy.sparse as sp

from athermal import linalg


def laplacian_1d(n, shift):
    main = np.full(n, 2.0 + shift)
    return sp.diags([main, -np.ones(n - 1), -np.ones(n - 1)], [0, -1, 1]).tocsr()


@pytest.mark.parametrize("cholespy", [True, False])
def test_cholesky_solves_spd_matrices_and_refuses_indefinite_ones(monkeypatch, cholespy):
    if not cholespy:  # the fallback: SuperLU without pivoting, pivots tested
        monkeypatch.setattr(linalg, "available", lambda module: module != "cholespy")
    spd = laplacian_1d(50, 0.01)
    factor = linalg.cholesky(spd)
    assert factor is not None
    assert factor.backend == ("cholespy" if cholespy else "splu")
    b = np.random.default_rng(0).normal(size=(50, 2))
    np.testing.assert_allclose(spd @ factor.solve(b), b, atol=1e-10)
    assert linalg.cholesky(laplacian_1d(50, -0.5)) is None  # lowest eigenvalue ~ -0.5
