"""Weak forces and small gaps: the estimator recovers known exponents, and the samples of a
jammed packing are what the module says they are."""

import json
from pathlib import Path

import numpy as np
import pytest

import athermal as at
from athermal.analysis.observables import rattlers
from athermal.certify import (
    GAP_REACH,
    certify,
    contact_network,
    toward_jamming,
)
from athermal.certify.bisection import bisect_jamming_point
from athermal.certify.criticality import (
    WeakForcesAndGaps,
    critical_exponents,
    fit_truncated_power_law,
    local_exponents,
    packing_bootstrap,
    weak_forces_and_gaps,
)
from athermal.certify.extended import NearPairs
from athermal.cli import main
from athermal.errors import InputError

DATA = Path(__file__).parent / "data"


def measured_gaps(done, model):
    """The gaps ``h`` of a certified packing as it is (pairs of non-rattlers apart), sorted."""
    packing = done.packing
    pairs = NearPairs(packing, model, GAP_REACH)
    sums = pairs.sums(packing.positions.copy(), done.position_lo.copy())
    _, rattler = contact_network(pairs, packing.positions, sums)
    overlap = sums.overlap[0] + sums.overlap[1]
    apart = ~(rattler[pairs.first] | rattler[pairs.second]) & (overlap <= 0.0)
    sigma = packing.radii[pairs.first] + packing.radii[pairs.second]
    return np.sort(-overlap[apart] / sigma[apart])


@pytest.mark.parametrize("a", [0.59, 1.0, 1.42])
def test_the_truncated_fit_recovers_a_known_exponent(a):
    rng = np.random.default_rng(1)
    low, high = 1e-4, 1e-1
    u = rng.uniform(size=20000)  # inverse CDF of a x^(a-1) / (high^a - low^a) on [low, high]
    x = (low**a + u * (high**a - low**a)) ** (1.0 / a)
    fit = fit_truncated_power_law(np.concatenate([x, [1e-6, 0.5]]), (low, high))
    assert fit.points == 20000
    assert abs(fit.a - a) < 3.0 * fit.stderr
    assert 0.003 < fit.stderr < 0.03


def test_the_errors_of_the_fit_are_its_spread():
    rng = np.random.default_rng(2)
    fits = []
    for _ in range(200):
        x = (1e-3**0.6 + rng.uniform(size=500) * (1.0 - 1e-3**0.6)) ** (1.0 / 0.6)
        fits.append(fit_truncated_power_law(x, (1e-3, 1.0)))
    spread = np.std([f.a for f in fits])
    assert np.mean([f.stderr for f in fits]) == pytest.approx(spread, rel=0.15)


def _piecewise(rng, size, a_low, a_high, knee, low, high):
    """Values of the continuous density ``x^(a_low - 1)`` below ``knee`` and
    ``knee^(a_low - a_high) x^(a_high - 1)`` above it, on ``[low, high]``."""
    below = (knee**a_low - low**a_low) / a_low
    above = knee ** (a_low - a_high) * (high**a_high - knee**a_high) / a_high
    u = rng.uniform(size=size) * (below + above)
    low_part = (low**a_low + a_low * u) ** (1.0 / a_low)
    high_part = (knee**a_high + a_high * (u - below) * knee ** (a_high - a_low)) ** (1.0 / a_high)
    return np.where(u < below, low_part, high_part)


def test_local_exponents_follow_a_drift_that_one_window_averages():
    rng = np.random.default_rng(4)
    x = _piecewise(rng, 200000, 0.59, 1.0, 1e-3, 1e-6, 1e-1)
    fits = local_exponents(x, (1e-8, 1e-1), per_decade=1)
    assert [f.window[0] for f in fits] == pytest.approx([1e-6, 1e-5, 1e-4, 1e-3, 1e-2])  # none
    for fit in fits:  # below 1e-6 (no values there)
        expected = 0.59 if fit.window[1] <= 1e-3 else 1.0
        assert abs(fit.a - expected) < 4.0 * fit.stderr
    one = fit_truncated_power_law(x, (1e-6, 1e-1))
    assert 0.62 < one.a < 0.97 and abs(one.a - 0.59) > 10 * one.stderr
    half = local_exponents(x, (1e-6, 1e-1), per_decade=2)
    assert len(half) == 10 and half[1].window == pytest.approx((10**-5.5, 1e-5))
    with pytest.raises(InputError, match="per_decade"):
        local_exponents(x, (1e-6, 1e-1), per_decade=0)
    with pytest.raises(InputError, match="low < high"):
        local_exponents(x, (1e-1, 1e-6))


def _packings_of(gaps_each):
    return [
        WeakForcesAndGaps(
            forces=np.ones(3),
            localized=np.zeros(3, bool),
            gaps=g,
            gap_localized=np.zeros(g.size, bool),
            n_live=g.size,
            bucklers=0,
            touching=0,
            jamming_strain=0.0,
        )
        for g in gaps_each
    ]


def test_the_bootstrap_error_counts_packings_not_values():
    rng = np.random.default_rng(5)
    window = (1e-4, 1e-1)

    def gamma(samples):
        return 1.0 - fit_truncated_power_law(np.concatenate([s.gaps for s in samples]), window).a

    def draw(size):
        return _piecewise(rng, size, 0.59, 0.59, 1e-2, *window)

    independent = _packings_of([draw(400) for _ in range(30)])
    fisher = fit_truncated_power_law(np.concatenate([s.gaps for s in independent]), window)
    assert packing_bootstrap(independent, gamma) == pytest.approx(fisher.stderr, rel=0.3)
    # each packing holds 20 copies of 20 values: the Fisher error counts 400 values per packing
    copied = _packings_of([np.tile(draw(20), 20) for _ in range(30)])
    fisher = fit_truncated_power_law(np.concatenate([s.gaps for s in copied]), window)
    assert packing_bootstrap(copied, gamma) > 2.5 * fisher.stderr
    with pytest.raises(InputError, match="2 or more"):
        packing_bootstrap(copied[:1], gamma)


def test_values_that_follow_no_power_law_are_refused():
    values = np.concatenate([np.full(50, 1.0001e-3), np.linspace(0.01, 0.1, 3)])
    with pytest.raises(InputError, match="no power law"):
        fit_truncated_power_law(values, (1e-3, 1e-1))


def test_too_few_values_are_refused():
    with pytest.raises(InputError, match="at least 10"):
        fit_truncated_power_law(np.linspace(0.1, 0.2, 5), (0.01, 1.0))


@pytest.fixture(scope="module")
def certified():
    model = at.ContactModel(2.0)
    jammed = at.jam(at.random_packing(128, 0.8, seed=3), model).packing
    return certify(jammed, model), model


def test_the_samples_of_a_jammed_packing(certified):
    done, model = certified
    sample = weak_forces_and_gaps(done.packing, model, done.position_lo)
    contacts = at.find_contacts(done.packing, model)
    rattler = rattlers(contacts, done.packing.n, 2)
    live = ~(rattler[contacts.i] | rattler[contacts.j])
    assert sample.forces.size == live.sum() == done.certificate.contacts
    assert sample.forces.mean() == pytest.approx(1.0)
    assert sample.forces.min() == pytest.approx(
        done.certificate.smallest_force / done.certificate.mean_force, rel=1e-9
    )
    counts = np.bincount(contacts.i[live], minlength=128) + np.bincount(
        contacts.j[live], minlength=128
    )
    assert sample.bucklers == int(np.sum(~rattler & (counts == 3)))
    buckler = ~rattler & (counts == 3)
    localized = buckler[contacts.i[live]] | buckler[contacts.j[live]]
    assert sample.localized.sum() == localized.sum()  # the pairs come in another order
    np.testing.assert_allclose(
        np.sort(sample.forces[sample.localized]),
        np.sort(contacts.force_magnitude[live][localized] / done.certificate.mean_force),
        rtol=1e-6,
    )
    assert np.all(sample.gaps > 0.0) and sample.gaps.max() < 0.5  # within reach
    # the expansion to the jamming point is the certificate's, and moves each gap by its rate
    # (test_certify checks the rates against relaxed expansions)
    strain = sample.jamming_strain
    assert (done.packing.phi / (1.0 + strain) ** 2) == pytest.approx(
        done.certificate.linear_phi_c, rel=1e-14
    )
    packing = done.packing
    pairs = NearPairs(packing, model, GAP_REACH)
    sums = pairs.sums(packing.positions.copy(), done.position_lo.copy())
    network, rattler = contact_network(pairs, packing.positions, sums)
    overlap = sums.overlap[0] + sums.overlap[1]
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    _, rate, _ = toward_jamming(pairs, packing.positions, overlap, network, rattler, live)
    sigma = packing.radii[pairs.first] + packing.radii[pairs.second]
    apart = live & (overlap <= 0.0)
    closing = strain * rate[apart] / sigma[apart]
    at_jamming = -overlap[apart] / sigma[apart] + closing
    touching = at_jamming < -closing  # the pressure made more than half of the gap
    assert sample.touching == touching.sum() and sample.gaps.size == (~touching).sum()
    np.testing.assert_allclose(np.sort(sample.gaps), np.sort(at_jamming[~touching]), rtol=1e-12)
    first, second = pairs.first[apart][~touching], pairs.second[apart][~touching]
    np.testing.assert_allclose(sample.gaps, at_jamming[~touching], rtol=1e-12)  # same order
    np.testing.assert_array_equal(sample.gap_localized, buckler[first] | buckler[second])
    assert 0 < sample.gap_localized.sum() < sample.gaps.size


def test_pooled_exponents_need_enough_values(certified):
    done, model = certified
    sample = weak_forces_and_gaps(done.packing, model, done.position_lo)
    with pytest.raises(InputError, match="at least 10"):
        critical_exponents([sample])
    exponents = critical_exponents([sample], force_window=(1e-2, 1.0), gap_window=(1e-3, 0.1))
    assert exponents.packings == 1 and exponents.contacts == sample.forces.size


def test_the_command_pools_files_and_refuses_bad_windows(certified, tmp_path, capsys):
    done, model = certified
    files = []
    for k in range(2):
        path = tmp_path / f"c{k}.gsd"
        at.write_gsd(path, done.packing, model=model, position_lo=done.position_lo)
        files.append(str(path))
    windows = ["--force-window", "1e-2", "1", "--gap-window", "1e-3", "0.1"]
    figure = tmp_path / "crit.png"
    assert main(["criticality", *files, *windows, "--figure", str(figure), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["packings"] == out["certified"] == 2
    assert out["contacts"] == 2 * done.certificate.contacts
    assert out["theta_e"]["mean_field"] == 0.42311 and out["gamma"]["window"] == [1e-3, 0.1]
    gaps = weak_forces_and_gaps(done.packing, model, done.position_lo).gaps
    local = local_exponents(np.concatenate([gaps, gaps]), (1e-3, 0.1), per_decade=1)
    assert local  # a decade at a time across the gap window, where 10 gaps or more lie
    assert [g["window"] for g in out["gamma_local"]] == [list(f.window) for f in local]
    assert [g["value"] for g in out["gamma_local"]] == pytest.approx([1 - f.a for f in local])
    assert [g["per_packing"] for g in out["gamma_local"]] == [f.points / 2 for f in local]
    assert figure.stat().st_size > 0
    assert main(["criticality", *files, "--force-window", "1", "0.1"]) == 2
    assert "--force-window: need 0 < LOW < HIGH" in capsys.readouterr().err
    assert main(["criticality", str(tmp_path / "missing.gsd")]) == 2
    assert "no such file" in capsys.readouterr().err


def stored(name):
    data = np.load(DATA / f"jammed_{name}.npz")
    return at.Packing(data["positions"], data["radii"], at.Cell(data["h"]))


def test_gaps_at_the_jamming_point_do_not_depend_on_epsilon():
    """Taken at the jamming point, the gaps of a packing jammed in float64 (~6e-7 above it;
    stored, N = 256, no contact changes on the way) and of the same packing bracketed to 1e-12
    agree: the extrapolation removes nearly all of the shift the pressure gave them (measured
    gaps move by ~1e-7 between the two)."""
    model = at.ContactModel(2.0)
    jammed = stored("n256_seed2")
    point = bisect_jamming_point(jammed, model, 1e-12)
    assert point.contacts_shed == point.contacts_formed == point.rearrangements == 0
    above, at_jamming = certify(jammed, model), point.jammed
    a = weak_forces_and_gaps(above.packing, model, above.position_lo)
    b = weak_forces_and_gaps(at_jamming.packing, model, at_jamming.position_lo)
    assert a.gaps.size == b.gaps.size and a.touching == b.touching
    shift = np.abs(measured_gaps(above, model) - measured_gaps(at_jamming, model)).max()
    assert shift > 1e-8
    assert np.abs(np.sort(a.gaps) - np.sort(b.gaps)).max() < 0.02 * shift


def test_pairs_that_touch_at_the_jamming_point_are_counted_apart():
    """A stored packing (N = 1024) with pairs whose gap the pressure made: at its certified
    bound ~1e-12 above its jamming point they are ~1e-13 apart, as far as its contacts
    overlap, and they touch at the jamming point; found alike from the float64 packing."""
    packing = stored("n1024_seed31")
    model = at.ContactModel(2.0)
    point = bisect_jamming_point(packing, model, 1e-12)
    assert point.rearrangements == 0  # its last trials come apart and clear: unjammed
    above = certify(packing, model)
    a = weak_forces_and_gaps(above.packing, model, above.position_lo)
    b = weak_forces_and_gaps(point.jammed.packing, model, point.jammed.position_lo)
    assert b.touching > 0 and a.touching == b.touching
    gaps = measured_gaps(point.jammed, model)
    assert np.all(gaps[: b.touching] < 1e-11) and gaps[b.touching] > 1e-9
    assert b.gaps.min() > 1e-9
