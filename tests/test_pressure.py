"""Packings at a target pressure: reached to rtol from above and below the jammed packing, in
2D and 3D, following p ~ (phi - phi_c)^(alpha - 1) from one start; refused when out of reach."""

import json

import numpy as np
import pytest

from athermal.analysis.fitting import fit_power_law
from athermal.analysis.moduli import stability
from athermal.cli import main
from athermal.errors import ConvergenceError, InputError
from athermal.io import read_gsd
from athermal.model.contact import ContactModel
from athermal.model.packing import random_packing
from athermal.protocols import jam, jam_to_pressure, pressure_search


@pytest.fixture(scope="module")
def jammed_2d():
    model = ContactModel(2.0)
    return jam(random_packing(256, 0.8, seed=2), model, epsilon=1e-8), model


@pytest.mark.parametrize(("dim", "n", "target"), [(2, 128, 1e-3), (3, 256, 1e-4)])
def test_jam_to_pressure_reaches_it_at_a_minimum_above_phi_c(dim, n, target):
    model = ContactModel(2.0)
    start = random_packing(n, 0.8 if dim == 2 else 0.6, dim=dim, seed=1)
    result = jam_to_pressure(start, model, target, epsilon=1e-6)
    assert abs(result.pressure / target - 1.0) <= 1e-3
    assert result.observables.pressure == pytest.approx(result.pressure, rel=1e-12)
    assert result.phi_c == result.jamming.phi_c and result.delta_phi > 0.0
    assert stability(result.packing, model).stable
    assert result.iterations == result.jamming.iterations + sum(t.iterations for t in result.trials)


@pytest.mark.parametrize("alpha", [2.0, 2.5])
def test_pressures_from_one_start_follow_the_scaling_law(alpha):
    """On one branch, up to its first plastic rearrangement (a pressure drop moves phi_c; where
    it falls depends on the CPU's rounding): p ~ (phi - phi_c)^(alpha - 1)."""
    model = ContactModel(alpha)
    jammed = jam(random_packing(256, 0.8, seed=3), model, epsilon=1e-8)
    current, delta, pressure = jammed.packing, [], []
    # Hertzian pressures are smaller at a given overlap (k delta^1.5 with delta ~ 1e-2 radii)
    targets = np.logspace(-6, -3, 6) if alpha == 2.0 else np.logspace(-8.5, -6, 6)
    for target in targets:
        found = pressure_search(current, model, target, phi_low=jammed.phi_low, phi_c=jammed.phi_c)
        assert abs(found.pressure / target - 1.0) <= 1e-3
        if found.pressure_drops:
            break
        # 4 trials per decade of phi - phi_low covered, and a few to close the bracket
        covered = np.log10((found.phi - jammed.phi_low) / (current.phi - jammed.phi_low))
        assert len(found.trials) <= 4 * covered + 6
        current = found.packing
        delta.append(found.delta_phi)
        pressure.append(found.pressure)
    assert len(delta) >= 4 and np.all(np.diff(delta) > 0)
    fit = fit_power_law(delta, pressure)
    assert fit.exponent == pytest.approx(alpha - 1.0, abs=0.12)


def test_a_pressure_below_the_jammed_one_is_reached_by_decompression(jammed_2d):
    jammed, model = jammed_2d
    below = 0.3 * jammed.observables.pressure
    found = pressure_search(jammed.packing, model, below, phi_low=jammed.phi_low)
    assert abs(found.pressure / below - 1.0) <= 1e-3
    assert jammed.phi_low < found.phi < jammed.packing.phi
    assert found.phi_c == jammed.phi_low  # the default reference


def test_out_of_reach_and_bad_requests_are_refused(jammed_2d):
    jammed, model = jammed_2d
    with pytest.raises(ConvergenceError, match="out of reach below phi"):
        pressure_search(jammed.packing, model, 1.0, phi_low=jammed.phi_low)
    with pytest.raises(InputError, match="pressure"):
        pressure_search(jammed.packing, model, -1e-3, phi_low=jammed.phi_low)
    with pytest.raises(InputError, match="phi_low"):
        pressure_search(jammed.packing, model, 1e-3, phi_low=0.95)


def test_jam_pressure_writes_the_packing_at_that_pressure(tmp_path, capsys):
    out = tmp_path / "p.gsd"
    argv = ["jam", "--n", "128", "--seed", "5", "--pressure", "2e-3", "--picture", "none"]
    assert main([*argv, "--quiet", "-o", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert abs(report["pressure"] / 2e-3 - 1.0) <= 1e-3 and report["delta_phi"] > 0
    frame = read_gsd(out)
    assert float(frame.log["target_pressure"]) == 2e-3
    assert float(frame.log["phi_c"]) == pytest.approx(report["phi_c"])
    assert frame.packing.phi == pytest.approx(report["phi"], rel=1e-12)
    assert main(["measure", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["pressure"] == pytest.approx(report["pressure"])
    # the jamming check's numbers are labelled as the jammed packing's, at phi_c, not at P
    check = report["jamming_check"]
    assert check["phi"] == pytest.approx(report["phi_c"], abs=1e-12) and check["passed"]
    # at phi_c, at most epsilon above jamming: p ~ B epsilon, far below P (not P's numbers)
    assert check["pressure"] < 1e-2 * report["pressure"] and check["z"] < report["z"]
    assert report["written"].startswith("the packing at pressure 0.002")
    for key in ("energy", "pressure", "z", "contacts", "excess_contacts"):
        assert float(frame.log[f"jamming_check_{key}"]) == check[key]
    assert float(frame.log["z"]) == report["z"]


def test_a_pressure_drop_on_the_way_is_counted(jammed_2d):
    from dataclasses import replace

    from athermal.protocols import PressureTrial

    jammed, model = jammed_2d
    found = pressure_search(jammed.packing, model, 1e-4, phi_low=jammed.phi_low)
    assert found.pressure_drops == 0
    trials = (
        PressureTrial(0.84, 1e-4, 1),
        PressureTrial(0.85, 5e-5, 1),
        PressureTrial(0.86, 2e-4, 1),
    )
    assert replace(found, trials=trials).pressure_drops == 1
