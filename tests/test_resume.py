"""Checkpoint/resume of the protocol commands: a run killed with SIGKILL resumes to the result
of an uninterrupted run, bit for bit; foreign, truncated and existing files get clear errors."""

import json
import signal
import subprocess
import sys
import time

import numpy as np

from athermal.cli import main
from athermal.io import count_frames, read_gsd
from athermal.studies.tables import read_table

JAM = ["jam", "--n", "128", "--seed", "5", "--epsilon", "1e-7", "--picture", "none", "--quiet"]


def athermal(*argv, cwd):
    return subprocess.Popen(
        [sys.executable, "-m", "athermal.cli", *argv],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def frames(path):
    try:
        return count_frames(path)
    except Exception:  # not there yet, or being written
        return 0


def kill_after(proc, path, count, timeout=120.0):
    start = time.monotonic()
    while frames(path) < count:
        assert proc.poll() is None, "the run ended before it could be killed"
        assert time.monotonic() - start < timeout
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()


def test_jam_killed_with_sigkill_resumes_bit_identically(tmp_path):
    whole = athermal(*JAM, "-o", "whole.gsd", "--json", cwd=tmp_path)
    out, err = whole.communicate(timeout=300)
    assert whole.returncode == 0, err
    expected = json.loads(out)

    killed = athermal(*JAM, "-o", "cut.gsd", cwd=tmp_path)
    kill_after(killed, tmp_path / "cut.steps.gsd", 8)
    assert killed.returncode == -signal.SIGKILL and not (tmp_path / "cut.gsd").exists()
    done = frames(tmp_path / "cut.steps.gsd")
    assert 8 <= done < expected["steps"]

    resumed = athermal(*JAM, "-o", "cut.gsd", "--resume", "--json", cwd=tmp_path)
    out, err = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, err
    got = json.loads(out)
    assert got["resumed_steps"] == done and got["steps"] == expected["steps"]
    assert got["phi_c"] == expected["phi_c"] and got["iterations"] == expected["iterations"]
    a, b = read_gsd(tmp_path / "whole.gsd"), read_gsd(tmp_path / "cut.gsd")
    np.testing.assert_array_equal(a.packing.positions, b.packing.positions)
    np.testing.assert_array_equal(a.packing.radii, b.packing.radii)
    whole_rows = read_table(tmp_path / "whole.csv")
    cut_rows = read_table(tmp_path / "cut.csv")
    drop = ("seconds",)
    assert [{k: v for k, v in r.items() if k not in drop} for r in whole_rows] == [
        {k: v for k, v in r.items() if k not in drop} for r in cut_rows
    ]


def test_shear_killed_with_sigkill_resumes_bit_identically(tmp_path, capsys):
    from athermal.io import write_gsd
    from athermal.model.packing import random_packing

    write_gsd(tmp_path / "start.gsd", random_packing(128, 0.87, seed=2))
    args = ["shear", "start.gsd", "--mode", "simple", "--strain", "0.03", "--step", "1e-3"]
    whole = athermal(*args, "-o", "whole.gsd", "--quiet", cwd=tmp_path)
    assert whole.wait(timeout=300) == 0
    killed = athermal(*args, "-o", "cut.gsd", "--quiet", cwd=tmp_path)
    kill_after(killed, tmp_path / "cut.gsd", 10)
    resumed = athermal(*args, "-o", "cut.gsd", "--resume", "--quiet", cwd=tmp_path)
    assert resumed.wait(timeout=300) == 0
    n = count_frames(tmp_path / "whole.gsd")
    assert count_frames(tmp_path / "cut.gsd") == n == 31
    for k in (n - 1, 12):
        a = read_gsd(tmp_path / "whole.gsd", frame=k)
        b = read_gsd(tmp_path / "cut.gsd", frame=k)
        np.testing.assert_array_equal(a.packing.positions, b.packing.positions)
        assert float(a.log["tau"]) == float(b.log["tau"])


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_existing_foreign_and_truncated_trajectories_are_refused(tmp_path, capsys):
    out = tmp_path / "j.gsd"
    base = ["jam", "--n", "32", "--seed", "1", "--epsilon", "1e-4", "--picture", "none"]
    assert run(capsys, *base, "-o", str(out))[0] == 0
    steps = tmp_path / "j.steps.gsd"
    before = steps.read_bytes()
    code, _, err = run(capsys, *base, "-o", str(out))
    assert code == 2 and "--resume" in err and "--overwrite" in err
    code, _, err = run(
        capsys, *base[:-4], "--seed", "2", "--epsilon", "1e-4", "-o", str(out), "--resume"
    )
    assert code == 2 and "another run" in err
    assert steps.read_bytes() == before  # refused runs leave the file alone
    code, _, _ = run(capsys, *base, "-o", str(out), "--resume")  # finished: nothing to redo
    assert code == 0 and steps.read_bytes() == before
    steps.write_bytes(before[: len(before) // 2])
    code, _, err = run(capsys, *base, "-o", str(out), "--resume")
    assert code == 2 and str(steps) in err and len(err.strip().splitlines()) == 1
    code, _, _ = run(capsys, *base, "-o", str(out), "--overwrite")
    assert code == 0 and count_frames(steps) > 3
