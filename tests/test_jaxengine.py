"""The JAX engine (issue 37) against the numba engine, finite differences, brute-force twins and
the CPU minimizers; JAX's CPU build, as CI has."""

from __future__ import annotations

import importlib
import json
import os
import sys

import numpy as np
import pytest
import scipy.sparse.linalg as sla

from athermal.analysis.observables import stress
from athermal.engines.precon import ExpPreconditioner
from athermal.errors import InputError
from athermal.minimize._wolfe import GO_ON
from athermal.minimize.linesearch import strong_wolfe as cpu_search
from athermal.model.cell import simple_shear
from athermal.model.contact import ContactModel, find_contacts
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing
from athermal.relaxation import Minimizer, relax

je = pytest.importorskip("athermal.engines.jax.device")
from athermal.engines.jax import _precon, _search  # noqa: E402 (after the skip without JAX)


def on_device(packing: Packing, model: ContactModel, x: np.ndarray | None = None):
    """The JAX energy and gradient ``(N d,)`` of ``packing`` (at positions ``x``)."""
    typeid = np.asarray(model.typeid(packing), dtype=np.int64)
    positions = packing.positions if x is None else x
    pairs = je.device_pairs(
        positions, packing.radii, packing.cell, model, typeid, 0.1 * packing.radii.mean()
    )
    energy, grad = je.energy_gradient(je.jnp.asarray(positions), pairs.arrays, model.law)
    return float(energy), np.asarray(grad).ravel()


@pytest.mark.parametrize("alpha", [2.0, 2.5])
@pytest.mark.parametrize(
    ("dim", "phi", "sheared"), [(2, 0.88, False), (2, 0.88, True), (3, 0.7, False)]
)
def test_energy_and_gradient_match_the_numba_engine(alpha, dim, phi, sheared):
    packing = random_packing(128, phi, dim=dim, seed=3)
    if sheared:  # a tilted cell: images by the lattice of h, positions carried affinely
        packing = packing.deform(simple_shear(0.3, dim))
    model = ContactModel(alpha)
    energy, grad = Objective(packing, model, sort=False)(packing.positions.ravel())
    device_energy, device_grad = on_device(packing, model)
    assert device_energy == pytest.approx(energy, rel=1e-13)
    np.testing.assert_allclose(device_grad, grad, rtol=0.0, atol=1e-13 * np.abs(grad).max())


def test_gradient_matches_finite_differences():
    packing, model = random_packing(32, 0.9, seed=5), ContactModel(2.5)
    x = packing.positions.copy()
    _, grad = on_device(packing, model, x)
    rng = np.random.default_rng(0)
    for _ in range(5):
        u = rng.standard_normal(x.shape)
        h = 1e-6
        plus, _ = on_device(packing, model, x + h * u)
        minus, _ = on_device(packing, model, x - h * u)
        assert (plus - minus) / (2 * h) == pytest.approx(grad @ u.ravel(), rel=1e-6)


@pytest.mark.parametrize("sheared", [False, True])
def test_stress_and_contacts_match_the_observables(sheared):
    packing, model = random_packing(96, 0.9, seed=4), ContactModel(2.5)
    if sheared:
        packing = packing.deform(simple_shear(0.2))
    typeid = np.asarray(model.typeid(packing), dtype=np.int64)
    pairs = je.device_pairs(packing.positions, packing.radii, packing.cell, model, typeid, 0.05)
    sigma, count = je.stress_contacts(
        je.jnp.asarray(packing.positions), pairs.arrays, model.law, packing.cell.volume
    )
    contacts = find_contacts(packing, model)
    expected = stress(contacts, packing.cell)
    np.testing.assert_allclose(np.asarray(sigma), expected, rtol=1e-12, atol=1e-15)
    assert int(count) == contacts.i.size


def pair_set(first, second, shift, count, positions):
    """The pairs ``(i, j, |x_i - x_j + shift|)`` of a list, distances to 1e-10."""
    sep = positions[first[:count]] - positions[second[:count]] + shift[:count]
    lengths = np.sqrt(np.sum(sep * sep, axis=1))
    return sorted(
        (int(i), int(j), round(float(d), 10))
        for i, j, d in zip(first[:count], second[:count], lengths, strict=True)
    )


@pytest.mark.parametrize(
    ("dim", "phi", "shear"), [(2, 0.88, 0.0), (2, 0.88, 0.4), (2, 0.5, 1.0), (3, 0.6, 0.0)]
)
def test_the_device_cell_list_is_the_brute_force_list(dim, phi, shear):
    """In square and sheared cells, 2D and 3D, from unwrapped positions: the same pairs at the
    same distances as the O(N^2) search over images."""
    from athermal.engines.jax import _cells
    from athermal.model.neighbors import brute_force_pairs

    packing = random_packing(400, phi, dim=dim, seed=3)
    if shear:
        packing = packing.deform(simple_shear(shear, dim))
    packing = packing.with_positions(packing.positions + 3.7)  # several cells away
    model, skin = ContactModel(2.0), 0.3 * packing.radii.mean()
    nbins = _cells.bins_for(packing.cell, 2 * packing.radii.max() + skin)
    inputs = (packing.positions, packing.radii, model.typeid(packing), model.kmat, packing.cell.h)
    device = [je.jnp.asarray(a) for a in inputs]
    arrays, count, _, overflow = _cells.build_compiled(*device, skin, nbins, 32, 16384)
    assert not bool(overflow)
    first, second, shift = (np.asarray(a) for a in arrays[:3])
    found = pair_set(first, second, shift, int(count), packing.positions)
    expected = []
    for i, j, n in brute_force_pairs(packing.positions, packing.radii, packing.cell, skin):
        sep = packing.positions[i] - packing.positions[j] + np.asarray(n) @ packing.cell.h.T
        expected.append((i, j, round(float(np.linalg.norm(sep)), 10)))
    assert found == sorted(expected)


def test_an_overflowing_cell_list_is_built_again_never_used():
    """Capacities far too small: each build overflows, grows and builds again; the relaxation
    ends on the CPU engine's minimum with its energy."""
    model = ContactModel(2.0)
    relaxed = relax(random_packing(300, 0.86, seed=2), model, rtol=1e-12).packing
    start = relaxed.scale_radii(1.0 + 5e-5)
    objective = Objective(start, model)
    engine = je.Engine(objective)
    assert engine.nbins is not None
    engine.bin_capacity, engine.pair_capacity = 1, 16
    tol = objective.tolerance(None, 1e-9)
    result = engine.minimize("lbfgs", objective.x0, gtol=tol)
    assert engine.overflows >= 2 and result.converged
    cpu = relax(start, model, Minimizer("lbfgs"))
    assert result.energy == pytest.approx(cpu.energy, rel=1e-10)
    assert engine.pairs is not None and engine.pairs.count <= engine.pair_capacity


def test_a_small_cell_takes_the_host_list():
    from athermal.engines.jax import _cells

    packing = random_packing(16, 0.85, seed=1)
    assert (
        _cells.bins_for(packing.cell, 2 * packing.radii.max() + 0.5 * packing.radii.mean()) is None
    )
    device = relax(packing, ContactModel(2.0), Minimizer("lbfgs", backend="jax"))
    assert device.converged


def test_capacity_holds_a_tenth_more_pads_less_than_a_quarter_and_only_grows():
    for count in [1, 7, 100, 103, 999, 44_773, 1_000_003]:
        size = je.capacity_for(count)
        assert size >= 1.1 * count and (size <= 1.25 * count or size == 16)
        assert je.capacity_for(count, size) == size and je.capacity_for(count - 1, size) == size
        assert je.capacity_for(size + 1, size) > size


def test_the_line_search_is_the_compiled_one():
    """The same trials, end and code as the CPU engine's state machine on scalar functions
    that bracket, zoom, hit the step cap, lie below the round-off, reach zero energy and
    exhaust the budget."""
    feed = je.jax.jit(_search.feed)
    cases = [
        (lambda a: (-a, -1.0 + 0 * a), 1.0, np.inf, 0.0),  # 40 evaluations, no Wolfe step
        (lambda a: (max(1.0 - a, 0.0) ** 2, -2.0 * max(1.0 - a, 0.0)), 7.0, np.inf, 0.0),
        (lambda a: ((a - 1.3) ** 4 - 0.5 * a, 4 * (a - 1.3) ** 3 - 0.5), 0.05, np.inf, 0.0),
        (lambda a: ((a - 1.3) ** 4 - 0.5 * a, 4 * (a - 1.3) ** 3 - 0.5), 7.0, np.inf, 0.0),
        (lambda a: (-np.sin(3 * a) + 0.1 * a * a, -3 * np.cos(3 * a) + 0.2 * a), 0.3, 0.9, 0.0),
        (lambda a: (-a, -1.0 + 0 * a), 1.0, 2.5, 0.0),
        (lambda a: (1e-3 * (a - 2) ** 2 + 1.0, 2e-3 * (a - 2)), 1.0, np.inf, 1e-2),
    ]
    codes = []
    for phi, step, cap, noise in cases:
        f0, g0 = phi(0.0)
        trials: list[float] = []

        def recorded(a, phi=phi, trials=trials):
            trials.append(a)
            return phi(a)

        cpu = cpu_search(recorded, f0, g0, step, c2=0.9, step_max=cap, noise=noise)
        search = _search.begin(f0, g0, step, 0.9, cap, noise)
        device_trials = []
        while int(search.code) == GO_ON:
            device_trials.append(float(search.trial))
            f, df = phi(float(search.trial))
            search = feed(search, f, df)
        np.testing.assert_allclose(device_trials, trials, rtol=1e-12)
        assert float(search.end[0]) == pytest.approx(cpu.step, rel=1e-12)
        assert int(search.evaluations) == cpu.evaluations
        assert (int(search.code) == 1) == cpu.ok
        codes.append(int(search.code))
    assert codes[:2] == [2, 1] and 1 in codes[2:]  # exhausted; zero energy at once; Wolfe


@pytest.mark.parametrize("n", [256, 2048])
def test_the_device_preconditioner_is_a_fixed_spd_operator(n):
    """One V-cycle: symmetric, positive definite, within 25 % of the exact solve whatever N."""
    packing, model = random_packing(n, 0.88, seed=1), ContactModel(2.0)
    objective = Objective(packing, model)
    matrix = ExpPreconditioner(objective).assemble(objective.x0)
    hierarchy = _precon.Hierarchy.of(matrix, packing.positions, 1.0)
    rng = np.random.default_rng(0)
    g, v = rng.standard_normal((n, 2)), rng.standard_normal((n, 2))
    pg = np.asarray(_precon.apply(je.jnp.asarray(g), *hierarchy.arrays))
    pv = np.asarray(_precon.apply(je.jnp.asarray(v), *hierarchy.arrays))
    assert np.sum(pg * v) == pytest.approx(np.sum(pv * g), rel=1e-10)
    assert np.sum(pg * g) > 0.0 and np.sum(pv * v) > 0.0
    exact = sla.spsolve(matrix.tocsc(), g)
    assert np.linalg.norm(pg - exact) <= 0.25 * np.linalg.norm(exact)


@pytest.fixture(scope="module")
def table_like():
    """The paper's Case 1 at N = 1024: a relaxed packing grown by 1 + 5e-5, and the CPU
    engine's P-L-BFGS minimum to 1e-9 F0."""
    model = ContactModel(2.0)
    relaxed = relax(random_packing(1024, 0.86, seed=1), model, rtol=1e-12).packing
    start = relaxed.scale_radii(1.0 + 5e-5)
    return start, model, relax(start, model, Minimizer("plbfgs"))


@pytest.mark.parametrize("method", ["fire", "lbfgs", "plbfgs", "cg", "pcg"])
def test_every_device_minimizer_reaches_the_cpu_minimum(table_like, method):
    """To 1e-9 F0, the same minimum as the CPU engine to 1e-10 of the energy, the forces
    balanced by the CPU engine's own evaluation of the result."""
    start, model, cpu = table_like
    device = relax(start, model, Minimizer(method, backend="jax"))
    assert device.converged and device.max_gradient <= device.gtol
    assert device.energy == pytest.approx(cpu.energy, rel=1e-10)
    check = Objective(device.packing, model)
    energy, grad = check(check.x0)
    assert energy == pytest.approx(device.energy, rel=1e-12)
    assert check.max_gradient(grad) <= 1.01 * device.gtol
    assert device.history_energy.size == device.iterations + 1


@pytest.mark.parametrize("method", ["fire", "plbfgs", "pcg"])
def test_from_random_positions_the_lists_are_rebuilt_on_the_way(method):
    """Particles move far beyond the skin and the preconditioner's reach: both are rebuilt on
    the host, the loop goes on, and the end is a minimum by the CPU's own evaluation."""
    model = ContactModel(2.0)
    device = relax(random_packing(128, 0.88, seed=2), model, Minimizer(method, backend="jax"))
    assert device.converged and device.neighbor_rebuilds > 1
    if method != "fire":
        assert device.precon_builds > 1
    check = Objective(device.packing, model)
    energy, grad = check(check.x0)
    assert energy == pytest.approx(device.energy, rel=1e-12)
    assert check.max_gradient(grad) <= 1.01 * device.gtol


@pytest.mark.parametrize("method", ["plbfgs", "pcg"])
def test_the_device_preconditioner_is_the_same_from_run_to_run(method):
    """The V-cycle's hierarchy is pyamg's, whose setup draws a random vector: from a fixed seed
    (:func:`athermal.linalg.aggregation_hierarchy`), two runs rebuilding it on the way give the
    same bits."""
    model = ContactModel(2.0)
    start = random_packing(128, 0.88, seed=2)
    runs = [relax(start, model, Minimizer(method, backend="jax")) for _ in range(2)]
    assert runs[0].precon_builds > 1
    assert runs[0].iterations == runs[1].iterations and runs[0].energy == runs[1].energy
    np.testing.assert_array_equal(runs[0].packing.positions, runs[1].packing.positions)


def test_fire_on_an_engine_with_the_preconditioner_runs_without_it():
    """The hand-over of a failed line search: FIRE on the P-L-BFGS engine, from far away."""
    model = ContactModel(2.0)
    objective = Objective(random_packing(128, 0.88, seed=2), model)
    engine = je.Engine(objective, "exp")
    result = engine.minimize("fire", objective.x0, gtol=objective.tolerance(None, 1e-9))
    assert result.converged and engine.hierarchy is None


def test_polak_ribiere_cg_reaches_the_cpu_minimum(table_like):
    start, model, cpu = table_like
    objective = Objective(start, model)
    engine = je.Engine(objective, "exp")
    tol = objective.tolerance(None, 1e-9)
    result = engine.minimize("cg", objective.x0, gtol=tol, polak=True)
    assert result.converged and result.energy == pytest.approx(cpu.energy, rel=1e-10)


def test_an_error_in_a_batch_reaches_every_member_and_blocks_none(monkeypatch):
    from concurrent.futures import ThreadPoolExecutor

    def broken(self, chunk):
        raise RuntimeError("device lost")

    monkeypatch.setattr(je.Batcher, "_batched", broken)
    batcher = je.Batcher(3)
    how = Minimizer("lbfgs", backend="jax")

    def member(seed):
        with batcher.member():
            return relax(random_packing(32, 0.88, seed=seed), ContactModel(2.0), how)

    with ThreadPoolExecutor(3) as pool:
        futures = [pool.submit(member, seed) for seed in range(3)]
        for future in futures:
            with pytest.raises(RuntimeError, match="device lost"):
                future.result(timeout=120)


def test_an_unjammed_packing_ends_at_zero_energy():
    how = Minimizer("plbfgs", backend="jax")
    device = relax(random_packing(64, 0.5, seed=1), ContactModel(2.0), how)
    assert device.converged and device.energy == 0.0


@pytest.mark.parametrize(
    ("method", "precon"), [("newton", "none"), ("lbfgs", "contact"), ("fire", "exp")]
)
def test_what_the_engine_has_not_is_refused(method, precon):
    with pytest.raises(InputError, match="backend jax"):
        Minimizer(method, precon, backend="jax")


def test_without_jax_the_engine_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "jax", None)
    for name in [m for m in sys.modules if m.startswith("athermal.engines.jax.device")]:
        monkeypatch.delitem(sys.modules, name)
    with pytest.raises(InputError, match=r"JAX is not installed; pip install jax"):
        importlib.import_module("athermal.engines.jax.device")


def test_relax_backend_jax_on_the_command_line(tmp_path, capsys):
    from athermal.cli import main
    from athermal.io import write_gsd

    write_gsd(tmp_path / "r.gsd", random_packing(64, 0.88, seed=1))
    args = ["relax", str(tmp_path / "r.gsd"), "-o", str(tmp_path / "o.gsd"), "--json"]
    assert main([*args, "--method", "plbfgs", "--backend", "jax"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["method"] == "lbfgs (jax)" and out["converged"]
    assert out["max_gradient"] <= out["gtol"]
    written = (tmp_path / "o.gsd").read_bytes()
    assert main([*args, "--backend", "jax", "--method", "newton", "--overwrite"]) == 2
    assert "backend jax" in capsys.readouterr().err
    assert (tmp_path / "o.gsd").read_bytes() == written  # refused before any work


def test_jam_on_the_device_passes_the_jamming_checks(tmp_path, capsys):
    from athermal.cli import main

    out = tmp_path / "j.gsd"
    args = ["jam", "--n", "64", "--seed", "3", "-o", str(out), "--json", "--quiet"]
    assert main([*args, "--backend", "jax", "--method", "plbfgs"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["checks_passed"] and report["method"] == "lbfgs+exp/jax"
    assert 0.80 < report["phi_c"] < 0.87


@pytest.mark.parametrize("command", ["relax", "jam"])
def test_backend_jax_without_jax_is_refused_at_the_door(tmp_path, capsys, monkeypatch, command):
    import importlib.util

    from athermal.cli import main
    from athermal.io import write_gsd

    write_gsd(tmp_path / "r.gsd", random_packing(64, 0.88, seed=1))
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "jax" else real(name, *a)
    )
    out = tmp_path / "o.gsd"
    first = [str(tmp_path / "r.gsd")] if command == "relax" else ["--n", "64"]
    assert main([command, *first, "-o", str(out), "--backend", "jax"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "JAX is not installed; pip install jax" in err[0]
    assert not out.exists()


def test_a_batch_relaxes_each_member_as_alone(table_like):
    """Four threads relax four packings through one Batcher: fewer device calls than member
    loops, and each member ends on the minimum it reaches alone."""
    from concurrent.futures import ThreadPoolExecutor

    start, model, _ = table_like
    rng = np.random.default_rng(7)
    a = 1e-4 * start.radii.mean()
    shape = start.positions.shape
    starts = [start.with_positions(start.positions + rng.uniform(-a, a, shape)) for _ in range(4)]
    how = Minimizer("plbfgs", backend="jax")
    alone = [relax(s, model, how) for s in starts]
    batcher = je.Batcher(4)

    def member(s):
        with batcher.member():
            return relax(s, model, how)

    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(member, starts))
    assert batcher.members >= 4 and batcher.calls < batcher.members
    for one, batched in zip(alone, together, strict=True):
        assert batched.converged and batched.max_gradient <= batched.gtol
        assert batched.energy == pytest.approx(one.energy, rel=1e-10)


def test_ensemble_batch_on_the_device_passes_the_jamming_checks(tmp_path, capsys):
    from athermal.cli import main

    args = ["ensemble", "jam", "--realizations", "3", "--n", "48", "-o", str(tmp_path / "e")]
    assert main([*args, "--backend", "jax", "--batch", "3", "--json", "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["summary"]["checks_passed"] == 3 and "batches of 3" in out["engine"]
    assert main([*args, "--backend", "jax", "--batch", "3", "--json", "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["computed"] == []  # resumed: nothing to do


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--batch", "4"], "--backend jax"),
        (["--batch", "4", "--backend", "jax", "--workers", "2"], "drop workers"),
        (["--batch", "100000000", "--backend", "jax", "--n", "100000"], "GiB of device memory"),
    ],
)
def test_a_batch_that_cannot_run_is_refused_at_the_door(tmp_path, capsys, extra, message):
    from athermal.cli import main

    out = tmp_path / "e"
    assert main(["ensemble", "jam", "--realizations", "2", "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not out.exists()


def test_jam_at_a_pressure_on_the_device(tmp_path, capsys):
    from athermal.cli import main

    out = tmp_path / "p.gsd"
    args = ["jam", "--n", "48", "--seed", "2", "-o", str(out), "--json", "--quiet"]
    assert main([*args, "--backend", "jax", "--pressure", "1e-3"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["pressure"] == pytest.approx(1e-3, rel=2e-3) and report["checks_passed"]


def test_deterministic_asks_xla_for_its_deterministic_scatter(tmp_path, capsys, monkeypatch):
    """``--deterministic`` sets XLA's flag before JAX starts (it is refused without
    ``--backend jax``: the numba engine is the same bits everywhere already)."""
    from athermal.cli import main
    from athermal.engines.jax import DETERMINISTIC_OPS

    start = str(tmp_path / "p.gsd")
    assert main(["random", "--n", "64", "--phi", "0.86", "-o", start]) == 0
    argv = ["relax", start, "-o", str(tmp_path / "r.gsd"), "--deterministic"]
    assert main(argv) == 2
    assert "--deterministic: only with --backend jax" in capsys.readouterr().err
    monkeypatch.setenv("XLA_FLAGS", "")
    assert main([*argv, "--backend", "jax", "--method", "plbfgs"]) == 0
    assert os.environ["XLA_FLAGS"] == DETERMINISTIC_OPS
