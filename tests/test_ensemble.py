"""Ensembles on a real dask.distributed cluster (worker processes on loopback)."""

import builtins
import json
import os
import signal
import threading
import time

import pytest

from athermal.errors import InputError
from athermal.studies.ensemble import EnsembleSpec, Realization, run_ensemble
from athermal.studies.experiments import JamSpec, child_seeds

distributed = pytest.importorskip("dask.distributed")

SPEC = EnsembleSpec("jam", JamSpec(n=48, epsilon=1e-4))


def numbers(result):
    return [{k: v for k, v in r.to_json().items() if k != "seconds"} for r in result.realizations]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return run_ensemble(SPEC, tmp_path_factory.mktemp("ref"), 4, seed=11, workers=1)


def test_child_seeds_are_fixed_by_the_root_seed():
    assert child_seeds(11, 4) == child_seeds(11, 4)
    assert child_seeds(11, 4)[:2] == child_seeds(11, 2)
    assert len(set(child_seeds(11, 100))) == 100 and child_seeds(12, 1) != child_seeds(11, 1)


@pytest.mark.slow
def test_one_and_two_workers_give_identical_realizations(reference, tmp_path):
    two = run_ensemble(SPEC, tmp_path, 4, seed=11, workers=2)
    assert "2 worker" in two.engine and "1 worker" in reference.engine
    assert numbers(two) == numbers(reference)
    assert [r.seed for r in two.realizations] == child_seeds(11, 4)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["phi_c"]["n"] == 4 and summary["phi_c"]["sd"] > 0.0
    assert (tmp_path / "summary.png").stat().st_size > 5_000
    assert (tmp_path / "realizations.csv").read_text().count("\n") == 5


@pytest.mark.slow
def test_a_killed_worker_loses_and_duplicates_nothing(reference, tmp_path):
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    )
    client = distributed.Client(cluster)
    pids = client.run(os.getpid)
    outcome = {}

    def ensemble():
        outcome["result"] = run_ensemble(
            SPEC, tmp_path, 4, seed=11, scheduler=cluster.scheduler_address
        )

    runner = threading.Thread(target=ensemble)
    runner.start()
    deadline = time.monotonic() + 120
    while not list(tmp_path.glob("realization-*.gsd")):  # a realization is under way
        assert time.monotonic() < deadline
        time.sleep(0.01)
    victim = next(iter(pids.values()))
    os.kill(victim, signal.SIGKILL)
    runner.join(timeout=600)
    after = set(client.run(os.getpid).values())
    client.close()
    cluster.close()
    result = outcome["result"]
    assert victim not in after and len(after) == 2  # the nanny restarted the killed worker
    assert sorted(r.index for r in result.realizations) == [0, 1, 2, 3]
    assert numbers(result) == numbers(reference)
    assert len(list(tmp_path.glob("realization-*.json"))) == 4
    from athermal.io import count_frames

    for r in result.realizations:  # a retried realization resumed, it did not append twice
        assert count_frames(tmp_path / f"realization-{r.index:04d}.gsd") == r.steps


@pytest.mark.slow
def test_rerun_skips_finished_realizations_and_refuses_another_spec(reference, tmp_path):
    first = run_ensemble(SPEC, tmp_path, 2, seed=11, workers=1)
    assert first.computed == [0, 1]
    more = run_ensemble(SPEC, tmp_path, 3, seed=11, workers=1)
    assert more.computed == [2] and numbers(more) == numbers(reference)[:3]
    again = run_ensemble(SPEC, tmp_path, 3, seed=11, workers=1)
    assert again.computed == [] and again.engine.startswith("none")
    with pytest.raises(InputError, match="another spec or seed"):
        run_ensemble(SPEC, tmp_path, 3, seed=12)


def test_without_dask_the_same_realizations_run_sequentially(reference, tmp_path, monkeypatch):
    real_import = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name.startswith("dask"):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_dask)
    with pytest.warns(UserWarning, match=r"Dask is not installed"):
        result = run_ensemble(SPEC, tmp_path, 2, seed=11)
    assert result.engine == "sequential" and numbers(result) == numbers(reference)[:2]
    with pytest.raises(InputError, match="Dask is not installed"):
        run_ensemble(SPEC, tmp_path / "b", 1, seed=11, scheduler="tcp://127.0.0.1:1")


@pytest.mark.slow
def test_a_shear_ensemble_records_every_section_and_reads_back(tmp_path):
    from athermal.studies.experiments import CompressSpec, ShearSpec

    spec = EnsembleSpec(
        "shear",
        JamSpec(n=48, epsilon=1e-4),
        CompressSpec(delta_min=1e-3, delta_max=1e-1, per_decade=2),
        ShearSpec(strain=2e-3, step=1e-3, delta_phi=1e-2),
    )
    result = run_ensemble(spec, tmp_path, 2, seed=3, workers=1)
    for r in result.realizations:
        assert r.compression is not None and len(r.compression.rows) == 5
        assert r.shear is not None and [row["strain"] for row in r.shear.rows] == [0, 1e-3, 2e-3]
        assert abs(r.shear.delta_phi - 1e-2) < 1e-9 and r.iteration_counts is None
        stored = json.loads((tmp_path / f"realization-{r.index:04d}.json").read_text())
        assert Realization.from_json(stored) == r
    # A jammed packing stays jammed under a small compression and far above any phi_c; in
    # between, a packing of 48 may rearrange and unjam (measured: one of these two, jammed at
    # 0.817, unjams at Delta phi = 3e-3, with p = 0 on an Intel Xeon and p = 6e-15 from one
    # contact of round-off on an AMD EPYC). The pooled fit takes each compression's rows up to
    # its first unjammed step: after it the packing has left the basin of its phi_c.
    rows = [row for r in result.realizations for row in r.compression.rows]
    for r in result.realizations:
        assert r.compression.rows[0]["pressure"] > 0.0 and r.compression.rows[-1]["pressure"] > 0.0

    def in_basin(steps):
        unjammed = [k for k, row in enumerate(steps) if "unjammed" in row["events"]]
        return steps[: unjammed[0]] if unjammed else steps

    jammed = [row for r in result.realizations for row in in_basin(r.compression.rows)]
    pooled = result.summary["pooled_exponent_p"]
    assert pooled["points"] == len(jammed) > len(rows) / 2
    assert 0.7 < pooled["exponent"] < 1.3
    assert result.summary["plastic_events"]["n"] == 2


def test_a_scheduler_that_does_not_answer_leaves_nothing_behind(tmp_path, monkeypatch):
    """Reached before the directory is touched: a new one is not created, an existing one
    keeps exactly what it held."""
    import athermal.studies.ensemble

    monkeypatch.setattr(athermal.studies.ensemble, "CONNECT_TIMEOUT", 0.5)
    new, kept = tmp_path / "new", tmp_path / "kept"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine\n")
    for directory in (new, kept):
        with pytest.raises(InputError, match=r"--scheduler: cannot reach tcp://127\.0\.0\.1:1"):
            run_ensemble(SPEC, directory, 2, seed=11, scheduler="tcp://127.0.0.1:1")
    assert not new.exists() and [p.name for p in kept.iterdir()] == ["notes.txt"]
