"""Vibrational modes: the analytic spectrum of a triangular crystal, d zero modes and no negative
one at a minimum, a saddle's negative mode, dense against shift-invert (at a saddle too, below
the contacts' Hessian floor), D(omega), omega* and its bootstrap error on spectra with a known
edge, and `athermal modes`."""

import json
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from athermal.analysis.modes import (
    density_of_states,
    plateau_edge,
    plateau_frequency,
    vibrational_modes,
)
from athermal.analysis.moduli import (
    lowest_eigenpairs,
    nonrattler_contacts,
    nonrattler_hessian,
    stiffness_matrix,
)
from athermal.cli import main
from athermal.errors import InputError
from athermal.io import write_gsd
from athermal.model.cell import Cell
from athermal.model.contact import ContactModel, hessian, hessian_floor
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing
from athermal.relaxation import minimize_objective


def relaxed(n, phi, dim, seed):
    model = ContactModel()
    packing = random_packing(n, phi, dim=dim, seed=seed)
    return minimize_objective(
        Objective(packing, model), "lbfgs", precon="exp", rtol=1e-12
    ).packing, model


@pytest.fixture(scope="module")
def packing_2d():
    return relaxed(256, 0.88, 2, 1)


def triangular(nx, ny, radius):
    """A triangular crystal of spacing 1 in its periodic rectangular cell (ny even)."""
    rows = [[(i + 0.5 * (j % 2), j * np.sqrt(3) / 2) for i in range(nx)] for j in range(ny)]
    cell = Cell.box([float(nx), ny * np.sqrt(3) / 2])
    return Packing(np.array(rows).reshape(-1, 2), np.full(nx * ny, radius), cell)


def test_a_compressed_triangular_crystal_has_its_lattice_dynamics_spectrum():
    """Unit masses, six contacts a at spacing 1 with overlap delta: the dynamical matrix
    D(q) = sum_a K_a (1 - cos q.a), K = k n n^T - k delta (I - n n^T), over the N wave vectors
    of the cell."""
    nx, ny, radius, k = 6, 4, 0.52, 1.0
    modes = vibrational_modes(triangular(nx, ny, radius), ContactModel(2.0, k))
    delta = 2 * radius - 1.0
    bonds = [np.array([np.cos(t), np.sin(t)]) for t in np.arange(6) * np.pi / 3]
    lx, ly = nx, ny * np.sqrt(3) / 2
    expected = []
    for i in range(nx):
        for j in range(ny):
            q = 2 * np.pi * np.array([i / lx, j / ly])
            dyn = sum(
                (k * np.outer(a, a) - k * delta * (np.eye(2) - np.outer(a, a)))
                * (1 - np.cos(q @ a))
                for a in bonds
            )
            expected.extend(np.linalg.eigvalsh(dyn))
    np.testing.assert_allclose(modes.eigenvalues, np.sort(expected), atol=1e-12)
    assert modes.zero_modes == 2 and modes.negative_modes == 0 and modes.n_rattlers == 0


@pytest.mark.parametrize(("dim", "n"), [(2, 256), (3, 512)])
def test_a_minimum_has_d_zero_modes_the_translations_and_no_negative_one(dim, n):
    packing, model = relaxed(n, 0.88 if dim == 2 else 0.68, dim, 2)
    modes = vibrational_modes(packing, model)
    assert modes.zero_modes == dim and modes.negative_modes == 0 and modes.complete
    assert modes.frequencies.size == modes.dofs - dim
    h, dofs, rattler = stiffness_matrix(packing, model)
    assert modes.dofs == h.shape[0] == dim * int((~rattler).sum())
    # eigenpairs of the stiffness matrix, unit vectors, nothing on the rattlers
    u = modes.vectors.reshape(modes.vectors.shape[0], -1)
    assert np.all(u[:, ~np.isin(np.arange(u.shape[1]), dofs)] == 0)
    residual = h @ u[:, dofs].T - u[:, dofs].T * modes.eigenvalues
    assert np.abs(residual).max() < 1e-12 * np.abs(h.diagonal()).max()
    np.testing.assert_allclose(u @ u.T, np.eye(u.shape[0]), atol=1e-10)
    # the zero modes span the translations, which move every particle alike: ratio 1
    zero = u[:dim, dofs]
    for axis in range(dim):
        shift = np.zeros((dofs.size // dim, dim))
        shift[:, axis] = 1.0
        t = shift.ravel() / np.linalg.norm(shift)
        assert np.linalg.norm(zero @ t) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(modes.participation[:dim], 1.0, atol=1e-9)
    assert np.all((modes.participation > 0) & (modes.participation <= 1 + 1e-12))


def test_shift_invert_gives_the_lowest_of_the_dense_spectrum(packing_2d):
    packing, model = packing_2d
    dense = vibrational_modes(packing, model)
    lowest = vibrational_modes(packing, model, 12, vectors=4)
    scale = np.abs(dense.eigenvalues).max()  # both accurate to round-off of the largest
    np.testing.assert_allclose(lowest.eigenvalues[2:], dense.eigenvalues[2:12], atol=1e-10 * scale)
    again = vibrational_modes(packing, model, 12, vectors=4)
    np.testing.assert_array_equal(again.eigenvalues, lowest.eigenvalues)  # reproducible
    assert not lowest.complete and lowest.zero_modes == 2
    np.testing.assert_array_equal(lowest.vector_index, [2, 3, 4, 5])
    for a, b in zip(lowest.vectors, dense.vectors[2:6], strict=True):
        assert abs(np.sum(a * b)) == pytest.approx(1.0, abs=1e-6)  # the same modes, up to sign


def test_a_saddle_has_a_negative_mode():
    g = (np.arange(4) + 0.5) / 4
    square = Packing(
        np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), np.full(16, 0.13), Cell.box([1.0, 1.0])
    )  # compressed square lattice: f = 0.01, l = 0.25
    modes = vibrational_modes(square, ContactModel(2.0))
    assert modes.negative_modes > 0 and modes.eigenvalues[0] == pytest.approx(-0.16)


def test_shift_invert_gives_the_lowest_of_a_saddle_whose_negative_modes_spread():
    """Shift-invert about -tolerance finds the eigenvalues nearest it: at a saddle, the least
    negative ones. Below every eigenvalue (the contacts' floor) it finds the lowest."""
    g = (np.arange(10) + 0.5) / 10
    grid = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    jitter = np.random.default_rng(3).uniform(-5e-4, 5e-4, grid.shape)
    square = Packing(grid + jitter, np.full(100, 0.055), Cell.box([1.0, 1.0]))
    model = ContactModel(2.0)
    dense = vibrational_modes(square, model)
    assert dense.negative_modes > 20  # down to ~ -f/l (I - n n^T) summed over a particle
    lowest = vibrational_modes(square, model, 6)
    scale = np.abs(dense.eigenvalues).max()
    np.testing.assert_allclose(lowest.eigenvalues, dense.eigenvalues[:6], atol=1e-10 * scale)
    contacts, rattler = nonrattler_contacts(square, model)
    floor = hessian_floor(contacts, square.n)
    assert floor <= dense.eigenvalues[0]
    h, _ = nonrattler_hessian(contacts, rattler, 2)
    straight, _ = lowest_eigenpairs(h, 6, floor, saddle=True)  # no try at -tolerance first
    np.testing.assert_allclose(straight, dense.eigenvalues[:6], atol=1e-10 * scale)
    loose, _ = lowest_eigenpairs(h, 6)  # below Gershgorin's bound of h
    np.testing.assert_allclose(loose, dense.eigenvalues[:6], atol=1e-10 * scale)


def test_the_hessian_floor_lies_below_every_eigenvalue(packing_2d):
    """Compressed (the pre-stress lowers the transverse terms) and pulled apart (a spring in
    tension: a negative overlap, as the certified bisection's networks hold)."""
    packing, model = packing_2d
    contacts, rattler = nonrattler_contacts(packing, model)
    h, _ = stiffness_matrix(packing, model)[:2]
    floor = hessian_floor(contacts, packing.n)
    assert floor < 0.0 and floor <= np.linalg.eigvalsh(h.toarray())[0]
    pulled = replace(contacts, overlap=-contacts.overlap)  # every spring in tension
    assert hessian_floor(pulled, packing.n) <= 0.0
    live = np.flatnonzero(~rattler)
    dofs = (live[:, None] * 2 + np.arange(2)).ravel()
    tense = hessian(pulled, packing.n)[dofs][:, dofs].toarray()
    assert hessian_floor(pulled, packing.n) <= np.linalg.eigvalsh(tense)[0] + 1e-12


def test_the_density_of_states_is_normalised_and_omega_star_of_a_gap_is_twice_its_edge():
    rng = np.random.default_rng(4)
    omega = np.concatenate([rng.uniform(0.05, 2.0, 20_000), rng.uniform(0.001, 0.05, 20)])
    edges, density = density_of_states(omega)
    assert np.sum(density * np.diff(edges)) == pytest.approx(1.0)
    # a flat D above an (almost) empty gap: the mean density below omega is half the plateau
    # at twice the gap's edge
    assert plateau_frequency(omega) == pytest.approx(0.1, rel=0.05)
    with pytest.raises(InputError, match="at least two frequencies"):
        density_of_states(np.array([1.0]))


def spectrum(m, omega_star, seed=None):
    """``m`` frequencies drawn from D ~ omega / omega_star below omega_star (Debye in 2D), flat
    up to 1.2, then 1.6x higher up to 2.4 (the band's peak): omega* = omega_star exactly. With
    no seed, the ``m`` quantiles ``(k - 1/2) / m`` of that density (no sampling noise)."""
    grid = np.linspace(0.0, 2.4, 240_001)
    density = np.where(grid < omega_star, grid / omega_star, np.where(grid < 1.2, 1.0, 1.6))
    cdf = np.concatenate([[0.0], np.cumsum((density[1:] + density[:-1]) / 2)])
    if seed is None:
        u = (np.arange(m) + 0.5) / m
    else:
        u = np.random.default_rng(seed).uniform(0.0, 1.0, m)
    return np.interp(u * cdf[-1], cdf, grid)


def test_omega_star_of_the_quantiles_of_a_known_density_is_its_edge():
    for star in (0.02, 0.05, 0.2):
        assert plateau_frequency(spectrum(4000, star)) == pytest.approx(star, rel=2e-3)


def test_omega_star_of_a_known_edge_lies_within_its_error_bar():
    edges = [plateau_edge(spectrum(2000, 0.05, seed), resamples=200) for seed in range(30)]
    star = np.array([e.omega_star for e in edges])
    error = np.array([e.error for e in edges])
    assert np.mean(star) == pytest.approx(0.05, rel=0.15)
    # a calibrated one-sigma error: ~68% of the draws within it, ~95% within twice it
    # (measured 0.7 and 0.9), and the scatter of omega* over the draws (measured 1.0x)
    assert np.mean(np.abs(star - 0.05) <= error) >= 0.5
    assert np.mean(np.abs(star - 0.05) <= 2 * error) >= 0.8
    assert 0.7 < np.mean(error) / np.std(star) < 1.4
    assert all(e.plateau == pytest.approx(1 / (1.2 - 0.025 + 1.6 * 1.2), rel=0.1) for e in edges)


def test_the_error_of_omega_star_shrinks_with_more_modes():
    few, many = (plateau_edge(spectrum(m, 0.05, 1), resamples=200) for m in (1000, 16_000))
    assert many.error < 0.4 * few.error  # 1 / sqrt(16) expected
    # the modes below the edge: (0.05 / 2) / (1.2 - 0.025 + 1.6 x 1.2) of them
    assert many.modes_below == pytest.approx(16_000 * 0.025 / 3.095, rel=0.15)


def test_omega_star_ignores_an_empty_bin_and_a_lone_soft_mode():
    omega = spectrum(2000, 0.05, 2)
    edges, density = density_of_states(omega)
    b = int(np.searchsorted(edges, 0.12)) - 1  # a bin on the plateau, above omega*
    emptied = omega[(omega < edges[b]) | (omega >= edges[b + 1])]
    assert density_of_states(emptied)[1][b] == 0.0 < density[b]
    lone = np.append(omega, 1e-3)  # one soft mode a decade and a half below the rest
    full = plateau_edge(omega)
    # a histogram's lowest bin (the lone mode) or its empty one set the old omega*; the count
    # only moves by the one mode more below omega*
    for changed, moved in ((emptied, 0.05), (lone, 0.5)):
        edge = plateau_edge(changed)
        assert abs(edge.omega_star - 0.05) <= 2 * edge.error
        assert edge.omega_star == pytest.approx(full.omega_star, abs=moved * full.error)


def test_omega_star_and_its_error_are_reproducible():
    omega = spectrum(2000, 0.05, 3)
    edge = plateau_edge(omega)
    assert plateau_edge(omega) == edge and edge.seed == 0
    assert edge.omega_star == plateau_frequency(omega)
    other = plateau_edge(omega, seed=1)
    assert other.omega_star == edge.omega_star and other.error != edge.error
    assert other.error == pytest.approx(edge.error, rel=0.2)
    with pytest.raises(InputError, match="resamples"):
        plateau_edge(omega, resamples=1)


def test_omega_star_rises_with_compression():
    low = plateau_edge(vibrational_modes(*relaxed(512, 0.85, 2, 3)).frequencies)
    high = plateau_edge(vibrational_modes(*relaxed(512, 0.95, 2, 3)).frequencies)
    # omega* ~ z - z_iso (Wyart et al. 2005): measured over seeds 3 and 4, each relaxed with the
    # exact and the incomplete factor, z - z_iso rose 3.0-4.2x; omega* rises beyond both errors
    assert high.omega_star - high.error > low.omega_star + low.error


def test_the_full_spectrum_is_refused_beyond_the_dense_limit(packing_2d, monkeypatch):
    import athermal.analysis.modes

    monkeypatch.setattr(athermal.analysis.modes, "DENSE_MODES_DOFS", 100)
    with pytest.raises(InputError, match="ask for the lowest k"):
        vibrational_modes(*packing_2d)
    with pytest.raises(InputError, match="k: need an integer"):
        vibrational_modes(*packing_2d, 0)


def test_the_modes_command_writes_the_modes_and_the_figure(packing_2d, tmp_path, capsys):
    packing, model = packing_2d
    write_gsd(tmp_path / "p.gsd", packing, model=model)
    out = tmp_path / "m.npz"
    assert main(["modes", str(tmp_path / "p.gsd"), "-o", str(out), "--vectors", "3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["zero_modes"] == 2 and report["negative_modes"] == 0
    assert report["omega_star"] > 0 and (tmp_path / "m.png").stat().st_size > 10_000
    assert 0 < report["omega_star_err"] and report["plateau_density"] > 0
    data = np.load(out)
    assert data["omega_star"] == report["omega_star"] and data["bootstrap_seed"] == 0
    assert data["omega_star_err"] == report["omega_star_err"]
    assert data["omega_star_modes"] == report["omega_star_modes"]
    assert data["vectors"].shape == (3, packing.n, 2) and data["eigenvalues"].size == report["dofs"]
    assert np.sum(data["dos"] * np.diff(data["dos_edges"])) == pytest.approx(1.0)
    # --seed: another bootstrap, the same omega*; the seed is recorded
    other = tmp_path / "s.npz"
    argv = ["modes", str(tmp_path / "p.gsd"), "-o", str(other), "--seed", "7", "--json"]
    assert main([*argv, "--figure", "none"]) == 0
    seeded = json.loads(capsys.readouterr().out)
    assert seeded["bootstrap_seed"] == 7 and np.load(other)["bootstrap_seed"] == 7
    assert seeded["omega_star"] == report["omega_star"]
    assert seeded["omega_star_err"] != report["omega_star_err"]
    for argv, message in (
        ([], "exists; replace it with --overwrite"),
        (["--lowest", "5", "--figure", "x.png"], "needs the full spectrum"),
        (["--lowest", "5", "--vectors", "6"], "exceeds --lowest"),
    ):
        assert main(["modes", str(tmp_path / "p.gsd"), "-o", str(out), *argv]) == 2
        assert message in capsys.readouterr().err
    assert main(["modes", str(tmp_path / "p.gsd"), "-o", str(tmp_path / "m.txt")]) == 2
    assert ".npz" in capsys.readouterr().err


def test_lobpcg_near_a_factor_finds_the_negative_mode_a_change_made():
    """A stable network's Hessian less a rank-one term: one negative eigenvalue, found by LOBPCG
    preconditioned with the stable Hessian's factor as the dense spectrum has it, its residual
    within the tolerance (too few iterations give None), and so with the factor of the
    Hessian with one particle pinned, the translations held out."""
    from athermal.analysis.modes import lowest_eigenpair_near
    from athermal.linalg import cholesky

    packing, model = relaxed(64, 0.9, 2, 1)
    contacts, rattler = nonrattler_contacts(packing, model)
    h0, _ = nonrattler_hessian(contacts, rattler, 2)
    dense, modes = np.linalg.eigh(h0.toarray())  # two translations, then the lowest mode
    v = modes[:, 2] + 0.1 * modes[:, 5]
    v /= np.linalg.norm(v)
    h = sp.csr_matrix(h0 - 2.0 * dense[2] * np.outer(v, v))
    want = np.linalg.eigh(h.toarray())
    assert want[0][0] < -0.5 * dense[2]
    factor = cholesky((h0 + 1e-3 * dense[2] * sp.identity(h0.shape[0])).tocsr())
    tolerance = 1e-9 * dense[-1]
    value, vector = lowest_eigenpair_near(h, factor, tolerance, 100)
    assert value == pytest.approx(want[0][0], abs=tolerance)
    assert abs(vector @ want[1][:, 0]) == pytest.approx(1.0, abs=1e-6)
    assert np.linalg.norm(h @ vector - value * vector) <= tolerance
    assert lowest_eigenpair_near(h, factor, tolerance, 1) is None
    # the factor of the Hessian with its first particle pinned, the translations held out
    rows = np.arange(2, h0.shape[0])
    pinned = cholesky(h0[rows][:, rows].tocsr())
    translations = np.zeros((h0.shape[0], 2))
    translations[np.arange(h0.shape[0]), np.arange(h0.shape[0]) % 2] = np.sqrt(2 / h0.shape[0])
    value, vector = lowest_eigenpair_near(h, pinned, tolerance, 100, rows=rows, null=translations)
    assert value == pytest.approx(want[0][0], abs=tolerance)
    assert abs(vector @ want[1][:, 0]) == pytest.approx(1.0, abs=1e-6)
