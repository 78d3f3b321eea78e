from itertools import pairwise

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from athermal.analysis.observables import stress
from athermal.errors import InputError
from athermal.model.cell import Cell, pure_shear, simple_shear
from athermal.model.contact import (
    ContactModel,
    assemble_blocks,
    contact_blocks,
    energy_gradient,
    find_contacts,
    gradient,
    hessian,
    packing_energy,
    strain_derivative,
    total_energy,
)
from athermal.model.neighbors import build_neighbor_list
from athermal.model.packing import Packing, random_packing

ALPHAS = [2.0, 2.5, 3.0, 2.7]
CELLS = {
    "square": lambda d: np.eye(d),
    "shear 0.3": lambda d: simple_shear(0.3, d),
    "shear past one box": lambda d: simple_shear(1.3, d),
    "pure shear": lambda d: pure_shear(0.15, d),
}


class Evaluator:
    """Energy and gradient of a packing's positions through the compiled kernel."""

    def __init__(self, packing: Packing, model: ContactModel):
        self.p, self.model = packing, model
        self.nl = build_neighbor_list(
            packing.positions, packing.radii, packing.cell, skin=0.5 * packing.radii.min()
        )
        self.shifts = self.nl.shifts(packing.cell)
        self.typeid = model.typeid(packing)

    def __call__(self, x):
        g = np.empty_like(x)
        e = energy_gradient(
            np.ascontiguousarray(x), self.p.radii, self.typeid, self.shifts, self.nl, self.model, g
        )
        return e, g


def overlapped(dim, name, seed=0):
    p = random_packing(40 if dim == 2 else 30, 0.9 if dim == 2 else 0.7, dim=dim, seed=seed)
    return p.deform(CELLS[name](dim))


def assert_second_order(err_h, err_h2, scale, tol=1e-6):
    """Central differences: small error that shrinks ~4x when the step halves (or round-off)."""
    assert err_h2 <= tol * scale, (err_h, err_h2, scale)
    assert err_h2 <= err_h / 3.0 or err_h <= 1e-9 * scale, (err_h, err_h2)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("cell", list(CELLS))
def test_gradient_and_hessian_against_central_differences(dim, alpha, cell):
    p = overlapped(dim, cell)
    model = ContactModel(alpha)
    ev = Evaluator(p, model)
    x = p.positions
    _, g = ev(x)
    v = np.random.default_rng(1).normal(size=x.shape)
    v /= np.linalg.norm(v)
    h = 1e-4 * p.radii.mean()
    errs, herrs = [], []
    hv = hessian(find_contacts(p, model), p.n) @ v.ravel()
    for step in (h, h / 2):
        ep, gp = ev(x + step * v)
        em, gm = ev(x - step * v)
        errs.append(abs((ep - em) / (2 * step) - np.vdot(g, v)))
        herrs.append(np.linalg.norm((gp - gm).ravel() / (2 * step) - hv))
    assert_second_order(*errs, scale=np.linalg.norm(g))
    assert_second_order(*herrs, scale=np.linalg.norm(hv))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("alpha", ALPHAS)
def test_strain_derivative_and_stress_against_energy_under_homogeneous_strain(dim, alpha):
    p = overlapped(dim, "shear 0.3", seed=2)
    model = ContactModel(alpha)
    c = find_contacts(p, model)
    got = strain_derivative(c)

    def energy(eps):
        branch = c.branch @ (np.eye(dim) + eps).T
        delta = c.overlap + c.distance - np.linalg.norm(branch, axis=1)
        return np.sum(c.stiffness * delta**alpha / alpha)

    h = 1e-6
    for a in range(dim):
        for b in range(dim):
            errs = []
            for step in (h, h / 2):
                e = np.zeros((dim, dim))
                e[a, b] = step
                errs.append(abs((energy(e) - energy(-e)) / (2 * step) - got[a, b]))
            assert_second_order(*errs, scale=np.abs(got).max())
    np.testing.assert_allclose(stress(c, p.cell), -got / p.cell.volume, rtol=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
def test_stress_against_energy_of_the_deformed_cell(dim):
    """Deforming positions and cell together: dE/dgamma = -V sigma_01 (simple shear) and
    dE/d(log V) = -V p d (isotropic)."""
    p = overlapped(dim, "square", seed=3)
    model = ContactModel(2.5)
    sigma = stress(find_contacts(p, model), p.cell)
    h = 1e-7
    de = (
        packing_energy(p.deform(simple_shear(h, dim)), model)
        - packing_energy(p.deform(simple_shear(-h, dim)), model)
    ) / (2 * h)
    assert de == pytest.approx(-p.cell.volume * sigma[0, 1], rel=1e-6)
    dv = (
        packing_energy(p.deform((1 + h) * np.eye(dim)), model)
        - packing_energy(p.deform((1 - h) * np.eye(dim)), model)
    ) / (2 * h)
    assert dv == pytest.approx(-p.cell.volume * np.trace(sigma), rel=1e-6)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("alpha", ALPHAS)
def test_compiled_kernel_equals_vectorized_reference(dim, alpha):
    p = random_packing(500, 0.85 if dim == 2 else 0.6, dim=dim, seed=4).deform(
        simple_shear(0.7, dim)
    )
    model = ContactModel(alpha, stiffness=1.7)
    e, g = Evaluator(p, model)(p.positions)
    c = find_contacts(p, model)
    assert e == pytest.approx(total_energy(c), rel=1e-12)
    np.testing.assert_allclose(g, gradient(c, p.n), rtol=0, atol=1e-13 * np.abs(g).max())


def test_two_disks_by_hand():
    cell = Cell.box([1.0, 1.0])
    # the pair touches across the periodic boundary: separation 0.15 along x
    p = Packing(np.array([[0.425, 0.0], [-0.425, 0.0]]), np.array([0.1, 0.1]), cell)
    for alpha in (2.0, 2.5):
        c = find_contacts(p, ContactModel(alpha, stiffness=2.0))
        assert c.i.size == 1
        delta = 0.05
        assert total_energy(c) == pytest.approx(2.0 * delta**alpha / alpha, rel=1e-12)
        f = 2.0 * delta ** (alpha - 1)
        # particle 1's nearest image is at x = 0.575, right of particle 0: 0 is pushed to -x
        np.testing.assert_allclose(gradient(c, 2), [[f, 0.0], [-f, 0.0]], atol=1e-15)
        np.testing.assert_allclose(stress(c, cell), [[0.15 * f, 0.0], [0.0, 0.0]], atol=1e-15)
    c2 = find_contacts(p, ContactModel(2.0))
    np.testing.assert_allclose(contact_blocks(c2)[0], np.diag([1.0, -1.0 / 3.0]), atol=1e-14)
    h = hessian(c2, 2).toarray()
    np.testing.assert_allclose(h[:2, :2], np.diag([1.0, -1.0 / 3.0]), atol=1e-14)
    np.testing.assert_allclose(h[:2, 2:], -np.diag([1.0, -1.0 / 3.0]), atol=1e-14)


def test_three_disks_in_a_triangle_by_hand():
    r, side = 0.1, 0.18
    angles = np.deg2rad([90.0, 210.0, 330.0])
    x = side / np.sqrt(3.0) * np.column_stack([np.cos(angles), np.sin(angles)])
    p = Packing(x, np.full(3, r), Cell.box([1.0, 1.0]))
    c = find_contacts(p, ContactModel(2.0))
    delta = 2 * r - side
    assert c.i.size == 3
    assert total_energy(c) == pytest.approx(3 * delta**2 / 2, rel=1e-12)
    g = gradient(c, 3)
    # each disk is pushed outwards by two forces 60 degrees apart: |sum| = sqrt(3) f
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), np.sqrt(3.0) * delta, rtol=1e-12)
    np.testing.assert_allclose(
        g / np.linalg.norm(g, axis=1)[:, None], -x / np.linalg.norm(x, axis=1)[:, None], atol=1e-12
    )
    np.testing.assert_allclose(
        stress(c, p.cell), 1.5 * side * delta * np.eye(2), rtol=1e-12, atol=1e-15
    )


@pytest.mark.parametrize("dim", [2, 3])
def test_translation_and_periodic_image_invariance(dim):
    p = overlapped(dim, "shear 0.3", seed=5)
    model = ContactModel(2.5)
    c = find_contacts(p, model)
    e0, g0 = total_energy(c), gradient(c, p.n)
    np.testing.assert_allclose(g0.sum(axis=0), 0.0, atol=1e-15 * p.n)
    rng = np.random.default_rng(0)
    moved = p.with_positions(p.positions + rng.normal(size=dim))
    jumps = rng.integers(-3, 4, size=(p.n, dim)).astype(float) @ p.cell.h.T
    imaged = p.with_positions(p.positions + jumps)
    for q in (moved, imaged, p.wrapped()):
        cq = find_contacts(q, model)
        assert total_energy(cq) == pytest.approx(e0, rel=1e-12)
        np.testing.assert_allclose(gradient(cq, q.n), g0, atol=1e-12 * np.abs(g0).max())


def test_per_pair_stiffness_by_species():
    p = random_packing(200, 0.88, seed=6)
    kmat = np.array([[1.0, 2.0], [2.0, 3.0]])
    model = ContactModel(2.0, stiffness=kmat)
    c = find_contacts(p, model)
    typeid, _ = p.types()
    np.testing.assert_array_equal(c.stiffness, kmat[typeid[c.i], typeid[c.j]])
    e, g = Evaluator(p, model)(p.positions)
    assert e == pytest.approx(np.sum(c.stiffness * c.overlap**2 / 2), rel=1e-12)
    np.testing.assert_allclose(g, gradient(c, p.n), atol=1e-13 * np.abs(g).max())
    with pytest.raises(InputError, match="species"):
        ContactModel(2.0, stiffness=np.ones((3, 3))).typeid(p)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"alpha": 1.5}, "alpha"),
        ({"alpha": float("nan")}, "alpha"),
        ({"stiffness": -1.0}, "stiffness"),
        ({"stiffness": [[1.0, 2.0], [3.0, 1.0]]}, "symmetric"),
    ],
)
def test_bad_contact_models(kwargs, message):
    with pytest.raises(InputError, match=message):
        ContactModel(**kwargs)


def test_hessian_is_symmetric_and_positive_semidefinite_at_a_minimum(jammed_packing_2d):
    p, ref = jammed_packing_2d
    h = hessian(find_contacts(p, ContactModel(float(ref["alpha"]))), p.n)
    assert abs(h - h.T).max() == 0.0
    low = spla.eigsh(h, k=6, sigma=-1e-4, which="LM", return_eigenvectors=False)
    scale = abs(h).max()
    assert low.min() > -1e-10 * scale


@pytest.mark.parametrize("dim", [2, 3])
def test_block_assembly_against_a_dense_loop(dim):
    """Duplicate pairs (two images), self-image pairs and particles without pairs included."""
    rng = np.random.default_rng(4)
    n = 9
    i = rng.integers(0, n - 1, 40)  # particle n - 1 has no pair
    j = rng.integers(0, n - 1, 40)
    i[:3], j[:3] = (2, 2, 5), (2, 6, 6)  # a self-image pair; (5, 6) twice below
    i[3], j[3] = 5, 6
    raw = rng.normal(size=(40, dim, dim))
    blocks = raw + raw.transpose(0, 2, 1)
    dense = np.zeros((n * dim, n * dim))
    for p in range(40):
        if i[p] == j[p]:
            continue
        a, b = slice(i[p] * dim, (i[p] + 1) * dim), slice(j[p] * dim, (j[p] + 1) * dim)
        dense[a, a] += blocks[p]
        dense[b, b] += blocks[p]
        dense[a, b] -= blocks[p]
        dense[b, a] -= blocks[p]
    got = assemble_blocks(i, j, blocks, n)
    np.testing.assert_allclose(got.toarray(), dense, rtol=0, atol=1e-13)
    assert got.has_sorted_indices and abs(got - got.T).max() == 0.0
    # every particle's diagonal block is stored (a factorization adds its shift there)
    assert np.all(np.diff(got.indptr) >= dim)


@pytest.mark.parametrize("dim, walls", [(2, ()), (2, (1,)), (3, ())])
def test_the_slab_kernel_matches_one_thread_whatever_the_threads(dim, walls):
    """The threads' kernel (slabs of one parity at once) gives the one-thread kernel's energy and
    gradient to round-off, the same bits on 1 and 2 threads, and its slabs of one parity share
    no particle."""
    import numba

    from athermal.model.contact import energy_gradient_contacts

    cell = Cell(np.eye(dim), walls)
    p = random_packing(4096 if dim == 2 else 8000, 0.86 if dim == 2 else 0.66, cell=cell, seed=2)
    model = ContactModel(2.0)
    nl = build_neighbor_list(p.positions, p.radii, p.cell)
    slabs = nl.slabs
    assert slabs.size - 1 >= 4 and (slabs.size - 1) % 2 == 0 and slabs[-1] == nl.n_pairs
    touched = [set(nl.first[a:b]) | set(nl.second[a:b]) for a, b in pairwise(slabs)]
    for s in range(len(touched)):
        for t in range(s + 2, len(touched), 2):
            assert not touched[s] & touched[t], (s, t)
    x, typeid, shifts = np.ascontiguousarray(p.positions), model.typeid(p), nl.shifts(p.cell)
    walls_args = model.walls(p.cell)
    one = np.empty_like(x)
    e_one, c_one = energy_gradient_contacts(x, p.radii, typeid, shifts, nl, model, one, walls_args)
    results = []
    before = numba.get_num_threads()
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            g = np.empty_like(x)
            e, c = energy_gradient_contacts(
                x, p.radii, typeid, shifts, nl, model, g, walls_args, (slabs, True)
            )
            results.append((e, g))
            assert c == c_one
    finally:
        numba.set_num_threads(before)
    assert results[0][0] == pytest.approx(e_one, rel=1e-13)
    np.testing.assert_allclose(results[0][1], one, atol=1e-14 * np.abs(one).max())
    assert results[0][0] == results[1][0] and np.array_equal(results[0][1], results[1][1])
