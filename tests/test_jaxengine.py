"""The JAX engine (issue 37, first part) against the numba engine, finite differences and the
CPU minimizers; JAX's CPU build, as CI has."""

from __future__ import annotations

import importlib
import sys

import numpy as np
import pytest

from athermal.cell import simple_shear
from athermal.contact import ContactModel
from athermal.errors import InputError
from athermal.objective import Objective
from athermal.packing import Packing, random_packing
from athermal.relaxation import Minimizer, relax

je = pytest.importorskip("athermal.jaxengine")


def on_device(packing: Packing, model: ContactModel, x: np.ndarray | None = None):
    """The JAX energy and gradient ``(N d,)`` of ``packing`` (at positions ``x``)."""
    typeid = np.asarray(model.typeid(packing), dtype=np.int64)
    positions = packing.positions if x is None else x
    pairs = je.device_pairs(positions, packing, model, typeid, 0.1 * packing.radii.mean())
    arrays = (pairs.first, pairs.second, pairs.shift, pairs.radius_sum, pairs.stiffness)
    energy, grad = je.energy_gradient(je.jnp.asarray(positions), *arrays, float(model.alpha))
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


def test_capacity_grows_by_powers_of_two_and_only_grows():
    assert je.capacity_for(100) == 128 and je.capacity_for(103) == 256
    assert je.capacity_for(100, 256) == 256 and je.capacity_for(300, 256) == 512


def test_fire_on_the_device_reaches_the_cpu_minimum():
    """The seed's Case 1 in small: a relaxed packing grown by 1 + 5e-5, to 1e-9 F0; the same
    minimum as the CPU engine's L-BFGS to 1e-10 of the energy, forces balanced by the CPU's own
    count."""
    model = ContactModel(2.0)
    relaxed = relax(random_packing(256, 0.86, seed=1), model, rtol=1e-12).packing
    start = relaxed.scale_radii(1.0 + 5e-5)
    device = je.relax_fire(start, model)
    assert device.converged and device.max_gradient <= device.gtol
    cpu = relax(start, model, Minimizer("lbfgs"), rtol=1e-12)
    assert device.energy == pytest.approx(cpu.energy, rel=1e-10)
    check = Objective(device.packing, model)
    energy, grad = check(check.x0)
    assert energy == pytest.approx(device.energy, rel=1e-12)
    assert check.max_gradient(grad) <= 1.01 * device.gtol


def test_fire_on_the_device_rebuilds_its_list_on_the_way():
    """From random positions particles move far beyond the skin: the list is rebuilt on the
    host, the loop goes on, and the end is a minimum by the CPU's own evaluation."""
    model = ContactModel(2.0)
    start = random_packing(128, 0.88, seed=2)
    device = je.relax_fire(start, model, rtol=1e-9)
    assert device.converged and device.neighbor_rebuilds > 1
    check = Objective(device.packing, model)
    energy, grad = check(check.x0)
    assert energy == pytest.approx(device.energy, rel=1e-12)
    assert check.max_gradient(grad) <= 1.01 * device.gtol
    assert device.history_energy.size == device.iterations + 1


def test_without_jax_the_engine_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "jax", None)
    monkeypatch.delitem(sys.modules, "athermal.jaxengine")
    with pytest.raises(InputError, match=r"athermal\[jax\]"):
        importlib.import_module("athermal.jaxengine")


def test_relax_backend_jax_on_the_command_line(tmp_path, capsys):
    import json

    from athermal.cli import main
    from athermal.io import write_gsd

    write_gsd(tmp_path / "r.gsd", random_packing(64, 0.88, seed=1))
    args = ["relax", str(tmp_path / "r.gsd"), "-o", str(tmp_path / "o.gsd"), "--json"]
    assert main([*args, "--method", "fire", "--backend", "jax"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["method"] == "fire (jax)" and out["converged"]
    assert out["max_gradient"] <= out["gtol"]
    written = (tmp_path / "o.gsd").read_bytes()
    assert main([*args, "--backend", "jax", "--overwrite"]) == 2  # lbfgs: not yet on jax
    assert "--backend jax" in capsys.readouterr().err
    assert (tmp_path / "o.gsd").read_bytes() == written  # refused before any work


def test_relax_backend_jax_without_jax_is_refused_at_the_door(tmp_path, capsys, monkeypatch):
    import importlib.util

    from athermal.cli import main
    from athermal.io import write_gsd

    write_gsd(tmp_path / "r.gsd", random_packing(64, 0.88, seed=1))
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "jax" else real(name, *a)
    )
    out = tmp_path / "o.gsd"
    assert (
        main(
            [
                "relax",
                str(tmp_path / "r.gsd"),
                "-o",
                str(out),
                "--method",
                "fire",
                "--backend",
                "jax",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install "athermal[jax]"' in err[0]
    assert not out.exists()
