"""Contact-force statistics: normalisation, the tail fit, anisotropy, rattlers left out, and the
force network through `measure --json` and the ensemble summary."""

import json

import numpy as np
import pytest

from athermal.analysis.forces import (
    EDGES,
    FORCE_BIN,
    anisotropy,
    exponential_tail,
    force_histogram,
    force_statistics,
    histogram_density,
)
from athermal.analysis.observables import measure
from athermal.cli import main
from athermal.io import write_gsd
from athermal.model.cell import Cell
from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing
from athermal.relaxation import minimize_objective
from athermal.studies.ensemble import EnsembleSpec, Realization, run_ensemble
from athermal.studies.experiments import JamSpec


@pytest.fixture(scope="module")
def relaxed():
    model = ContactModel()
    packing = random_packing(1024, 0.86, seed=5)
    return minimize_objective(
        Objective(packing, model), "lbfgs", precon="exp", rtol=1e-10
    ).packing, model


def test_the_density_integrates_to_the_fraction_below_the_range():
    x = np.random.default_rng(1).exponential(1.0, 10_000)
    counts, overflow = force_histogram(x)
    assert overflow == int(np.sum(x >= EDGES[-1])) and counts.sum() + overflow == x.size
    assert np.sum(histogram_density(counts, overflow)) * FORCE_BIN == pytest.approx(
        1.0 - overflow / x.size, rel=1e-12
    )
    big = np.concatenate([x, np.full(500, 50.0)])  # far beyond the range
    counts, overflow = force_histogram(big)
    assert overflow >= 500
    assert np.sum(histogram_density(counts, overflow)) * FORCE_BIN < 0.96


@pytest.mark.parametrize("rate", [1.0, 2.0])
def test_the_tail_fit_recovers_an_exponential_decay(rate):
    x = np.random.default_rng(2).exponential(1.0 / rate, 200_000)
    tail = exponential_tail(*force_histogram(x))
    assert tail is not None and tail.x_min >= 1.0 and tail.points >= 10
    assert abs(tail.decay - rate) < 4 * tail.stderr and tail.stderr < 0.05 * rate
    # the prefactor of a normalized exponential: P(x) = rate exp(-rate x)
    assert tail.log_prefactor == pytest.approx(np.log(rate), abs=0.1)


def test_too_few_forces_give_no_tail():
    assert exponential_tail(*force_histogram(np.array([0.5, 1.0, 1.5]))) is None


@pytest.mark.parametrize("a", [0.0, 0.3, 0.8])
def test_anisotropy_is_the_cos_2theta_amplitude_of_the_normals_in_2d(a):
    rng = np.random.default_rng(3)
    theta = rng.uniform(0.0, 2 * np.pi, 400_000)  # P(theta) ~ 1 + a cos 2 (theta - 0.4)
    keep = rng.uniform(0.0, 1.0 + a, theta.size) < 1.0 + a * np.cos(2 * (theta - 0.4))
    n = np.column_stack([np.cos(theta[keep]), np.sin(theta[keep])])
    value, axis = anisotropy(n, np.ones(n.shape[0]))
    assert value == pytest.approx(a, abs=0.01)
    if a > 0:
        assert abs(abs(axis @ [np.cos(0.4), np.sin(0.4)]) - 1.0) < 1e-3
    weighted, _ = anisotropy(n, 1.0 + 0.5 * np.abs(n[:, 0]))  # forces larger along x
    assert weighted > value - 0.01


def test_a_relaxed_packing_counts_the_forces_of_its_non_rattlers(relaxed):
    packing, model = relaxed
    stats = force_statistics(packing, model)
    obs = measure(packing, model)
    assert stats.contacts == obs.contacts_nonrattler
    assert stats.counts.sum() + stats.overflow == stats.contacts
    assert np.sum(stats.density) * FORCE_BIN == pytest.approx(1.0, rel=1e-12)
    assert 0.8 < stats.tail.decay < 2.5  # exponential tails of 2D packings: ~1.3 ... 1.9
    assert 0.0 <= stats.contact_anisotropy < 0.1  # isotropically compressed
    # shear loads the force network along the compressive axis of x += gamma y, (1, -1) /
    # sqrt(2): the change of the anisotropy (a cos 2 theta, a sin 2 theta) points at 2 theta =
    # -90 degrees. A relaxed random packing keeps a residual anisotropy (here 0.04-0.08,
    # measured) as large as a 1 % shear adds, and a 1e-3 shear may rearrange contacts, so the
    # change is taken at gamma = 1e-5, in linear response.
    sheared = minimize_objective(
        Objective(packing.deform([[1.0, 1e-5], [0.0, 1.0]]), model), rtol=1e-10
    )
    after = force_statistics(sheared.packing, model)
    change = anisotropy_vector(after.force_anisotropy, after.force_axis) - anisotropy_vector(
        stats.force_anisotropy, stats.force_axis
    )
    # axis within 22.5 degrees of the compressive one (measured on three packings: 2-11)
    assert change[1] < 0.0 and abs(change[0]) < abs(change[1])
    # in 2D the stress-force-fabric relation (branch lengths alike) makes the force-weighted
    # anisotropy twice the stress ratio sigma_dev / sigma_iso: for the change (measured within
    # 4 %), and for each state within what the spread of branch lengths leaves (measured on
    # three packings: within 0.0033)
    stress_change = stress_vector(measure(sheared.packing, model)) - stress_vector(obs)
    np.testing.assert_allclose(change, stress_change, atol=0.1 * np.linalg.norm(stress_change))
    for state, network in ((packing, stats), (sheared.packing, after)):
        ratio = measure(state, model)
        assert abs(network.force_anisotropy / 2 - ratio.stress_dev / ratio.stress_iso) < 0.005


def stress_vector(obs):
    """``2 ((sigma_xx - sigma_yy) / 2, sigma_xy) / sigma_iso``: twice the stress ratio as an
    anisotropy vector (see :func:`anisotropy_vector`)."""
    s = obs.stress
    return np.array([s[0, 0] - s[1, 1], 2.0 * s[0, 1]]) / obs.stress_iso


def anisotropy_vector(amplitude, axis):
    """``a (cos 2 theta, sin 2 theta)`` of an anisotropy ``a`` with major axis at ``theta``."""
    theta = np.arctan2(axis[1], axis[0])
    return amplitude * np.array([np.cos(2.0 * theta), np.sin(2.0 * theta)])


def test_rattlers_and_unjammed_packings():
    cell = Cell.box([1.0, 1.0])
    lone = Packing([[0.0, 0.0], [0.18, 0.0]], [0.1, 0.1], cell)  # one contact: both rattlers
    stats = force_statistics(lone, ContactModel())
    assert stats.contacts == 0 and stats.tail is None and stats.mean_force == 0.0
    assert not np.any(stats.density)


def test_measure_json_has_the_force_network_and_draws_it(relaxed, tmp_path, capsys):
    packing, model = relaxed
    write_gsd(tmp_path / "p.gsd", packing, model=model)
    figure = tmp_path / "forces.png"
    argv = ["measure", str(tmp_path / "p.gsd"), "--json", "--forces-figure", str(figure)]
    assert main(argv) == 0
    forces = json.loads(capsys.readouterr().out)["forces"]
    assert forces["contacts"] == force_statistics(packing, model).contacts
    assert np.sum(forces["density"]) * FORCE_BIN == pytest.approx(1.0)
    assert len(forces["edges"]) == len(forces["density"]) + 1
    assert figure.stat().st_size > 10_000
    assert main(argv) == 2 and "exists" in capsys.readouterr().err  # not replaced silently


def test_an_ensemble_pools_the_force_networks(tmp_path):
    result = run_ensemble(EnsembleSpec("jam", JamSpec(n=128, epsilon=1e-5)), tmp_path, 3, seed=2)
    forces = result.summary["forces"]
    assert forces["realizations"] == 3 and forces["contact_anisotropy"]["n"] == 3
    records = [r.forces for r in result.realizations]
    counts = np.sum([f.counts for f in records], axis=0)
    total = counts.sum() + sum(f.overflow for f in records)
    np.testing.assert_allclose(forces["pooled_density"], counts / (total * FORCE_BIN))
    assert (tmp_path / "forces.png").exists()
    stored = json.loads((tmp_path / "realization-0000.json").read_text())
    assert Realization.from_json(stored) == result.realizations[0]
    del stored["forces"]  # a realization written before the force statistics existed
    assert Realization.from_json(stored).forces is None
