"""Avalanche statistics and the yielding amplitude over realizations: the power-law fit against
samples of known exponent and cutoff, the log-binned density's normalization, the pooling of
events after the transient, the yielding bracket, and the ensembles ``events`` and ``cycles``
from the command line (files, resume, refusals)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import integrate

from athermal.analysis.avalanches import log_binned, power_law_tail
from athermal.cli import main
from athermal.errors import InputError
from athermal.studies.avalanches import (
    CyclesRecord,
    EventsRecord,
    EventsSpec,
    avalanche_statistics,
    yielding,
)


def sample(tau: float, cutoff: float, count: int, seed: int) -> np.ndarray:
    """Sizes from ``S^-tau exp(-S / cutoff)`` above 1 (a power law thinned by the cutoff)."""
    rng = np.random.default_rng(seed)
    s = (1.0 - rng.random(4 * count)) ** (-1.0 / (tau - 1.0))
    s = s[rng.random(s.size) < np.exp(-(s - 1.0) / cutoff)]
    return s[:count]


@pytest.mark.parametrize(("tau", "cutoff", "seed"), [(1.3, 50.0, 1), (1.5, 1e3, 2), (1.2, 1e9, 3)])
def test_the_fit_recovers_a_known_exponent_and_cutoff(tau, cutoff, seed):
    """Maximum likelihood with the start chosen by the KS distance: the exponent within three
    standard errors of the one sampled, with or without a cutoff in range."""
    fit = power_law_tail(sample(tau, cutoff, 3000, seed))
    assert abs(fit.exponent - tau) < 3.0 * fit.stderr
    assert fit.stderr < 0.06
    if cutoff < 1e4:
        assert abs(np.log(fit.cutoff / cutoff)) < 3.0 * fit.cutoff_stderr / fit.cutoff
    # the fitted density carries the fitted sizes' share of the probability
    mass, _ = integrate.quad(
        lambda u: fit.density(np.exp(u)) * np.exp(u), np.log(fit.s_min), 300.0, limit=400
    )
    assert mass == pytest.approx(fit.tail / fit.count, rel=1e-6)
    assert set(fit.by_start) == {"0", "0.1", "0.2", "0.3", "0.4", "0.5", "0.6"}


def test_a_power_law_fit_needs_enough_sizes():
    assert power_law_tail([1.0, 2.0, 3.0]) is None
    assert power_law_tail(np.full(50, -1.0)) is None  # no positive size


def test_the_log_binned_density_is_normalized():
    sizes = sample(1.4, 100.0, 2000, 4)
    centres, density, counts = log_binned(sizes, per_decade=5)
    edges_ratio = np.sqrt(centres[1] / centres[0])
    widths = centres * (edges_ratio - 1.0 / edges_ratio)
    assert np.sum(density * widths) == pytest.approx(1.0, rel=1e-9)
    assert counts.sum() == sizes.size
    one = log_binned([3e-5])
    assert one[2].tolist() == [1]


def record(strains, drops, reached=0.0):
    events = tuple(
        {
            "strain": s,
            "tau_before": 1.0,
            "stress_drop": d,
            "energy_drop": d * d,
            "moved": 10.0,
            "saddle_node": 1.0,
        }
        for s, d in zip(strains, drops, strict=True)
    )
    return EventsRecord(0.01, reached or max(strains), 10, events, 1.0, 1.0, 0.5)


def test_statistics_pool_the_events_after_the_transient():
    """Events below the transient are left out; the strain between events is taken within
    each realization, never across two."""
    a = record([0.01, 0.06, 0.08], [5.0, 1.0, 2.0])
    b = record([0.07, 0.1], [3.0, 4.0])
    stats = avalanche_statistics([a, b], 0.05)
    assert stats["events"] == 4
    assert stats["stress_drop"]["mean"] == pytest.approx(5.0)  # in units of 0.5
    assert stats["strain_between_events"]["mean"] == pytest.approx((0.02 + 0.03) / 2)
    assert stats["strain_sheared"] == pytest.approx(0.03 + 0.05)
    assert stats["stress"]["mean"] == pytest.approx(2.0) and stats["stress"]["n"] == 4
    assert stats["stress_drop_exponent"] is None  # too few events to fit


def test_the_yielding_bracket_lies_where_most_stop_reaching_a_limit_cycle():
    def rows(*reached):
        return tuple(
            {"amplitude": a, "reached": r, "cycle": 2, "period": 1, "events_per_period": 3}
            for a, r in zip((0.02, 0.05, 0.1), reached, strict=True)
        )

    records = [
        CyclesRecord(0.01, rows(True, True, False)),
        CyclesRecord(0.01, rows(True, False, False)),
        CyclesRecord(0.01, rows(True, True, True)),
    ]
    out = yielding(records)
    assert [t["fraction_reached"] for t in out["amplitudes"]] == pytest.approx([1, 2 / 3, 1 / 3])
    assert out["yielding_bracket"] == [0.05, 0.1]
    assert yielding([CyclesRecord(0.01, rows(True, True, True))])["yielding_bracket"] is None


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"transient": 0.3, "strain": 0.2}, "transient"),
        ({"delta_phi": -0.01}, "delta_phi"),
        ({"amplitudes": ()}, "amplitudes"),
        ({"amplitudes": (0.05, -0.1)}, "amplitude"),
        ({"cycles": 0}, "cycles"),
        ({"mode": "twist"}, "mode"),
        ({"tol": 1e-3, "step": 1e-4}, "step"),
    ],
)
def test_bad_event_specs_are_refused(options, message):
    with pytest.raises(InputError, match=message):
        EventsSpec(**options)


def test_the_events_ensemble_writes_its_statistics_and_resumes(tmp_path, capsys):
    out = tmp_path / "ens"
    args = ["ensemble", "events", "--realizations", "2", "--n", "32", "--strain", "0.03"]
    args += ["--transient", "0.005", "--step", "1e-3", "-o", str(out), "--quiet", "--json"]
    main(args)
    first = json.loads(capsys.readouterr().out)
    stats = first["summary"]["avalanches"]
    assert stats["realizations"] == 2 and stats["events"] >= 1
    assert stats["stress_drop"]["mean"] > 0.0
    assert (out / "avalanches.png").exists()
    saved = json.loads((out / "realization-0000.json").read_text())
    assert saved["events"]["strain"] == pytest.approx(0.03) and "events" in saved["events"]
    main(args)  # everything is there: nothing computed again, the same statistics
    again = json.loads(capsys.readouterr().out)
    assert again["computed"] == [] and again["summary"]["avalanches"] == stats


def _killed(original, kind, after):
    """``original`` (a generator function of the shear) interrupted once it yielded ``after``
    items of ``kind``, as a process killed there."""

    def killed(*args, **kwargs):
        seen = 0
        for item in original(*args, **kwargs):
            yield item
            seen += isinstance(item, kind)
            if seen == after:
                raise KeyboardInterrupt

    return killed


def test_a_killed_events_run_goes_on_from_its_last_event(tmp_path, monkeypatch):
    """A realization's AQS run writes its trajectory and tables as it goes: killed after its
    second event, the realization run again goes on from there (its jamming from its
    trajectory) to the same events, to the bit, as a run never stopped; the files of another
    start are refused."""
    import athermal.studies.plasticity as plasticity
    from athermal import ContactModel, random_packing
    from athermal.protocols.events import PlasticEvent
    from athermal.studies.avalanches import shear_events
    from athermal.studies.experiments import JamSpec
    from athermal.studies.realization import EnsembleSpec, run_realization
    from athermal.studies.tables import read_table

    events = EventsSpec(delta_phi=0.02, strain=0.05, transient=0.0, step=1e-3)
    spec = EnsembleSpec("events", jam=JamSpec(n=32), events=events)
    (tmp_path / "whole").mkdir()
    whole = run_realization(spec, 0, 11, str(tmp_path / "whole")).events
    assert whole is not None and len(whole.events) >= 3
    out = tmp_path / "killed"
    out.mkdir()
    original = plasticity.plastic_events
    monkeypatch.setattr(plasticity, "plastic_events", _killed(original, PlasticEvent, 2))
    with pytest.raises(KeyboardInterrupt):
        run_realization(spec, 0, 11, str(out))
    assert len(read_table(out / "realization-0000.shear.events.csv")) == 2
    monkeypatch.setattr(plasticity, "plastic_events", original)
    resumed = run_realization(spec, 0, 11, str(out)).events
    assert resumed is not None and resumed.events == whole.events
    assert (resumed.states, resumed.strain) == (whole.states, whole.strain)
    assert resumed.seconds > 0.0
    again = run_realization(spec, 0, 11, str(tmp_path / "whole")).events  # a finished run
    assert again is not None and (again.events, again.states) == (whole.events, whole.states)
    other = random_packing(32, 0.85, seed=2)
    with pytest.raises(InputError, match="holds another run"):
        shear_events(other, ContactModel(), events, out / "realization-0000.shear.gsd")


def test_a_killed_cycles_run_goes_on_from_its_last_cycle(tmp_path, monkeypatch):
    """Cyclic shear in an ensemble, killed after the first cycle's end at its second amplitude,
    goes on from there to the limit cycles of a run never stopped."""
    import athermal.studies.plasticity as plasticity
    from athermal.protocols.events import CycleEnd
    from athermal.studies.experiments import JamSpec
    from athermal.studies.realization import EnsembleSpec, run_realization

    events = EventsSpec(delta_phi=0.05, step=1e-3, amplitudes=(0.002, 0.05), cycles=3)
    spec = EnsembleSpec("cycles", jam=JamSpec(n=32), events=events)
    (tmp_path / "whole").mkdir()
    whole = run_realization(spec, 0, 5, str(tmp_path / "whole")).cycles
    out = tmp_path / "killed"
    out.mkdir()
    original = plasticity.cyclic_shear
    calls = []

    def second_killed(*args, **kwargs):
        calls.append(kwargs["amplitude"])
        if len(calls) == 2:
            return _killed(original, CycleEnd, 1)(*args, **kwargs)
        return original(*args, **kwargs)

    monkeypatch.setattr(plasticity, "cyclic_shear", second_killed)
    with pytest.raises(KeyboardInterrupt):
        run_realization(spec, 0, 5, str(out))
    monkeypatch.setattr(plasticity, "cyclic_shear", original)
    resumed = run_realization(spec, 0, 5, str(out)).cycles
    assert whole is not None and resumed is not None
    assert [{k: v for k, v in r.items() if k != "seconds"} for r in resumed.rows] == [
        {k: v for k, v in r.items() if k != "seconds"} for r in whole.rows
    ]
    assert whole.rows[1]["cycles_run"] >= 2
    again = run_realization(spec, 0, 5, str(tmp_path / "whole")).cycles  # finished runs
    assert again is not None and [r["cycles_run"] for r in again.rows] == [
        r["cycles_run"] for r in whole.rows
    ]


def test_the_cycles_ensemble_reports_the_limit_cycles(tmp_path, capsys):
    out = tmp_path / "ens"
    main(
        [
            *("ensemble", "cycles", "--realizations", "1", "--n", "32", "--amplitudes", "0.002"),
            *("--cycles", "3", "--shear-delta-phi", "0.05", "-o", str(out), "--quiet", "--json"),
        ]
    )
    table = json.loads(capsys.readouterr().out)["summary"]["yielding"]["amplitudes"]
    assert table[0]["amplitude"] == 0.002 and table[0]["fraction_reached"] == 1.0
    assert (out / "yielding.png").exists()


def test_an_ensemble_with_a_bad_shear_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "ens"
    assert (
        main(
            [
                *("ensemble", "events", "--realizations", "1", "--n", "32", "--strain", "0.01"),
                *("--transient", "0.02", "-o", str(out)),
            ]
        )
        == 2
    )
    assert "transient" in capsys.readouterr().err
    assert not out.exists()
