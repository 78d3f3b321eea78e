import numpy as np
import pytest
import scipy.sparse as sp

from athermal.analysis import moduli
from athermal.analysis.moduli import (
    _cholesky_solve,
    _solve,
    linear_response,
    nonaffine_displacement,
    relaxed_strain_curvature,
    strain_terms,
)
from athermal.analysis.observables import rattlers
from athermal.errors import InputError
from athermal.model.cell import Cell, pure_shear, simple_shear
from athermal.model.contact import (
    ContactModel,
    Contacts,
    find_contacts,
    gradient,
    hessian,
    strain_derivative,
    total_energy,
)
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing
from athermal.protocols import Minimizer, finite_strain_bulk, finite_strain_shear
from athermal.relaxation import minimize_objective
from conftest import network_strain


def assert_second_order(err_h, err_h2, scale, tol=1e-6):
    """Central differences: small error that shrinks ~4x when the step halves (or round-off)."""
    assert err_h2 <= tol * scale, (err_h, err_h2, scale)
    assert err_h2 <= err_h / 3.0 or err_h <= 1e-9 * scale, (err_h, err_h2)


def deformed(contacts: Contacts, dmat: np.ndarray) -> Contacts:
    """The same contacts after ``x -> D x`` (branch vectors deformed, rest lengths kept)."""
    branch = contacts.branch @ dmat.T
    dist = np.linalg.norm(branch, axis=1)
    overlap = contacts.overlap + contacts.distance - dist
    assert np.all(overlap > 0.0)  # no contact opens within the step
    return Contacts(contacts.i, contacts.j, branch, dist, overlap, contacts.stiffness, contacts.law)


def overlapping_more_than(contacts: Contacts, fraction: float) -> Contacts:
    """The contacts with ``overlap > fraction * distance`` (none opens under strains << fraction;
    the strain terms are sums over contacts, so any subset checks them)."""
    keep = contacts.overlap > fraction * contacts.distance
    assert keep.sum() > 0.5 * keep.size
    return contacts.subset(keep)


def quadratic_paths(dim: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``(D1, D2)`` of paths ``D(g) = I + g D1 + g^2 D2 / 2``: simple shear, isotropic, pure
    shear to second order (``diag(1 + g, 1 / (1 + g))``) and a random one."""
    rng = np.random.default_rng(7)
    zero = np.zeros((dim, dim))
    return {
        "simple shear": (simple_shear(1.0, dim) - np.eye(dim), zero),
        "isotropic": (np.eye(dim), zero),
        "pure shear": (np.diag([1.0, -1.0, 0.0][:dim]), np.diag([0.0, 2.0, 0.0][:dim])),
        "general": (rng.normal(size=(dim, dim)), rng.normal(size=(dim, dim))),
    }


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("alpha", [2.0, 2.5])
@pytest.mark.parametrize("path", ["simple shear", "isotropic", "pure shear", "general"])
def test_strain_terms_against_central_differences(dim, alpha, path):
    """Along ``D(g)`` at fixed contacts: ``Xi`` against the difference of the gradient, and
    ``d2E/dg2`` against the difference of ``dE/dg = sum_ab S_ab (D'(g) D(g)^-1)_ab``, with ``S``
    the strain derivative (tested against the energy in test_contact), itself checked here
    against the difference of the energy."""
    p = random_packing(40 if dim == 2 else 30, 0.9 if dim == 2 else 0.7, dim=dim, seed=3)
    model = ContactModel(alpha, stiffness=1.3)
    c = overlapping_more_than(find_contacts(p, model), 0.02)
    d1, d2 = quadratic_paths(dim)[path]
    curvature, xi = strain_terms(c, p.n, d1, d2)

    def at(g):
        return deformed(c, np.eye(dim) + g * d1 + 0.5 * g**2 * d2)

    def slope(g):
        rate = (d1 + g * d2) @ np.linalg.inv(np.eye(dim) + g * d1 + 0.5 * g**2 * d2)
        return float(np.sum(strain_derivative(at(g)) * rate))

    h = 1e-4
    assert (total_energy(at(h)) - total_energy(at(-h))) / (2 * h) == pytest.approx(
        slope(0.0), rel=1e-6
    )
    curv_errs, xi_errs = [], []
    for h in (1e-4, 5e-5):
        curv_errs.append(abs((slope(h) - slope(-h)) / (2.0 * h) - curvature))
        fd_xi = (gradient(at(h), p.n) - gradient(at(-h), p.n)) / (2.0 * h)
        xi_errs.append(np.abs(fd_xi - xi).max())
    assert_second_order(*curv_errs, scale=abs(curvature))
    assert_second_order(*xi_errs, scale=np.abs(xi).max())


def test_strain_terms_follow_the_deformed_packing_with_its_cell():
    """The same through ``Packing.deform`` (cell and periodic images deformed together) along the
    cell module's pure shear ``D = diag(1 + g, 1 / (1 + g))``, whose ``D'' = diag(0, 2)``. The
    curvature is the difference of ``dE/dg = sum_ab S_ab (D' D^-1)_ab = (S_00 - S_11) / (1 + g)``,
    ``S`` the strain derivative of the deformed packing."""
    p = random_packing(60, 0.9, seed=4).deform(simple_shear(0.2))
    model = ContactModel(2.5)
    c = find_contacts(p, model)
    curvature, xi = strain_terms(c, p.n, np.diag([1.0, -1.0]), np.diag([0.0, 2.0]))

    def slope(g):
        s = strain_derivative(find_contacts(p.deform(pure_shear(g)), model))
        return (s[0, 0] - s[1, 1]) / (1.0 + g)

    curv_errs, xi_errs = [], []
    for h in (2e-5, 1e-5):
        plus, minus = (find_contacts(p.deform(pure_shear(s)), model) for s in (h, -h))
        assert plus.i.size == minus.i.size == c.i.size
        curv_errs.append(abs((slope(h) - slope(-h)) / (2.0 * h) - curvature))
        fd_xi = (gradient(plus, p.n) - gradient(minus, p.n)) / (2.0 * h)
        xi_errs.append(np.abs(fd_xi - xi).max())
    # the pure-shear curvature nearly cancels here (1.9e-5 against terms ~1e-3)
    assert_second_order(*curv_errs, scale=abs(curvature), tol=1e-3)
    assert_second_order(*xi_errs, scale=np.abs(xi).max())


def relaxed(n, phi, dim, alpha, seed=1):
    model = ContactModel(alpha)
    result = minimize_objective(
        Objective(random_packing(n, phi, dim=dim, seed=seed), model), rtol=1e-12
    )
    assert result.converged
    return result.packing, model


@pytest.mark.parametrize(
    ("n", "phi", "dim", "alpha"),
    [(128, 0.87, 2, 2.0), (128, 0.87, 2, 2.5), (64, 0.68, 3, 2.0)],
)
def test_linear_response_agrees_with_finite_strain(n, phi, dim, alpha):
    """Measured relative differences (finite strain 1e-6..1e-5 in 10 steps, rtol 1e-9):
    2D alpha=2: G 8e-5, B 3e-5; 2D alpha=2.5: G 3e-4, B 2e-4; 3D alpha=2: G 1e-5, B 4e-5."""
    p, model = relaxed(n, phi, dim, alpha)
    lr = linear_response(p, model)
    assert lr.solver == "cholmod" and lr.residual < 1e-10
    assert 0.0 < lr.shear < lr.shear_affine
    assert 0.0 < lr.bulk < lr.bulk_affine
    # the paper's strains, 1e-6 to 1e-5, below the strain that changes the contact network (a
    # gap that closes or a contact that parts within 1e-5 would change the modulus measured)
    shear_d1, bulk_d1 = simple_shear(1.0, dim) - np.eye(dim), np.eye(dim)
    top = [min(1e-5, 0.25 * network_strain(p, model, d1, True)) for d1 in (shear_d1, bulk_d1)]
    for fs, exact in (
        (finite_strain_shear(p, model, np.linspace(0.1, 1.0, 10) * top[0]), lr.shear),
        (finite_strain_bulk(p, model, -np.linspace(0.1, 1.0, 10) * top[1]), lr.bulk),
    ):
        np.testing.assert_array_equal(fs.contacts, fs.contacts_initial)  # same contact network
        # Newton from the linear-response start: 0-1 iterations per step (measured)
        assert fs.iterations.shape == (10,) and fs.iterations.max() <= 5
        assert fs.modulus == pytest.approx(exact, rel=2e-3)
        assert fs.stderr < 1e-3 * abs(fs.modulus)
    # the general entry point gives the same shear modulus
    _, rel = relaxed_strain_curvature(p, model, simple_shear(1.0, dim) - np.eye(dim))
    assert rel / p.cell.volume == pytest.approx(lr.shear, rel=1e-12)


def test_pure_shear_curvature_against_relaxed_energy_differences():
    """Pure shear has ``D'' != 0``: the relaxed curvature against the second difference of the
    relaxed energy of the deformed packing."""
    p, model = relaxed(128, 0.87, 2, 2.0)
    d1, d2 = np.diag([1.0, -1.0]), np.diag([0.0, 2.0])
    affine, rel = relaxed_strain_curvature(p, model, d1, d2)
    h = 1e-5

    def energy(s):
        result = minimize_objective(Objective(p.deform(pure_shear(s)), model), gtol=1e-15)
        return result.energy

    fd = (energy(h) - 2.0 * total_energy(find_contacts(p, model)) + energy(-h)) / h**2
    assert fd == pytest.approx(rel, rel=1e-6)  # measured 4e-8
    assert rel < 0.9 * affine  # the non-affine relaxation matters


def triangular_crystal(a, radius, nx=6, ny=6):
    rows = np.arange(ny)
    x = np.arange(nx)[None, :] * a + 0.5 * a * (rows[:, None] % 2)
    y = np.repeat(rows[:, None] * a * np.sqrt(3.0) / 2.0, nx, axis=1)
    cell = Cell.box([nx * a, ny * a * np.sqrt(3.0) / 2.0])
    return Packing(np.column_stack([x.ravel(), y.ravel()]), np.full(nx * ny, radius), cell)


def fcc_crystal(a, radius, m=3):
    c = a * np.sqrt(2.0)
    basis = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]])
    cells = np.array(np.meshgrid(*[np.arange(m)] * 3, indexing="ij")).reshape(3, -1).T
    x = (cells[:, None, :] + basis[None, :, :]).reshape(-1, 3) * c
    return Packing(x, np.full(len(x), radius), Cell.box([m * c] * 3))


@pytest.mark.parametrize("alpha", [2.0, 2.5])
@pytest.mark.parametrize("dim", [2, 3])
def test_crystal_moduli_by_hand(alpha, dim):
    """Equal spheres at nearest distance ``a``, overlap ``delta``; ``phi' = -k delta^(alpha-1)``,
    ``phi'' = k (alpha-1) delta^(alpha-2)``. Every particle is a centre of inversion, so ``Xi``
    vanishes (neighbours at ``+r`` and ``-r`` cancel) and the moduli are the affine ones.
    Simple shear ``D1 r = (a ny, 0, ..)``: each bond gives ``phi'' (n.D1 r)^2 + (phi'/a)
    (|D1 r|^2 - (n.D1 r)^2) = a^2 [phi'' nx^2 ny^2 + (phi'/a) ny^2 (1 - nx^2)]``; compression
    ``D1 = I`` gives ``a^2 phi''`` per bond, and ``p = -(1 / (d V)) sum_bonds a phi'``.

    Triangular (2D): per particle 3 bonds at 0, 60, 120 degrees, area ``V = sqrt(3)/2 a^2``;
    ``sum nx^2 ny^2 = 3/8``, ``sum ny^2 (1 - nx^2) = 9/8``, so
    ``G = a^2 (3/8 phi'' + 9/8 phi'/a) / V``; ``E''_bulk = 3 a^2 phi''``,
    ``p = -sqrt(3) phi' / a`` and ``B = E''/(4 V) + p/2 = sqrt(3)/2 (phi'' - phi'/a)``. For
    alpha = 2 this is ``-V dp/dV`` of ``p(a) = sqrt(3) k (2R - a) / a``, ``V ~ a^2``.

    FCC (3D): per particle 6 bonds along (1,+-1,0), (1,0,+-1), (0,1,+-1) over sqrt(2), volume
    ``V = a^3/sqrt(2)``; ``sum nx^2 ny^2 = 1/2``, ``sum ny^2 (1 - nx^2) = 3/2``, so
    ``G = a^2 (phi''/2 + 3/2 phi'/a) / V``; ``E''_bulk = 6 a^2 phi''``,
    ``p = -2 sqrt(2) phi' / a^2`` and ``B = E''/(9 V) + 2p/3 =
    (2 sqrt(2)/3) (phi''/a - 2 phi'/a^2)``. For alpha = 2 this is ``-V dp/dV`` of
    ``p(a) = 2 sqrt(2) k (2R - a) / a^2``, ``V ~ a^3``.
    """
    a, delta, k = 1.0, 0.06, 1.3
    p = triangular_crystal(a, (a + delta) / 2) if dim == 2 else fcc_crystal(a, (a + delta) / 2)
    model = ContactModel(alpha, stiffness=k)
    lr = linear_response(p, model)
    d1 = -k * delta ** (alpha - 1.0)
    d2 = k * (alpha - 1.0) * delta ** (alpha - 2.0)
    if dim == 2:
        shear = a**2 * (3 / 8 * d2 + 9 / 8 * d1 / a) / (np.sqrt(3.0) / 2 * a**2)
        bulk = np.sqrt(3.0) / 2 * (d2 - d1 / a)
        press = -np.sqrt(3.0) * d1 / a
    else:
        shear = a**2 * (d2 / 2 + 1.5 * d1 / a) / (a**3 / np.sqrt(2.0))
        bulk = 2 * np.sqrt(2.0) / 3 * (d2 / a - 2 * d1 / a**2)
        press = -2 * np.sqrt(2.0) * d1 / a**2
    assert lr.n_rattlers == 0
    _, xi = strain_terms(find_contacts(p, model), p.n, np.eye(dim), None)
    assert np.abs(xi).max() < 1e-14 * abs(d2) * a  # neighbours at +r and -r cancel
    assert lr.pressure == pytest.approx(press, rel=1e-12)
    assert lr.shear == pytest.approx(shear, rel=1e-12)
    assert lr.bulk == pytest.approx(bulk, rel=1e-12)
    assert lr.shear_affine == pytest.approx(shear, rel=1e-12)
    assert lr.bulk_affine == pytest.approx(bulk, rel=1e-12)


def test_unjammed_packing_has_zero_moduli():
    p = random_packing(50, 0.3, seed=2)
    lr = linear_response(p, ContactModel())
    assert lr.n_rattlers == p.n and lr.solver == "none"
    assert lr.bulk == lr.shear == lr.pressure == 0.0


def test_rattlers_are_left_out():
    """A relaxed packing with rattlers (one pushed into a neighbour so that it has a loaded
    contact, still fewer than d + 1) has the moduli of the packing without them."""
    p, model = relaxed(256, 0.86, 2, 2.0)
    lr = linear_response(p, model)
    assert lr.n_rattlers >= 1  # how many depends on the CPU's rounding; one is needed
    c = find_contacts(p, model)
    rattler = rattlers(c, p.n, p.dim)
    r = int(np.flatnonzero(rattler)[0])
    sep = p.cell.minimum_image(p.positions[r] - p.positions)
    dist = np.linalg.norm(sep, axis=1)
    gap = dist - p.radii[r] - p.radii
    gap[r] = np.inf
    q = int(np.argmin(gap))
    moved = p.positions.copy()
    moved[r] -= sep[q] / dist[q] * (gap[q] + 0.01 * p.radii[r])
    pushed = p.with_positions(moved)
    cp = find_contacts(pushed, model)
    assert 1 <= np.sum((cp.i == r) | (cp.j == r)) <= 2
    assert np.array_equal(rattlers(cp, p.n, p.dim), rattler)
    lr_pushed = linear_response(pushed, model)
    keep = ~rattler
    lr_removed = linear_response(Packing(p.positions[keep], p.radii[keep], p.cell), model)
    assert lr_removed.n_rattlers == 0
    assert lr_pushed.n_rattlers == lr.n_rattlers
    for other in (lr_pushed, lr_removed):
        assert other.solver == "cholmod"
        for name in ("shear", "bulk", "shear_affine", "bulk_affine", "pressure"):
            assert getattr(other, name) == pytest.approx(getattr(lr, name), rel=1e-10)


def test_a_poor_solve_is_reported(monkeypatch):
    p, model = relaxed(32, 0.88, 2, 2.0)
    d1 = simple_shear(1.0) - np.eye(2)
    monkeypatch.setattr(moduli, "RESIDUAL_WARN", 0.0)  # any residual counts as poor
    with pytest.warns(RuntimeWarning, match="residual"):
        relaxed_strain_curvature(p, model, d1)


def test_solver_falls_back_for_singular_and_indefinite_matrices():
    """CHOLMOD for an SPD matrix; MINRES when the matrix is singular (right-hand side in its
    range) or indefinite. ``b^T y`` is ``b^T H^+ b`` in every case."""
    n = 12
    ring = sp.diags([2.0 * np.ones(n), -np.ones(n - 1), -np.ones(n - 1)], [0, 1, -1]).tolil()
    ring[0, n - 1] = ring[n - 1, 0] = -1.0
    ring = ring.tocsr()  # singular: the uniform vector
    rng = np.random.default_rng(0)
    b = rng.normal(size=(n, 2))
    b -= b.mean(axis=0)
    indefinite = ring + sp.diags(np.linspace(-0.5, 0.7, n))
    spd = ring + 0.1 * sp.eye(n)
    # cholespy reads the lower triangle only: given the upper one too (here doubled, so that
    # reading it would factor another matrix), the answer must be that of the lower one
    np.testing.assert_allclose(
        _cholesky_solve(spd + sp.triu(spd, 1), b), np.linalg.solve(spd.toarray(), b), rtol=1e-12
    )
    assert _cholesky_solve(indefinite, b) is None
    for matrix, solvers in (
        (spd, {"cholmod"}),
        (ring, {"cholmod", "minres"}),
        (indefinite, {"minres"}),
    ):
        dense = matrix.toarray()
        y, residual, solver = _solve(matrix.tocsr(), b)
        assert residual < 1e-10 and solver in solvers
        expected = np.einsum("km,km->m", b, np.linalg.pinv(dense) @ b)
        np.testing.assert_allclose(np.einsum("km,km->m", b, y), expected, rtol=1e-9)


def test_bad_input_is_rejected():
    p, model = relaxed(32, 0.88, 2, 2.0)
    for bad in ([], [1e-6], [1e-6, np.nan], [2e-6, 1e-6], [1e-6, -2e-6], [0.0, 1e-6]):
        with pytest.raises(InputError, match="strains"):
            finite_strain_shear(p, model, bad)
    with pytest.raises(InputError, match="strains"):
        finite_strain_bulk(p, model, [-0.5, -1.5])
    with pytest.raises(InputError, match="d1"):
        relaxed_strain_curvature(p, model, np.eye(3))
    with pytest.raises(InputError, match="d2"):
        relaxed_strain_curvature(p, model, np.eye(2), [1.0, 0.0])
    with pytest.raises(InputError, match="method"):
        finite_strain_shear(p, model, minimizer=Minimizer("bfgs"))  # type: ignore[arg-type]


def _square_lattice(radius=0.13, side=4):
    """``side`` x ``side`` equal disks (16 by default) on a square lattice in the unit cell,
    overlapping their four neighbours (spacing ``1 / side``, overlap ``2 r - 1 / side``): a
    force-balanced saddle, whose transverse modes have the negative stiffness -f/l of the
    compressed bonds (lowest eigenvalue ``-4 f / l`` for an even ``side``: a row displaced
    along itself, alternating from row to row)."""
    g = (np.arange(side) + 0.5) / side
    positions = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    return Packing(positions, np.full(side * side, radius), Cell.box([1.0, 1.0]))


def test_stability_finds_the_negative_mode_of_a_constructed_saddle():
    from athermal.analysis.moduli import stability

    square, model = _square_lattice(), ContactModel(2.0)
    f, length = 2 * 0.13 - 0.25, 0.25
    check = stability(square, model)
    assert not check.stable
    assert check.lowest_eigenvalue == pytest.approx(-4 * f / length, rel=1e-9)
    mode = check.mode
    h = hessian(find_contacts(square, model), 16).toarray()
    np.testing.assert_allclose(mode.ravel() @ h @ mode.ravel(), -4 * f / length, rtol=1e-9)
    assert np.linalg.norm(mode) == pytest.approx(1.0)


def test_stability_finds_the_negative_mode_of_a_saddle_too_large_for_a_dense_solve():
    """Above :data:`DENSE_EIGEN_DOFS` the lowest eigenpair comes from shift-invert below the
    contacts' bound (``docs/decisions.md``, "A saddle test that took longer than the march"):
    the lattice's analytic one."""
    from athermal.analysis.moduli import DENSE_EIGEN_DOFS, stability

    side, spacing = 40, 1.0 / 40
    square, model = _square_lattice(0.51 * spacing, side), ContactModel(2.0)
    assert 2 * side * side > DENSE_EIGEN_DOFS
    f = 1.02 * spacing - spacing
    check = stability(square, model)
    assert not check.stable
    assert check.lowest_eigenvalue == pytest.approx(-4 * f / spacing, rel=1e-9)
    mode = check.mode.ravel()
    h = hessian(find_contacts(square, model), side * side)
    assert mode @ (h @ mode) == pytest.approx(-4 * f / spacing, rel=1e-9)


def test_a_relaxed_packing_is_stable():
    from athermal.analysis.moduli import stability

    model = ContactModel(2.0)
    relaxed = minimize_objective(
        Objective(random_packing(128, 0.88, seed=2), model), rtol=1e-12
    ).packing
    check = stability(relaxed, model)
    assert check.stable and check.mode is None


def test_a_protocol_relaxation_leaves_the_saddle_for_a_minimum():
    from athermal.analysis.moduli import stability
    from athermal.protocols import Minimizer
    from athermal.relaxation import Relaxer

    square, model = _square_lattice(), ContactModel(2.0)
    objective = Objective(square, model)
    e0 = objective(objective.x0)[0]
    plain = Relaxer(objective, Minimizer()).relax(objective.x0, gtol=1e-13)
    assert plain.energy == pytest.approx(e0, rel=1e-12)  # the minimizer alone stays put
    result, escapes = Relaxer(objective, Minimizer()).relax_to_minimum(objective.x0, gtol=1e-13)
    assert escapes >= 1 and result.energy < 0.99 * e0
    assert stability(result.packing, model).stable


def test_nonaffine_displacement_is_the_relaxation_to_first_order():
    p, model = relaxed(128, 0.87, 2, 2.0)
    d1 = simple_shear(1.0, 2) - np.eye(2)
    u = nonaffine_displacement(p, model, d1)
    live = ~rattlers(find_contacts(p, model), p.n, 2)
    assert np.all(u[~live] == 0.0)
    errors = []
    for gamma in (1e-5, 1e-6):
        sheared = p.deform(np.eye(2) + gamma * d1)
        res = minimize_objective(Objective(sheared, model), "newton", gtol=1e-14)
        moved = sheared.cell.minimum_image(res.packing.positions - sheared.positions)[live]
        predicted = gamma * u[live]
        moved -= moved.mean(axis=0)  # the relaxation is defined up to a translation
        predicted -= predicted.mean(axis=0)
        errors.append(np.abs(moved - predicted).max() / np.abs(predicted).max())
    # first order: the error of the prediction falls with the strain
    assert errors[1] < 0.3 * errors[0] and errors[1] < 1e-3


def test_linear_start_gives_the_same_modulus_in_fewer_iterations():
    p, model = relaxed(128, 0.87, 2, 2.0)
    exact = linear_response(p, model)
    affine = finite_strain_shear(p, model, start="affine")
    linear = finite_strain_shear(p, model, start="linear")
    for found, bulk in (
        (affine, False),
        (linear, False),
        (finite_strain_bulk(p, model, start="affine"), True),
        (finite_strain_bulk(p, model, start="linear"), True),
    ):  # either start: the modulus at zero strain (measured 1.1e-6 and 4.6e-8 of G apart)
        truth = exact.bulk if bulk else exact.shear
        assert found.modulus == pytest.approx(truth, rel=2e-6)
    assert linear.iterations.sum() <= affine.iterations.sum()
    with pytest.raises(InputError, match="start"):
        finite_strain_shear(p, model, start="predicted")  # type: ignore[arg-type]


def test_a_linear_start_beyond_the_step_cap_is_not_taken(monkeypatch):
    import athermal.protocols.finite_strain as finite_strain

    p, model = relaxed(128, 0.87, 2, 2.0)
    affine = finite_strain_shear(p, model, start="affine")
    for bad in (np.full((p.n, 2), 0.2 * float(p.radii.mean())), np.full((p.n, 2), np.nan)):
        monkeypatch.setattr(finite_strain, "nonaffine_displacement", lambda *args, u=bad: u)
        linear = finite_strain_shear(p, model, start="linear")
        np.testing.assert_array_equal(linear.iterations, affine.iterations)
        assert linear.modulus == affine.modulus
