"""The truncated Newton method and the Hessian operator it applies."""

import importlib

import numpy as np
import pytest
import scipy.sparse as sp

from athermal.errors import InputError
from athermal.minimize import Hooks, Status
from athermal.model.cell import Cell, simple_shear
from athermal.model.contact import ContactModel, find_contacts, hessian
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing
from athermal.relaxation import Minimizer, minimize_objective
from athermal.studies.bench import make_case, reference_packing

newton_module = importlib.import_module("athermal.minimize.newton")


def overlapped(seed=1, n=128, phi=0.88, dim=2):
    return random_packing(n, phi, dim=dim, seed=seed)


@pytest.mark.parametrize(("alpha", "dim"), [(2.0, 2), (2.5, 2), (2.0, 3), (3.0, 3)])
def test_hessian_products_match_finite_differences_of_the_gradient(alpha, dim):
    obj = Objective(
        overlapped(seed=3, n=64, phi=0.9 if dim == 2 else 0.7, dim=dim), ContactModel(alpha)
    )
    x = obj.x0
    op = obj.hessian(x)
    rng = np.random.default_rng(0)
    v = rng.normal(size=obj.n_dof)
    h = 1e-7 * float(np.mean(obj.radii))
    fd = (obj(x + h * v / np.linalg.norm(v))[1] - obj(x - h * v / np.linalg.norm(v))[1]) / (2 * h)
    hv = op.dot(v / np.linalg.norm(v))
    assert np.abs(hv - fd).max() <= 1e-5 * np.abs(hv).max()
    # the matrix is the same operator, symmetric, and equals the reference assembly
    m = op.matrix()
    np.testing.assert_allclose(m @ v, op.dot(v), rtol=0, atol=1e-12 * np.abs(m @ v).max())
    assert abs(m - m.T).max() == 0.0
    ref = hessian(find_contacts(obj.packing(x, internal=True), obj.model), obj.n)
    assert abs(m - ref).max() <= 1e-12 * abs(ref).max()
    # the lowest eigenvalue of a particle's diagonal block, from the dense matrix
    dense = m.toarray()
    lowest = min(
        np.linalg.eigvalsh(dense[k : k + dim, k : k + dim])[0] for k in range(0, obj.n_dof, dim)
    )
    assert op.lowest_block_eigenvalue() == pytest.approx(lowest, rel=1e-12, abs=1e-14)
    assert np.linalg.eigvalsh(dense)[0] <= lowest + 1e-12 * abs(dense).max()


class MatrixHessian:
    """A Hessian given as a sparse matrix ``a``."""

    pairs = None  # no pair terms: the factor does not follow contacts

    def __init__(self, a):
        self.a = a

    def dot(self, v):
        return self.a @ v

    def matrix(self):
        return self.a

    def lowest_block_eigenvalue(self):
        return float(self.a.diagonal().min())  # one-by-one blocks


class Quadratic:
    """``f = (x - 1).A (x - 1) / 2`` with a sparse SPD ``A``: one Newton step solves it."""

    def compiled_search(self):
        return None  # evaluated from Python

    def __init__(self, n=20):
        main = np.linspace(1.0, 1e4, n)
        self.a = sp.diags([main, -0.3 * np.ones(n - 1), -0.3 * np.ones(n - 1)], [0, -1, 1]).tocsr()
        self.n_dof, self.dim = n, 2
        self.hooks = Hooks(block=2)
        self.n_evaluations = 0

    def __call__(self, x):
        self.n_evaluations += 1
        r = x - 1.0
        return 0.5 * float(r @ (self.a @ r)), self.a @ r

    def hessian(self, x):
        return MatrixHessian(self.a)


def test_a_quadratic_is_solved_in_one_newton_step():
    q = Quadratic()
    res = newton_module.newton(q, np.zeros(q.n_dof), gtol=1e-9)
    assert res.converged and res.status is Status.CONVERGED
    # one step, more when CG stopped at eta = 0.5: the factor is of A + 1e-5 <diag A> I
    # (SHIFT_MIN), whose smallest eigenvalue is 5 % off here (condition 1e4): 3 measured
    assert res.iterations <= 3
    np.testing.assert_allclose(res.x, 1.0, atol=1e-10)
    assert res.precon_builds == 1 and res.linear_iterations >= 1


def test_a_build_starts_above_the_negative_diagonal_blocks():
    """One DOF of negative curvature -1 (kappa = 100): the first shift tried is 2 x 1 / kappa,
    where from SHIFT_MIN it took four failed factorizations."""
    a = sp.diags([[-1.0] + [100.0] * 9], [0]).tocsr()
    factor = newton_module.LaggedFactor()
    factor.build(MatrixHessian(a))
    assert factor.n_failed == 0 and factor.n_builds == 1
    assert factor.shift * factor.scale == pytest.approx(newton_module.BLOCK_MARGIN)
    np.testing.assert_allclose(factor.solve(np.ones(10)), 1.0 / (a.diagonal() + 2.0))
    # a Hessian that knows no bound (a plain sparse matrix) is factored from SHIFT_MIN up
    plain = newton_module.LaggedFactor()
    plain.build(newton_module.SparseHessian(a))
    assert plain.n_failed == 4 and plain.shift == pytest.approx(0.1)


# Iterations measured on these seeded random starts (rtol 1e-9; L-BFGS: 537, 822, 311);
# they may only go down.
PINNED = {(2.0, 2): 200, (2.5, 2): 170, (2.0, 3): 200}


@pytest.mark.parametrize(("alpha", "dim"), sorted(PINNED))
def test_small_packings_relax_to_a_tight_tolerance(alpha, dim):
    packing = overlapped() if dim == 2 else random_packing(96, 0.7, dim=3, seed=3)
    obj = Objective(packing, ContactModel(alpha))
    res = minimize_objective(obj, "newton", rtol=1e-9)
    assert res.converged, res.message
    assert res.max_gradient <= res.gtol
    assert res.iterations <= PINNED[alpha, dim]
    assert res.precon_builds >= 1 and res.linear_iterations >= res.iterations
    # a minimum: the Hessian there has no negative eigenvalue beyond round-off
    eigenvalues = np.linalg.eigvalsh(obj.hessian(res.x).matrix().toarray())
    assert eigenvalues.min() >= -1e-9 * eigenvalues.max()


def test_a_table_case_converges_in_few_iterations():
    """The paper's Case 3 (alpha = 2, N = 4096): L-BFGS needs ~1560 iterations."""
    alpha = 2.0
    start = make_case(reference_packing(alpha), 3)
    res = minimize_objective(Objective(start, ContactModel(alpha)), "newton", rtol=1e-9)
    assert res.converged, res.message
    assert res.iterations <= 40  # measured 24-25


def test_a_quasi_static_step_near_jamming_takes_few_iterations():
    """A compressed packing, sheared by 1e-4: the contact network holds, Newton converges
    quadratically from the lagged factor."""
    model = ContactModel(2.0)
    relaxed = minimize_objective(
        Objective(random_packing(256, 0.87, seed=5), model), "lbfgs", rtol=1e-12
    ).packing
    sheared = relaxed.deform(simple_shear(1e-4, 2))
    res = minimize_objective(Objective(sheared, model), "newton", rtol=1e-9)
    plain = minimize_objective(Objective(sheared, model), "lbfgs", rtol=1e-9)
    assert res.converged and plain.converged
    assert res.iterations <= 10 < plain.iterations  # measured 2-3 against ~200
    assert res.energy == pytest.approx(plain.energy, rel=1e-8)


def test_packings_without_energy_end_at_once():
    grid = (np.stack(np.meshgrid(np.arange(8), np.arange(8)), axis=-1).reshape(-1, 2) + 0.5) / 8
    dilute = Packing(grid, np.full(64, 0.03), Cell.box([1.0, 1.0]))
    model = ContactModel(2.0)
    assert find_contacts(dilute, model).i.size == 0
    res = minimize_objective(Objective(dilute, model), "newton", gtol=1e-12)
    assert res.converged and res.iterations == 0 and res.evaluations == 1
    assert res.precon_builds == 0
    # an unjammed packing relaxes to (almost) zero energy, and from there ends at once
    start = random_packing(128, 0.5, seed=4)
    e0, _ = Objective(start, model)(start.positions.ravel())
    unjammed = minimize_objective(Objective(start, model), "newton", rtol=1e-9)
    assert unjammed.converged and unjammed.energy <= 1e-12 * e0
    again = minimize_objective(Objective(unjammed.packing, model), "newton", gtol=unjammed.gtol)
    assert again.iterations == 0
    # with an energy tolerance the run ends at the first iterate below it
    stopped = minimize_objective(Objective(start, model), "newton", gtol=0.0, etol=1e-12)
    assert stopped.converged and stopped.energy <= 1e-12


def test_runs_are_reproducible():
    a = minimize_objective(Objective(overlapped(), ContactModel(2.0)), "newton", rtol=1e-9)
    b = minimize_objective(Objective(overlapped(), ContactModel(2.0)), "newton", rtol=1e-9)
    np.testing.assert_array_equal(a.x, b.x)
    assert a.iterations == b.iterations and a.linear_iterations == b.linear_iterations


def test_newton_takes_no_preconditioner():
    obj = Objective(overlapped(), ContactModel(2.0))
    with pytest.raises(InputError, match="newton"):
        minimize_objective(obj, "newton", precon="exp", rtol=1e-9)
    with pytest.raises(InputError, match="newton"):
        Minimizer("newton", "contact")
    assert Minimizer("newton").name == "Newton-CG" and Minimizer("newton").label == "newton"


def test_indefinite_hessians_raise_the_shift_until_the_factor_exists():
    """Far from equilibrium (random overlaps) H is indefinite: the factor still exists."""
    obj = Objective(overlapped(seed=2, phi=0.95), ContactModel(2.0))
    op = obj.hessian(obj.x0)
    assert np.linalg.eigvalsh(op.matrix().toarray()).min() < 0.0
    factor = newton_module.LaggedFactor()
    factor.build(op)
    assert factor.n_failed >= 1 and factor.shift > newton_module.SHIFT_MIN
    r = np.random.default_rng(1).normal(size=obj.n_dof)
    assert float(r @ factor.solve(r)) > 0.0


class Channel(Quadratic):
    """``f = 1 + y^2 / 2 - x^2 / 2 + x^4 / 4`` on ``(x, y)``: a saddle at the origin, minima
    at ``x = +-1, y = 0``; along ``x`` the curvature is negative for ``|x| < 1/sqrt(3)``."""

    def __init__(self):
        self.n_dof, self.dim = 2, 2
        self.hooks = Hooks(block=2)
        self.n_evaluations = 0

    def __call__(self, v):
        self.n_evaluations += 1
        x, y = v
        return 1.0 + 0.5 * y * y - 0.5 * x * x + 0.25 * x**4, np.array([x**3 - x, y])

    def hessian(self, v):
        return MatrixHessian(sp.diags([[3.0 * v[0] ** 2 - 1.0, 1.0]], [0]).tocsr())


def test_a_direction_of_negative_curvature_is_followed_downhill_to_its_end():
    """From near the saddle, a first step of 1e-3 along x grows (x4 per trial) until the
    energy rises again: the search ends near the minimum x = 1, not 1e-3 further on."""
    problem = Channel()
    x0 = np.array([1e-3, 0.5])
    e0, g0 = problem(x0)
    for curved in (np.array([1.0, 0.0]), np.array([-2.0, 0.0])):  # either sign goes downhill
        x, energy, grad = newton_module.follow_negative_curvature(problem, x0, e0, g0, curved, 1e-3)
        assert abs(x[0] - 1.0) < 1e-3 and x[1] == 0.5
        assert energy == pytest.approx(e0 - 0.25, abs=1e-6)
        np.testing.assert_allclose(grad, problem(x)[1])
    # a direction orthogonal to the gradient, or no step, leaves the point as it was
    at_saddle = np.array([0.0, 0.5])
    e, g = problem(at_saddle)
    x, energy, _ = newton_module.follow_negative_curvature(
        problem, at_saddle, e, g, np.array([1.0, 0.0]), 1e-3
    )
    assert energy == e and np.array_equal(x, at_saddle)


def test_cg_returns_the_direction_of_negative_curvature_it_meets_after_a_first_step():
    """H = diag(2, 1, -0.01) preconditioned by the factor of a lagged diag(2, 1, 1): the first
    CG step solves the stiff part, the second direction is (almost) e_3, where H curves down."""

    def diagonal(values):
        return MatrixHessian(sp.diags([values], [0]).tocsr())

    factor = newton_module.LaggedFactor()
    factor.build(diagonal([2.0, 1.0, 1.0]))
    hessian = diagonal([2.0, 1.0, -0.01])
    grad = np.array([-1.0, -1.0, -1e-3])
    p, inner, curved = newton_module.newton_direction(hessian, grad, factor, 1e-10, 10)
    assert inner == 1 and curved is not None
    assert float(p @ grad) < 0.0
    np.testing.assert_allclose(p[:2], [0.5, 1.0], rtol=1e-4)  # M = diag(2, 1, 1) + 1.3e-5 I
    assert float(curved @ hessian.dot(curved)) <= 0.0
    assert abs(curved[2]) >= 0.99 * np.linalg.norm(curved)
    # a direction met at the first iteration is the step itself, not returned twice
    first = newton_module.newton_direction(hessian, np.array([0.0, 0.0, -1.0]), factor, 1e-10, 10)
    assert first[1] == 0 and first[2] is None


def test_newton_leaves_a_saddle_region_for_the_minimum():
    res = newton_module.newton(Channel(), np.array([1e-3, 0.5]), gtol=1e-12)
    assert res.converged, res.message
    np.testing.assert_allclose(res.x, [1.0, 0.0], atol=1e-9)
    assert res.iterations <= 12


def test_the_factor_follows_the_contacts_that_form():
    """A factor built with one contact network and corrected for 3 contacts formed since (one
    of them written j, i) solves with ``H + sigma kappa I`` of the build's network plus those
    three exactly (the 4 contacts lost stay in it); with too many new contacts it solves as
    built, and one that would leave the corrected matrix indefinite asks for a new build."""
    from scipy.sparse.linalg import spsolve

    from athermal.model.contact import HessianOperator

    rng = np.random.default_rng(4)
    n, d, m = 30, 2, 100
    keys = rng.choice(n * (n - 1) // 2, size=m, replace=False)
    pairs = np.array([(i, j) for i in range(n) for j in range(i + 1, n)])[keys]
    sep = rng.normal(size=(m, d))
    coef = np.column_stack([rng.uniform(1.0, 2.0, m), np.zeros(m)])  # positive blocks b b^T

    def operator(rows, flip=(), particles=n):
        p = pairs[rows].copy()
        p[list(flip)] = p[list(flip)][:, ::-1]
        return HessianOperator(particles, p, sep[rows], coef[rows])

    def follows(factor, hessian, rows, particles=n):
        """Whether ``factor`` corrected for ``hessian`` solves with the network ``rows``."""
        assert factor.follow(hessian)
        exact = operator(rows, particles=particles).matrix()
        shift = factor.shift * factor.scale * sp.identity(particles * d)
        r = np.random.default_rng(5).normal(size=particles * d)
        expected = spsolve((exact + shift).tocsc(), r)
        return np.allclose(factor.solve(r), expected, rtol=1e-9, atol=0.0)

    built = np.arange(0, 50)
    factor = newton_module.LaggedFactor()
    factor.build(operator(built))
    assert follows(factor, operator(np.arange(4, 53), flip=[47]), np.arange(0, 53))
    assert follows(factor, operator(built), built)  # back to the build's contacts
    many = np.arange(0, 51 + newton_module.CORRECTION_MAX)
    assert follows(factor, operator(many), built)  # too many new contacts: as built
    softened = HessianOperator(n, pairs[:51], sep[:51], np.vstack([coef[:50], [[0.0, 50.0]]]))
    assert not factor.follow(softened)  # a contact of stiffness -50 I: M would be indefinite
    assert factor.n_builds == 1
    # among 100,000 particles the columns of a contact take 6.4 MB (twice): the budget holds 10
    large = newton_module.LaggedFactor()
    large.build(operator(built, particles=100_000))
    assert follows(large, operator(np.arange(60), particles=100_000), np.arange(60), 100_000)
    assert follows(large, operator(np.arange(61), particles=100_000), built, 100_000)


def test_an_uphill_direction_from_round_off_falls_back_to_a_fresh_descent(monkeypatch):
    """Round-off in a nearly singular ``M`` (rattlers' zero modes at a small shift) can leave
    CG's answer uphill (seen: a 3D packing between walls relaxed to gtol 1e-14); Newton then
    takes ``-M^-1 g`` on a fresh factor, or ``-g``, instead of failing its line search."""
    solved = newton_module.newton_direction

    def uphill(*args):
        direction, inner, negative = solved(*args)
        return -direction, inner, negative

    monkeypatch.setattr(newton_module, "newton_direction", uphill)
    result = minimize_objective(
        Objective(overlapped(seed=2, n=64), ContactModel()), "newton", gtol=1e-11
    )
    assert result.converged
    # the 3D case where it was seen
    p = random_packing(96, 0.7, dim=3, seed=2, cell=Cell.unit(3, "z"))
    monkeypatch.setattr(newton_module, "newton_direction", solved)
    assert minimize_objective(Objective(p, ContactModel()), "newton", gtol=1e-14).converged
