"""Bad input refused at the door, outputs never lost or half-written, one writer per output."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from athermal.cli import main
from athermal.io import count_frames, read_gsd, write_gsd
from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.model.packing import random_packing
from athermal.relaxation import minimize_objective

JAM = ["jam", "--n", "64", "--seed", "1", "--epsilon", "1e-5", "--picture", "none", "--quiet"]
LONG_JAM = [*JAM, "--n", "512", "--epsilon", "1e-8"]  # runs for seconds: time to interfere


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden lock files aside) with its contents."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and not p.name.endswith(".lock")
    }


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A folder with a jammed packing (and its trajectory and table), an unjammed one, a damaged
    file and a folder."""
    folder = tmp_path_factory.mktemp("files")
    assert main([*JAM, "-o", str(folder / "j.gsd")]) == 0
    loose = minimize_objective(
        Objective(random_packing(64, 0.6, seed=2), ContactModel()), rtol=1e-9
    )
    write_gsd(folder / "r.gsd", loose.packing)  # relaxed and unjammed
    (folder / "bad.gsd").write_bytes(b"GSD but not really" * 10)
    (folder / "sub").mkdir()
    (folder / "old").mkdir()
    (folder / "old" / "report.md").write_text("an earlier athermal paper run")
    return folder


BAD = [
    ["random", "--n", "0"],
    ["random", "--n", "-5"],
    ["random", "--n", "1000000000000"],
    ["random", "--phi", "1.5"],
    ["random", "--phi", "-1e-3"],
    ["random", "--phi", "nan"],
    ["random", "--seed", "-1"],
    ["random", "--size-ratio", "0.5"],
    ["random", "--sizes", "uniform", "--polydispersity", "0.6"],
    ["random", "--sizes", "lognormal", "--polydispersity", "0"],
    ["jam", "--sizes", "lognormal", "--polydispersity", "1.5"],
    ["ensemble", "jam", "--realizations", "2", "--sizes", "uniform", "--polydispersity", "-0.1"],
    ["random", "--alpha", "1.5"],
    ["random", "--stiffness", "-1"],
    ["random", "-o", ""],
    ["random", "-o", "sub"],
    ["random", "-o", "nodir/x.gsd"],
    ["random", "-o", "/dev/null"],
    ["random", "-o", "r.gsd"],  # exists, no --overwrite
    ["jam", "--epsilon", "0"],
    ["jam", "--epsilon", "-1e-6"],
    ["jam", "--dphi", "1e-300"],
    ["jam", "--dphi", "inf"],
    ["jam", "--n", "2"],
    ["jam", "--pressure", "-1e-3"],
    ["jam", "--pressure", "1e-3", "--pressure-rtol", "2"],
    ["modes", "j.gsd", "-o", "m.txt"],
    ["modes", "j.gsd", "--lowest", "0", "-o", "m.npz"],
    ["jam", "--maxiter", "0"],
    ["jam", "--phi-init", "1.2"],
    ["jam", "-o", "t.csv"],
    ["jam", "-o", "x.gsd", "--trajectory", "x.gsd"],
    ["jam", "--table", "nodir/t.csv"],
    ["jam", "--picture", "nodir/p.png"],
    ["jam", "-o", "j.gsd"],  # its trajectory exists
    ["compress", "j.gsd", "--rtol", "-1"],
    ["compress", "j.gsd", "--per-decade", "1000000000"],
    ["compress", "j.gsd", "--from", "1e-2", "--to", "1e-3"],
    ["compress", "r.gsd"],  # not jammed
    ["compress", "bad.gsd"],
    ["compress", "missing.gsd"],
    ["compress", "j.gsd", "-o", "j.gsd"],
    ["shear", "j.gsd", "--step", "0"],
    ["shear", "j.gsd", "--strain", "1e6", "--step", "1e-6"],
    ["shear", "j.gsd", "--step", "0.1", "--strain", "0.01"],
    ["relax", "bad.gsd"],
    ["relax", "r.gsd", "--rtol", "0"],
    ["relax", "r.gsd", "--pressure", "1e-3", "--method", "newton"],
    ["relax", "r.gsd", "--pressure", "1e-3", "--precon", "contact"],
    ["relax", "r.gsd", "--pressure", "-1"],
    ["measure", "bad.gsd"],
    ["measure", "j.gsd", "--frame", "7"],
    ["ensemble", "jam", "--realizations", "0"],
    ["ensemble", "jam", "--realizations", "2", "--workers", "0"],
    ["ensemble", "jam", "--realizations", "2", "--workers", "-1"],
    ["ensemble", "jam", "--realizations", "2", "--epsilon", "0"],
    ["paper", "-o", "r.gsd"],
    ["paper", "-o", "old"],  # holds an earlier report, no --overwrite
    ["paper", "-o", "nodir/p"],
    # an output that names a folder, or a folder no file can be made in
    ["random", "-o", "."],
    ["jam", "-o", "sub/"],
    ["relax", "r.gsd", "-o", "sub"],
    ["jam", "--table", "sub"],
    ["random", "-o", "/proc/x.gsd"],
    ["paper", "-o", "/proc/p"],
    # a target out of reach
    ["jam", "--dphi", "0.5"],  # past phi = 1 in one step
    ["jam", "--n", "256", "--pressure", "1"],  # harmonic disks reach p ~ 0.1 below phi = 1
    # options that would do nothing
    ["relax", "r.gsd", "--cell", "shape"],
    ["relax", "r.gsd", "--solver", "amg"],
    ["relax", "r.gsd", "--A", "1"],
    ["relax", "r.gsd", "--backend", "jax", "--solver", "direct", "--precon", "exp"],
    ["jam", "--resume", "-o", "new.gsd"],
    ["compress", "j.gsd", "--resume", "-o", "new.gsd"],
    ["jam", "--dim", "3", "--picture", "p.png"],
    ["jam", "--polydispersity", "0.2"],
    ["jam", "--sizes", "uniform", "--size-ratio", "2"],
    ["jam", "--pressure-rtol", "0.1"],
    ["shear", "j.gsd", "--wall-layer", "0.1"],
]


def _with_output(argv: list[str]) -> list[str]:
    needs = {"random", "jam", "compress", "shear", "relax", "ensemble"}
    if argv[0] in needs and "-o" not in argv:
        argv = [*argv, "-o", {"ensemble": "ens"}.get(argv[0], "out.gsd")]
    return argv


@pytest.mark.parametrize("argv", BAD, ids=[" ".join(a) for a in BAD])
def test_bad_input_is_refused_in_one_line_and_touches_nothing(files, argv, monkeypatch, capsys):
    monkeypatch.chdir(files)
    before = snapshot(files)
    code = main(_with_output(argv))
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"athermal {argv[0]}: error: ")
    assert "Traceback" not in err
    assert snapshot(files) == before


def test_workers_without_dask_are_refused_before_any_work(files, monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "distributed" else real(name)
    )
    monkeypatch.chdir(files)
    before = snapshot(files)
    argv = ["ensemble", "jam", "--realizations", "2", "--workers", "2", "-o", "ens"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("athermal ensemble: error: --workers: Dask is not installed")
    assert err.count("\n") == 1 and snapshot(files) == before


def test_a_library_refusal_names_the_option(files, monkeypatch, capsys):
    monkeypatch.chdir(files)
    assert main(["jam", "--n", "64", "--dim", "3", "--phi-init", "0.75", "-o", "x.gsd"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("athermal jam: error: --phi-init: the start packing is jammed")
    assert not (files / "x.gsd").exists() and not (files / "x.steps.gsd").exists()


def test_a_second_writer_of_a_trajectory_is_refused_and_names_the_first(tmp_path):
    argv = [sys.executable, "-m", "athermal.cli", *LONG_JAM, "-o", "x.gsd"]
    first = subprocess.Popen(argv, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (tmp_path / "x.steps.gsd").exists():
            assert first.poll() is None and time.monotonic() < deadline
            time.sleep(0.01)
        second = subprocess.run([*argv, "--resume"], cwd=tmp_path, capture_output=True, text=True)
        assert second.returncode == 2
        assert f"another athermal run (pid {first.pid})" in second.stderr
        assert second.stderr.count("\n") == 1
    finally:
        first.kill()
        first.wait()


def test_a_dead_writer_leaves_no_stale_lock(tmp_path):
    from athermal.io import claim

    lock = claim(tmp_path / "y.gsd")
    lock.close()  # as a killed process's handle is closed by the system
    claim(tmp_path / "y.gsd").close()


def test_overwrite_removes_nothing_until_the_first_step_is_done(tmp_path, capsys):
    out = str(tmp_path / "j.gsd")
    assert main([*JAM, "-o", out]) == 0
    before = snapshot(tmp_path)
    assert main([*JAM, "-o", out, "--overwrite", "--epsilon", "0"]) == 2
    assert main([*JAM, "-o", out, "--overwrite", "--maxiter", "1"]) == 3  # fails in step 0
    assert snapshot(tmp_path) == before
    capsys.readouterr()
    assert main([*JAM, "-o", out, "--overwrite", "--epsilon", "1e-4", "--json"]) == 0
    steps = json.loads(capsys.readouterr().out)["steps"]
    assert count_frames(tmp_path / "j.steps.gsd") == steps  # replaced, not appended to


def test_sigint_ends_in_one_line_with_exit_130_and_the_run_resumes(tmp_path):
    argv = [sys.executable, "-m", "athermal.cli", *LONG_JAM, "-o", "x.gsd"]
    # the default SIGINT action for the run, even where the suite was started in the background
    # by a shell (which then ignores SIGINT, and the run would inherit that)
    run = subprocess.Popen(
        argv,
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 120
    while count_frames_safe(tmp_path / "x.steps.gsd") < 3:
        assert run.poll() is None and time.monotonic() < deadline
        time.sleep(0.01)
    run.send_signal(signal.SIGINT)
    _, err = run.communicate(timeout=60)
    assert run.returncode == 130, err
    assert err == "athermal jam: interrupted; rerun with --resume to continue\n"
    again = subprocess.run([*argv, "--resume"], cwd=tmp_path, capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    assert read_gsd(tmp_path / "x.gsd").log["phi_c"] > 0.7


def count_frames_safe(path: Path) -> int:
    try:
        return count_frames(path)
    except Exception:
        return 0


def test_coincident_particles_are_named(tmp_path, capsys):
    import gsd.hoomd

    p = random_packing(16, 0.5, seed=1)
    write_gsd(tmp_path / "ok.gsd", p)
    with gsd.hoomd.open(str(tmp_path / "ok.gsd")) as traj:
        frame = traj[0]
    frame.log["athermal/position"][7] = frame.log["athermal/position"][3]  # another tool's file
    frame.particles.position[7] = frame.particles.position[3]
    with gsd.hoomd.open(str(tmp_path / "c.gsd"), "x") as out:
        out.append(frame)
    source, target = str(tmp_path / "c.gsd"), str(tmp_path / "r.gsd")
    relax = ["relax", source, "-o", target]
    for argv in (
        ["measure", source],
        relax,
        [*relax, "--gtol", "1e-9"],
        [*relax, "--pressure", "0.1"],
    ):
        code = main(argv)
        _, err = capsys.readouterr()
        assert code == 2 and "particles 3 and 7 coincide" in err and err.count("\n") == 1
    assert not (tmp_path / "r.gsd").exists()


def test_a_damaged_realization_is_computed_again(tmp_path):
    from athermal.studies.ensemble import EnsembleSpec, run_ensemble
    from athermal.studies.experiments import JamSpec

    spec = EnsembleSpec("jam", JamSpec(n=32, epsilon=1e-4))
    first = run_ensemble(spec, tmp_path / "e", 2, workers=1)
    (tmp_path / "e" / "realization-0001.json").write_text("{not json")
    with pytest.warns(UserWarning, match="realization-0001.json: unreadable"):
        again = run_ensemble(spec, tmp_path / "e", 2, workers=1)
    assert again.computed == [1]
    assert again.realizations[1].phi_c == first.realizations[1].phi_c


def _can_mount_tmpfs(folder: Path) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(folder)], capture_output=True
    )
    if done.returncode == 0:
        subprocess.run(["umount", str(folder)], check=True)
    return done.returncode == 0


def test_a_full_disk_leaves_the_trajectory_whole_and_resumable(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    if not _can_mount_tmpfs(disk):
        pytest.skip("no tmpfs to fill (needs root and mount)")
    argv = [sys.executable, "-m", "athermal.cli", *JAM]
    whole = subprocess.run([*argv, "-o", str(tmp_path / "w.gsd")], capture_output=True)
    assert whole.returncode == 0
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=100k", "tmpfs", str(disk)], check=True)
    try:
        full = subprocess.run([*argv, "-o", str(disk / "x.gsd")], capture_output=True, text=True)
        assert full.returncode != 0 and "no space left" in full.stderr.lower()
        assert full.stderr.count("\n") == 1 and "Traceback" not in full.stderr
        kept = count_frames(disk / "x.steps.gsd")  # a whole, readable GSD file
        assert kept >= 1 and not [p for p in disk.iterdir() if p.name.endswith(".tmp")]
        shutil.copy(disk / "x.steps.gsd", tmp_path / "x.steps.gsd")
    finally:
        subprocess.run(["umount", str(disk)], check=True)
    resumed = subprocess.run(
        [*argv, "-o", str(tmp_path / "x.gsd"), "--resume"], capture_output=True, text=True
    )
    assert resumed.returncode == 0, resumed.stderr
    a, b = read_gsd(tmp_path / "w.gsd"), read_gsd(tmp_path / "x.gsd")
    np.testing.assert_array_equal(a.packing.positions, b.packing.positions)


def test_an_interrupt_reported_by_compiled_code_still_ends_in_one_line(monkeypatch, capsys):
    """numba turns a KeyboardInterrupt raised while its code calls back into Python into a
    SystemError; the command still ends as interrupted, and any other SystemError propagates."""
    from athermal import cli

    def interrupted_inside_compiled_code(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError("returned a result with an exception set") from exc

    monkeypatch.setitem(cli.COMMANDS, "jam", interrupted_inside_compiled_code)
    assert main([*JAM, "-o", "unused.gsd"]) == 130
    assert capsys.readouterr().err == "athermal jam: interrupted; rerun with --resume to continue\n"

    def broken(args):
        raise SystemError("something else")

    monkeypatch.setitem(cli.COMMANDS, "jam", broken)
    with pytest.raises(SystemError, match="something else"):
        main([*JAM, "-o", "unused.gsd"])
