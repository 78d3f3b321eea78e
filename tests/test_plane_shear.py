"""Frozen particles and plane shear between rough walls: no minimizer moves a frozen particle,
the decoupled solves against their principal-submatrix twins, the pinned stability test on an
analytic case, the walls' shear tractions against each other and against the energy's
derivative, resumption, and the refusals."""

import json

import numpy as np
import pytest
import scipy.sparse as sp

from athermal.analysis.moduli import stability
from athermal.cli import main
from athermal.errors import InputError
from athermal.io import count_frames, read_gsd
from athermal.linalg import pin_rows
from athermal.model.cell import Cell
from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing
from athermal.protocols.shear import plane_tractions, rough_walls, shear_steps
from athermal.relaxation import Minimizer, Relaxer, minimize_objective, relax, relax_objective

MODEL = ContactModel(2.0)


def between_walls(n=128, phi=0.9, seed=3, dim=2):
    axis = "y" if dim == 2 else "z"
    return random_packing(
        n, phi if dim == 2 else 0.7, dim=dim, seed=seed, cell=Cell.unit(dim, axis)
    )


def relaxed_between_walls(n=160, phi=0.88, seed=5, dim=2):
    """A random packing between walls relaxed to balance (jammed above phi_c)."""
    result = relax(between_walls(n, phi, seed, dim), MODEL, Minimizer("newton"), gtol=1e-14)
    assert result.converged
    return result.packing


def sheared_start(n=128, seed=3):
    """A packing between walls normal to y with its upper layer moved along x: far from balance,
    so every minimizer has work to do."""
    p = between_walls(n, seed=seed)
    lower, upper = rough_walls(p)
    frozen = lower | upper
    positions = p.positions.copy()
    positions[upper, 0] += 0.02
    return Packing(positions, p.radii, p.cell), frozen


@pytest.mark.parametrize(
    "method, precon, solver",
    [
        ("lbfgs", "none", "auto"),
        ("cg", "none", "auto"),
        ("fire", "none", "auto"),
        ("newton", "none", "auto"),
        ("lbfgs", "exp", "ic0"),
        ("lbfgs", "exp", "direct"),
        ("cg", "exp", "amg"),
        ("lbfgs", "contact", "direct"),
        ("fire", "exp", "auto"),
    ],
)
def test_no_minimizer_moves_a_frozen_particle(method, precon, solver):
    p, frozen = sheared_start()
    objective = Objective(p, MODEL, frozen=frozen)
    result = minimize_objective(objective, method, precon=precon, solver=solver, gtol=1e-12)
    assert result.converged
    q = result.packing
    np.testing.assert_array_equal(q.positions[frozen], p.positions[frozen])
    assert not np.array_equal(q.positions[~frozen], p.positions[~frozen])
    # the free particles balanced; the frozen ones carry the walls' load
    grad = Objective(q, MODEL)(Objective(q, MODEL).x0)[1].reshape(-1, 2)
    order = Objective(q, MODEL).order
    full = np.empty_like(grad)
    full[order] = grad
    assert np.abs(full[~frozen]).max() <= 1e-12 * np.sqrt(2)
    assert np.abs(full[frozen]).max() > 1e-6


def test_the_relaxers_hand_overs_keep_the_frozen_particles(monkeypatch):
    """Newton's hand-over to P-L-BFGS after its patience and the saddle escapes go through the
    same objective: with one Newton iteration allowed, the rest is P-L-BFGS's."""
    import athermal.relaxation as relaxation

    monkeypatch.setattr(relaxation, "NEWTON_PATIENCE", 1)
    p, frozen = sheared_start(seed=4)
    objective = Objective(p, MODEL, frozen=frozen)
    result, _ = Relaxer(objective, Minimizer("newton")).relax_to_minimum(objective.x0, gtol=1e-11)
    assert result.converged and result.method.startswith("newton+lbfgs")
    np.testing.assert_array_equal(result.packing.positions[frozen], p.positions[frozen])


def test_pin_rows_solves_as_the_principal_submatrix():
    rng = np.random.default_rng(1)
    a = sp.random(30, 30, density=0.2, random_state=2)
    m = (a @ a.T + sp.identity(30)).tocsr()
    rows = np.array([0, 7, 8, 29])
    pinned = pin_rows(m, rows)
    b = rng.normal(size=30)
    b[rows] = 0.0
    x = np.linalg.solve(pinned.toarray(), b)
    free = np.setdiff1d(np.arange(30), rows)
    np.testing.assert_array_equal(x[rows], 0.0)
    np.testing.assert_allclose(
        x[free], np.linalg.solve(m.toarray()[np.ix_(free, free)], b[free]), rtol=1e-12
    )
    np.testing.assert_allclose(pinned.toarray(), pinned.toarray().T)


def test_stability_pins_the_frozen_particles():
    """A compressed square lattice is a saddle (each contact's tangential term -f/l); one disk
    whose four neighbours are frozen is stable: its block is 2 k I (alpha = 2)."""
    g = (np.arange(4) + 0.5) / 4
    square = Packing(
        np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), np.full(16, 0.13), Cell.box([1.0, 1.0])
    )
    assert not stability(square, MODEL).stable
    one_free = np.ones(16, dtype=bool)
    one_free[5] = False
    check = stability(square, MODEL, one_free)
    assert check.stable
    bottom_row = np.zeros(16, dtype=bool)
    bottom_row[:4] = True
    check = stability(square, MODEL, bottom_row)
    assert not check.stable
    assert check.mode is not None and not check.mode[bottom_row].any()


@pytest.fixture(scope="module")
def plane_run():
    relaxed = relaxed_between_walls()
    steps = list(shear_steps(relaxed, MODEL, mode="plane", strain=3e-3, step=1e-3, rtol=1e-12))
    return relaxed, steps


def test_plane_shear_moves_the_upper_wall_and_balances_the_tractions(plane_run):
    relaxed, steps = plane_run
    lower, upper = rough_walls(relaxed)
    width = relaxed.cell.h[1, 1]
    for s in steps:
        q = s.packing
        np.testing.assert_array_equal(q.positions[lower], relaxed.positions[lower])
        np.testing.assert_allclose(
            q.positions[upper, 0] - relaxed.positions[upper, 0], s.strain * width, atol=1e-15
        )
        np.testing.assert_array_equal(q.positions[upper, 1], relaxed.positions[upper, 1])
        t = plane_tractions(q, MODEL, lower, upper)
        assert s.tau == pytest.approx(0.5 * (t[0, 0] - t[1, 0]), rel=1e-15)
        # the free particles balanced: the walls' tractions opposite, shear and normal
        np.testing.assert_allclose(t[0], -t[1], rtol=0, atol=1e-8 * t[1, 1])
        # the normal stress on the walls: near the pressure of the packing
        assert t[1, 1] == pytest.approx(s.observables.pressure, rel=0.3)
    assert steps[0].tau == pytest.approx(0.0, abs=1e-10 * steps[0].observables.pressure)
    assert all(s.tau > 0 for s in steps[1:])


def test_plane_shear_stress_is_the_energys_derivative(plane_run):
    """tau V = dE/dgamma of the relaxed energy (the upper wall's work), by central
    differences over two small steps of an elastic branch."""
    relaxed, steps = plane_run
    h = 1e-6
    around = list(
        shear_steps(steps[1].packing, MODEL, mode="plane", strain=2 * h, step=h, rtol=1e-13)
    )
    assert not any(s.plastic for s in around)
    derivative = (around[2].observables.energy - around[0].observables.energy) / (2 * h)
    assert around[1].tau * relaxed.cell.volume == pytest.approx(derivative, rel=1e-4)


def test_plane_shear_resumes_bit_for_bit(plane_run):
    relaxed, _ = plane_run
    full = list(shear_steps(relaxed, MODEL, mode="plane", strain=3e-3, step=1e-3))
    rest = list(shear_steps(relaxed, MODEL, mode="plane", strain=3e-3, step=1e-3, resume=full[:2]))
    for a, b in zip(full[2:], rest, strict=True):
        np.testing.assert_array_equal(a.packing.positions, b.packing.positions)
        timed, again = a.row(), b.row()
        assert timed.pop("seconds") > 0 and again.pop("seconds") > 0
        assert timed == again


def test_plane_shear_in_3d():
    start = relaxed_between_walls(96, 0.7, seed=2, dim=3)
    steps = list(shear_steps(start, MODEL, mode="plane", strain=2e-3, step=1e-3, rtol=1e-11))
    lower, upper = rough_walls(start)
    t = plane_tractions(steps[-1].packing, MODEL, lower, upper)
    np.testing.assert_allclose(t[0], -t[1], rtol=0, atol=1e-6 * t[1, 2])
    assert steps[-1].tau > steps[0].tau


def test_plane_shear_refusals():
    with pytest.raises(InputError, match="walls normal to one axis other than x"):
        next(shear_steps(random_packing(32, 0.9), MODEL, mode="plane"))
    for axes in ("x", "xy"):
        p = random_packing(32, 0.9, cell=Cell.unit(2, axes))
        with pytest.raises(InputError, match="plane shear"):
            next(shear_steps(p, MODEL, mode="plane"))
    p = between_walls(64)
    for layer in (1e-6, 0.6):
        with pytest.raises(InputError, match="wall_layer"):
            next(shear_steps(p, MODEL, mode="plane", wall_layer=layer))
    with pytest.raises(InputError, match="only plane shear"):
        next(shear_steps(p, MODEL, mode="pure", wall_layer=0.1))
    with pytest.raises(InputError, match="plane shear"):
        rough_walls(random_packing(32, 0.9))
    with pytest.raises(InputError, match="frozen"):
        Objective(p, MODEL, frozen=np.ones(64, dtype=bool))
    with pytest.raises(InputError, match="frozen"):
        Objective(p, MODEL, frozen=np.ones(63, dtype=bool))


def test_plane_shear_on_the_command_line(tmp_path, capsys):
    start = tmp_path / "start.gsd"
    assert main(["random", "--n", "96", "--phi", "0.9", "--walls", "y", "-o", str(start)]) == 0
    out = tmp_path / "plane.gsd"
    argv = ["shear", str(start), "-o", str(out), "--mode", "plane", "--strain", "2e-3"]
    capsys.readouterr()
    assert main([*argv, "--step", "1e-3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["mode"] == "plane" and report["steps"] == 3
    assert count_frames(out) == 3 and read_gsd(out).packing.cell.walls == (1,)
    # every frame marks the glued particles, never rattlers
    import gsd.hoomd

    lower, upper = rough_walls(read_gsd(start).packing)
    with gsd.hoomd.open(str(out)) as traj:
        for frame in traj:
            glued = frame.log["particles/glued"].astype(bool)
            np.testing.assert_array_equal(glued, lower | upper)
            assert not (frame.log["particles/rattler"].astype(bool) & glued).any()
    # refused at the door, nothing written
    bad = tmp_path / "bad.gsd"
    for extra in (["--wall-layer", "0.7"], ["--wall-layer", "-1"]):
        assert main([*argv[:3], str(bad), *argv[4:], *extra]) == 2
        assert not bad.exists()
    assert main(["shear", str(start), "-o", str(bad), "--mode", "pure", "--wall-layer", "0.1"]) == 2
    assert not bad.exists()


def test_the_jax_engine_refuses_frozen_particles():
    pytest.importorskip("jax")
    p = random_packing(32, 0.9)
    frozen = np.zeros(32, dtype=bool)
    frozen[:4] = True
    objective = Objective(p, MODEL, frozen=frozen)
    with pytest.raises(InputError, match="holds no particle fixed"):
        relax_objective(objective, Minimizer("lbfgs", backend="jax"), rtol=1e-9)
