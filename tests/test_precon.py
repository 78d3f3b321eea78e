import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import athermal.linalg as linalg
from athermal.engines.precon import (
    ContactPreconditioner,
    ExpPreconditioner,
    make_preconditioner,
    sine_perturbation,
)
from athermal.errors import InputError
from athermal.model.cell import Cell, simple_shear
from athermal.model.contact import ContactModel, find_contacts, hessian
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing

# overlapped random packings (N, phi) with contacts everywhere, small enough for dense algebra
SYSTEMS = {2: (96, 0.9), 3: (96, 0.7)}
KINDS = [ExpPreconditioner, ContactPreconditioner]


def objective(dim: int, *, alpha: float = 2.0, stiffness: float = 1.0, seed: int = 0, cell=None):
    n, phi = SYSTEMS[dim]
    packing = random_packing(n, phi, dim=dim, seed=seed, cell=cell)
    return Objective(packing, ContactModel(alpha=alpha, stiffness=stiffness))


def rng_vector(obj: Objective, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal(obj.n_dof)


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def brute_force_exp(obj: Objective, x: np.ndarray, r_cut: float, A: float, c_stab: float):
    """Dense ``P_{mu=1}`` (N, N) and r_nn from all minimum-image pairs, O(N^2)."""
    pos = x.reshape(obj.n, obj.dim)
    i, j = np.triu_indices(obj.n, 1)
    dist = np.linalg.norm(obj.cell.minimum_image(pos[i] - pos[j]), axis=1)
    close = dist < r_cut
    i, j, dist = i[close], j[close], dist[close]
    nearest = np.full(obj.n, np.inf)
    for a, b, r in zip(i, j, dist, strict=True):
        nearest[a] = min(nearest[a], r)
        nearest[b] = min(nearest[b], r)
    r_nn = nearest[np.isfinite(nearest)].mean()
    lap = np.zeros((obj.n, obj.n))
    for a, b, r in zip(i, j, dist, strict=True):
        c = np.exp(-A * (r / r_nn - 1.0))
        lap[a, b] -= c
        lap[b, a] -= c
        lap[a, a] += c
        lap[b, b] += c
    return lap + c_stab * np.eye(obj.n), r_nn


def positive_contact_stiffness(obj: Objective, x: np.ndarray) -> np.ndarray:
    """Dense K_+ (N d, N d), block by block: k (alpha - 1) delta^(alpha-2) n n^T per contact."""
    d = obj.dim
    contacts = find_contacts(obj.packing(x, internal=True), obj.model)
    k = np.zeros((obj.n_dof, obj.n_dof))
    for c in range(contacts.i.size):
        a, b = contacts.i[c], contacts.j[c]
        nvec = contacts.normal[c]
        block = (
            contacts.stiffness[c]
            * (contacts.alpha - 1.0)
            * contacts.overlap[c] ** (contacts.alpha - 2.0)
            * np.outer(nvec, nvec)
        )
        sa, sb = slice(a * d, a * d + d), slice(b * d, b * d + d)
        k[sa, sa] += block
        k[sb, sb] += block
        k[sa, sb] -= block
        k[sb, sa] -= block
    return k


# --- the Exp matrix ---------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("shear", [0.0, 0.3])
def test_exp_matrix_matches_brute_force_pairs_across_images(dim, shear):
    cell = Cell(simple_shear(shear, dim))
    obj = objective(dim, cell=cell, seed=4)
    pre = ExpPreconditioner(obj, A=3.0, solver="direct")
    x = obj.x0 + 0.3 * np.sin(np.arange(obj.n_dof))  # unwrapped positions
    pre.update(x)
    dense, r_nn = brute_force_exp(obj, x, pre.r_cut, 3.0, 0.1)
    assert pre.r_nn == pytest.approx(r_nn, rel=1e-12)
    np.testing.assert_allclose(pre.matrix.toarray(), pre.mu * dense, rtol=1e-12, atol=1e-14)
    # the matrix really couples pairs across the periodic boundary
    pos = obj.cell.fractional(x.reshape(obj.n, dim))
    i, j = pre.matrix.nonzero()
    assert np.any(np.abs(np.round(pos[i] - pos[j])).sum(axis=1) > 0)


@pytest.mark.parametrize("dim", [2, 3])
def test_exp_is_spd_with_kron_structure(dim):
    obj = objective(dim)
    pre = ExpPreconditioner(obj, A=3.0, solver="direct")
    pre.update(obj.x0)
    lap = pre.matrix.toarray()
    np.testing.assert_array_equal(lap, lap.T)
    np.testing.assert_allclose(lap.sum(axis=1), pre.mu * pre.c_stab, rtol=1e-10)
    full = np.kron(lap, np.eye(dim))
    assert np.linalg.eigvalsh(full).min() > 0.5 * pre.mu * pre.c_stab
    v = rng_vector(obj, 1)
    np.testing.assert_allclose(pre.dot(v), full @ v, rtol=1e-12, atol=1e-14)


def test_weights_depend_on_A():
    obj = objective(2)
    flat = ExpPreconditioner(obj, A=0.0, mu=1.0)
    steep = ExpPreconditioner(obj, A=3.0, mu=1.0)
    flat.update(obj.x0)
    steep.update(obj.x0)
    off_flat = flat.matrix.toarray()[~np.eye(obj.n, dtype=bool)]
    off_steep = steep.matrix.toarray()[~np.eye(obj.n, dtype=bool)]
    assert set(np.unique(off_flat)) == {-1.0, 0.0}  # the paper's stabilized adjacency matrix
    np.testing.assert_array_equal(off_flat != 0.0, off_steep != 0.0)
    assert np.ptp(off_steep[off_steep != 0.0]) > 1.0  # near pairs weigh more than far ones
    v = rng_vector(obj, 2)
    assert rel(flat.dot(v), steep.dot(v)) > 0.1


# --- solvers -----------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kind", KINDS)
def test_direct_solve_inverts_dot(dim, kind):
    obj = objective(dim, alpha=2.5)
    pre = kind(obj, A=3.0, solver="direct")
    pre.update(obj.x0)
    v = rng_vector(obj, 3)
    assert rel(pre.solve(pre.dot(v)), v) < 1e-10
    assert rel(pre.dot(pre.solve(v)), v) < 1e-10


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kind", KINDS)
def test_cholespy_result_equals_spsolve(dim, kind):
    """Would fail if the upper triangle (or anything but P) reached cholespy."""
    pytest.importorskip("cholespy")
    obj = objective(dim, alpha=2.5, seed=5)
    pre = kind(obj, A=3.0, solver="direct")
    pre.update(obj.x0)
    assert pre.backend == "cholespy"
    full = pre.matrix if kind is ContactPreconditioner else sp.kron(pre.matrix, sp.eye(dim))
    g = rng_vector(obj, 4)
    expected = spla.spsolve(sp.csc_matrix(full), g)
    assert rel(pre.solve(g), expected) < 1e-10


def test_cholespy_upper_triangle_pitfall_is_real():
    """cholespy silently reads only the lower triangle: the upper one gives a wrong answer."""
    cholespy = pytest.importorskip("cholespy")
    obj = objective(2)
    pre = ExpPreconditioner(obj, A=3.0, solver="direct")
    pre.update(obj.x0)
    q = rng_vector(obj, 5).reshape(obj.n, 2)
    expected = spla.spsolve(sp.csc_matrix(pre.matrix), q)
    results = {}
    for name, tri in (("lower", sp.tril(pre.matrix)), ("upper", sp.triu(pre.matrix))):
        coo = sp.coo_matrix(tri)
        solver = cholespy.CholeskySolverD(
            obj.n,
            coo.row.astype(np.int32),
            coo.col.astype(np.int32),
            coo.data.astype(np.float64),
            cholespy.MatrixType.COO,
        )
        out = np.empty_like(q)
        solver.solve(np.ascontiguousarray(q), out)
        results[name] = rel(out, expected)
    assert results["lower"] < 1e-10
    assert results["upper"] > 1e-2


@pytest.mark.parametrize("kind", KINDS)
def test_splu_fallback_without_cholespy(kind, monkeypatch):
    obj = objective(2, seed=6)
    reference = kind(obj, A=3.0, mu=0.7, solver="direct")
    reference.update(obj.x0)
    real_available = linalg.available
    monkeypatch.setattr(linalg, "available", lambda m: m != "cholespy" and real_available(m))
    pre = kind(obj, A=3.0, mu=0.7, solver="direct")
    pre.update(obj.x0)
    assert pre.backend == "splu"
    g = rng_vector(obj, 6)
    assert rel(pre.solve(g), reference.solve(g)) < 1e-10


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("cycles", [1, 3])
def test_amg_is_a_fixed_spd_linear_operator_that_reduces_the_residual(dim, kind, cycles):
    pytest.importorskip("pyamg")
    obj = objective(dim, seed=7)
    pre = kind(obj, A=3.0, solver="amg", amg_cycles=cycles)
    pre.update(obj.x0)
    assert pre.backend == "pyamg"
    u, w = rng_vector(obj, 7), rng_vector(obj, 8)
    a, b = 1.7, -0.4
    combined = pre.solve(a * u + b * w)
    assert rel(combined, a * pre.solve(u) + b * pre.solve(w)) < 1e-10
    assert u @ pre.solve(w) == pytest.approx(w @ pre.solve(u), rel=1e-10)
    assert u @ pre.solve(u) > 0.0
    residual = rel(pre.dot(pre.solve(u)), u)
    assert residual < 0.5
    if cycles > 1:  # each further V-cycle reduces the residual again
        single = kind(obj, A=3.0, solver="amg", amg_cycles=1)
        single.update(obj.x0)
        assert residual < 0.7 * rel(single.dot(single.solve(u)), u)
    # not an exact solve: the number of V-cycles is fixed, the result is approximate
    assert residual > 1e-8


def test_auto_solver_threshold():
    obj = objective(2)
    assert ExpPreconditioner(obj, solver="auto").solver == "ic0"  # an M-matrix
    assert ContactPreconditioner(obj, solver="auto").solver == "direct"  # none
    assert linalg.AUTO_DIRECT_MAX_N == 200_000 and linalg.AUTO_DIRECT_MAX_N_2D == 2_000_000
    assert linalg.AUTO_IC0_MAX_N == 200_000
    for dim in (2, 3):
        assert linalg.resolve_solver("auto", 199_999, dim, m_matrix=True) == "ic0"
        assert linalg.resolve_solver("auto", 199_999, dim) == "direct"
    assert linalg.resolve_solver("auto", 1_048_576, 2, m_matrix=True) == "direct"
    assert linalg.resolve_solver("auto", 262_144, 3, m_matrix=True) == "amg"


# --- rebuild rule and reuse ---------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_factorization_is_reused_and_rebuild_follows_displacement(kind):
    obj = objective(2)
    pre = kind(obj, solver="direct")
    with pytest.raises(RuntimeError, match="update"):
        pre.solve(obj.x0)
    pre.update(obj.x0)
    for s in range(10):
        pre.solve(rng_vector(obj, s))
    assert (pre.n_builds, pre.n_factorizations, pre.n_solves) == (1, 1, 10)
    pre.update(obj.x0 + 1e-9)
    assert pre.n_builds == 1
    x = obj.x0.copy()
    x[0] += 0.24 * pre.r_cut  # one particle, below the threshold
    pre.update(x)
    assert pre.n_builds == 1
    x[0] += 0.02 * pre.r_cut  # now past r_cut / 4 since the build
    pre.update(x)
    assert (pre.n_builds, pre.n_factorizations) == (2, 2)
    x[1] += 0.2 * pre.r_cut  # measured from the new reference
    pre.update(x)
    assert pre.n_builds == 2
    with pytest.raises(InputError, match="shape"):
        pre.solve(np.zeros(3))
    with pytest.raises(InputError, match="shape"):
        pre.update(np.zeros(3))


def test_contact_preconditioner_rebuilds_when_contact_number_changes():
    # a 4 x 4 square lattice of touching disks: 32 contacts of overlap 2e-4
    grid = (np.stack(np.meshgrid(np.arange(4), np.arange(4)), axis=-1).reshape(-1, 2) + 0.5) / 4
    packing = Packing(grid - 0.5, np.full(16, 0.1251), Cell.box([1.0, 1.0]))
    obj = Objective(packing, ContactModel())
    exp_pre = ExpPreconditioner(obj, solver="direct")
    pre = ContactPreconditioner(obj, solver="direct")
    for p in (exp_pre, pre):
        p.update(obj.x0)
    assert pre.n_contacts == 32
    # every other column moves by 1e-3 along x: 8 of the 16 x-contacts open (25 % change)
    shift = np.zeros_like(grid)
    shift[np.isin(np.round(grid[:, 0] * 4 - 0.5), (0, 2)), 0] = 1e-3
    x = (grid - 0.5 + shift)[obj.order].ravel()
    assert pre.count_contacts(x.reshape(16, 2)) == 24
    pre.update(x)
    exp_pre.update(x)
    assert exp_pre.n_builds == 1  # displacement rule only
    assert pre.n_builds == 2
    assert pre.n_contacts == 24
    # 2 more y-contacts open (8 % of 24): below the 10 % rule, no rebuild
    x2 = x.reshape(16, 2).copy()
    x2[np.argsort(obj.order)[[1, 9]], 1] += 1e-3
    assert pre.count_contacts(x2) == 22
    pre.update(x2.ravel())
    assert pre.n_builds == 2


# --- energy scale mu ----------------------------------------------------------------------------


@pytest.mark.parametrize(("dim", "seed"), [(2, 0), (3, 1)])
def test_mu_from_sine_test_matches_the_exact_hessian(dim, seed):
    obj = objective(dim, seed=seed)
    pre = ExpPreconditioner(obj, solver="direct")
    obj(obj.x0)
    before = obj.n_evaluations
    pre.update(obj.x0)
    assert obj.n_evaluations - before == 1  # grad E(x) was cached: only grad E(x + v) is new
    v = sine_perturbation(obj.x0.reshape(obj.n, dim), obj, pre.r_cut).ravel()
    assert np.abs(v).max() == pytest.approx(1e-3 * pre.r_cut, rel=1e-2)
    packing = obj.packing(obj.x0, internal=True)
    contacts = find_contacts(packing, obj.model)
    moved = find_contacts(packing.with_positions(packing.positions + v.reshape(-1, dim)), obj.model)
    assert set(zip(contacts.i, contacts.j, strict=True)) == set(
        zip(moved.i, moved.j, strict=True)
    )  # precondition: no contact opens or closes under v, so the harmonic Hessian is exact
    assert np.isfinite(pre.mu)
    assert 1e-2 < pre.mu < 10.0  # k = 1: of the order of the contact stiffness
    vpv = v @ pre.dot(v)  # = mu v^T P_{mu=1} v
    secant = v @ (obj(obj.x0 + v)[1] - obj(obj.x0)[1])
    assert vpv == pytest.approx(secant, rel=1e-10)  # the definition
    vhv = v @ (hessian(contacts, obj.n) @ v)
    assert vpv == pytest.approx(vhv, rel=1e-3)


def test_mu_scales_with_stiffness_and_can_be_given():
    soft, stiff = objective(2), objective(2, stiffness=7.0)
    a, b = ExpPreconditioner(soft), ExpPreconditioner(stiff)
    a.update(soft.x0)
    b.update(stiff.x0)
    assert b.mu == pytest.approx(7.0 * a.mu, rel=1e-10)
    fixed = ExpPreconditioner(stiff, mu=3.0)
    before = stiff.n_evaluations
    fixed.update(stiff.x0)
    assert fixed.mu == 3.0
    assert stiff.n_evaluations == before


def test_mu_falls_back_without_contacts():
    packing = random_packing(16, 0.5, seed=3)
    grid = (np.stack(np.meshgrid(np.arange(4), np.arange(4)), axis=-1).reshape(-1, 2) + 0.5) / 4
    free = Objective(packing.with_positions(grid - 0.5), ContactModel(stiffness=2.5))
    assert free(free.x0)[0] == 0.0
    pre = ExpPreconditioner(free, solver="direct")
    pre.update(free.x0)
    assert pre.mu == 2.5  # first build: the contact stiffness
    assert rel(pre.solve(pre.dot(free.x0)), free.x0) < 1e-10
    # estimated on an overlapped start, then kept when the contacts are gone
    obj = Objective(packing, ContactModel(stiffness=2.5))
    pre = ExpPreconditioner(obj)
    pre.update(obj.x0)
    first = pre.mu
    assert first != 2.5
    pre.update((grid - 0.5)[obj.order].ravel())  # the same contact-free grid, internal order
    assert pre.n_builds == 2
    assert pre.mu == first


# --- contact preconditioner --------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("alpha", [2.0, 2.5])
def test_contact_preconditioner_is_exp_plus_positive_stiffness(dim, alpha):
    obj = objective(dim, alpha=alpha, seed=8)
    exp_pre = ExpPreconditioner(obj, A=3.0, mu=0.05, solver="direct")
    pre = ContactPreconditioner(obj, A=3.0, mu=0.05, solver="direct")
    exp_pre.update(obj.x0)
    pre.update(obj.x0)
    k_plus = positive_contact_stiffness(obj, obj.x0)
    assert np.abs(k_plus).max() > 0.0
    v = rng_vector(obj, 10)
    np.testing.assert_allclose(pre.dot(v) - exp_pre.dot(v), k_plus @ v, rtol=1e-10, atol=1e-13)
    dense = pre.matrix.toarray()
    np.testing.assert_allclose(dense, dense.T, rtol=0, atol=1e-15)
    assert np.linalg.eigvalsh(dense).min() > 0.0
    # K_+ drops only the negative semidefinite tangential part of the exact Hessian
    exact = hessian(find_contacts(obj.packing(obj.x0, internal=True), obj.model), obj.n).toarray()
    assert np.linalg.eigvalsh(k_plus - exact).min() > -1e-10
    # its own mu estimate equals the Exp one
    auto_exp, auto_contact = ExpPreconditioner(obj), ContactPreconditioner(obj)
    auto_exp.update(obj.x0)
    auto_contact.update(obj.x0)
    assert auto_contact.mu == pytest.approx(auto_exp.mu, rel=1e-12)


# --- inputs -------------------------------------------------------------------------------------


def test_invalid_inputs_name_the_choices():
    obj = objective(2)
    with pytest.raises(InputError, match="'auto', 'direct', 'amg'"):
        ExpPreconditioner(obj, solver="cholesky")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="'none', 'exp', 'contact'"):
        make_preconditioner("jacobi", obj)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="half the narrowest cell width"):
        ExpPreconditioner(obj, r_cut=0.5)
    with pytest.raises(InputError, match="half the narrowest cell width"):
        ContactPreconditioner(
            Objective(Packing(np.zeros((1, 2)), [0.3], Cell.box([1, 1])), ContactModel())
        )
    for bad in ({"c_stab": 0.0}, {"mu": -1.0}, {"A": np.nan}, {"amg_cycles": 0}):
        with pytest.raises(InputError):
            ExpPreconditioner(obj, **bad)


def test_make_preconditioner():
    obj = objective(2)
    assert make_preconditioner("none", obj) is None
    exp_pre = make_preconditioner("exp", obj, A=3.0, solver="direct")
    contact_pre = make_preconditioner("contact", obj)
    assert isinstance(exp_pre, ExpPreconditioner) and exp_pre.name == "exp" and exp_pre.A == 3.0
    assert isinstance(contact_pre, ContactPreconditioner) and contact_pre.name == "contact"
    assert exp_pre.n_builds == contact_pre.n_builds == 0
