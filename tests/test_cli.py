import json
import re
import subprocess
import sys

import numpy as np
import pytest

from athermal.cli import main
from athermal.io import read_gsd, write_gsd
from athermal.model.packing import random_packing

CONTRACT_MEASURE_KEYS = {
    "n",
    "dim",
    "phi",
    "energy",
    "pressure",
    "stress",
    "fabric",
    "contacts",
    "z",
    "n_rattlers",
}


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_random_then_measure_json(tmp_path, capsys):
    out_file = tmp_path / "p.gsd"
    code, out, _ = run(
        capsys,
        "random",
        "--n",
        "256",
        "--phi",
        "0.86",
        "--seed",
        "3",
        "--alpha",
        "2.5",
        "-o",
        str(out_file),
        "--json",
    )
    assert code == 0
    made = json.loads(out)
    assert made["output"] == str(out_file) and made["seed"] == 3
    frame = read_gsd(out_file)
    assert frame.seed == 3 and frame.model.alpha == 2.5
    assert float(frame.log["energy"]) == made["energy"]
    code, out, _ = run(capsys, "measure", str(out_file), "--json")
    assert code == 0
    data = json.loads(out)
    assert CONTRACT_MEASURE_KEYS <= set(data)
    assert data["n"] == 256 and data["dim"] == 2
    assert data["phi"] == pytest.approx(0.86)
    assert data["energy"] == made["energy"] and data["alpha"] == 2.5
    assert np.asarray(data["stress"]).shape == (2, 2)


def test_measure_human_output_and_model_override(tmp_path, capsys):
    path = tmp_path / "q.gsd"
    write_gsd(path, random_packing(100, 0.88, seed=1))
    code, out, _ = run(capsys, "measure", str(path))
    assert code == 0 and "pressure" in out and "z (rattlers removed)" in out
    _, a2, _ = run(capsys, "measure", str(path), "--json")
    _, a3, _ = run(capsys, "measure", str(path), "--json", "--alpha", "3")
    assert json.loads(a2)["energy"] != json.loads(a3)["energy"]


def test_measure_prints_a_steps_codes_as_text_and_the_wall_pressures(tmp_path, capsys):
    jam = ["jam", "--n", "64", "--seed", "1", "--picture", "none", "--quiet"]
    assert main([*jam, "-o", str(tmp_path / "j.gsd")]) == 0
    _, out, _ = run(capsys, "measure", str(tmp_path / "j.steps.gsd"), "--frame", "1")
    assert re.search(r"^  phase +increment$", out, re.M)  # not its index among the phases
    assert main([*jam, "--walls", "y", "-o", str(tmp_path / "w.gsd")]) == 0
    capsys.readouterr()
    _, out, _ = run(capsys, "measure", str(tmp_path / "w.gsd"))
    assert re.search(r"^wall pressure +y- \S+  y\+ \S+$", out, re.M)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["random", "--phi", "1.0", "-o", "{tmp}/x.gsd"], "phi"),
        (["random", "--n", "0", "-o", "{tmp}/x.gsd"], "n:"),
        (["random", "--alpha", "1.5", "-o", "{tmp}/x.gsd"], "alpha"),
        (["measure", "{tmp}/missing.gsd"], "no such file"),
        (["measure", "{tmp}/text.gsd"], "not a readable GSD"),
        (["measure", "{tmp}/nan.gsd"], "NaN"),
    ],
)
def test_bad_input_gives_one_line_error_and_writes_nothing(tmp_path, capsys, argv, message):
    (tmp_path / "text.gsd").write_text("not a gsd file\n")
    good = tmp_path / "good.gsd"
    write_gsd(good, random_packing(10, 0.5, seed=0))
    _write_nan_file(tmp_path / "nan.gsd")
    before = sorted(p.name for p in tmp_path.iterdir())
    code, out, err = run(capsys, *[a.format(tmp=tmp_path) for a in argv])
    assert code != 0
    assert out == ""
    assert len(err.strip().splitlines()) == 1 and message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def _write_nan_file(path):
    import gsd.hoomd

    frame = gsd.hoomd.Frame()
    frame.configuration.dimensions = 2
    frame.configuration.box = [1, 1, 1, 0, 0, 0]
    frame.particles.N = 2
    frame.particles.position = np.array([[0, 0, 0], [np.nan, 0, 0]], dtype=np.float32)
    frame.particles.diameter = np.array([0.1, 0.1], dtype=np.float32)
    with gsd.hoomd.open(str(path), "w") as traj:
        traj.append(frame)


def test_command_line_entry_point_and_help():
    done = subprocess.run(
        [sys.executable, "-m", "athermal.cli", "measure", "--help"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "--json" in done.stdout


CONTRACT_RELAX_KEYS = {
    "method",
    "converged",
    "iterations",
    "evaluations",
    "seconds",
    "energy",
    "max_gradient",
}


@pytest.mark.parametrize(
    "extra", [[], ["--method", "plbfgs"], ["--method", "cg", "--gtol", "1e-12"]]
)
def test_relax_json_and_output_file(tmp_path, capsys, extra):
    start = tmp_path / "start.gsd"
    write_gsd(start, random_packing(64, 0.88, seed=2))
    out = tmp_path / "relaxed.gsd"
    code, stdout, _ = run(capsys, "relax", str(start), "-o", str(out), "--json", *extra)
    assert code == 0
    data = json.loads(stdout)
    assert CONTRACT_RELAX_KEYS <= set(data) and data["converged"] is True
    assert data["max_gradient"] <= data["gtol"]
    frame = read_gsd(out)
    assert float(frame.log["energy"]) == pytest.approx(data["energy"], rel=1e-12)


def test_relax_that_does_not_converge_exits_3_but_writes(tmp_path, capsys):
    start = tmp_path / "start.gsd"
    write_gsd(start, random_packing(64, 0.88, seed=2))
    out = tmp_path / "relaxed.gsd"
    code, stdout, err = run(capsys, "relax", str(start), "-o", str(out), "--maxiter", "2", "--json")
    assert code == 3 and "did not converge" in err
    assert json.loads(stdout)["converged"] is False and out.exists()


def test_bench_quick_json_rows(capsys):
    code, out, err = run(
        capsys,
        "bench",
        "--cases",
        "3",
        "--alphas",
        "2.5",
        "--methods",
        "L-BFGS",
        "P-L-BFGS",
        "--repeats",
        "1",
        "--json",
    )
    assert code == 0 and err == ""  # no progress when stderr is not a terminal
    rows = json.loads(out)["rows"]
    assert [r["method"] for r in rows] == ["L-BFGS", "P-L-BFGS"]
    assert all(r["converged"] and r["grad_over_f0"] <= 1e-9 for r in rows)
    assert rows[1]["iterations"] < rows[0]["iterations"]


def test_bench_rejects_unknown_methods(capsys):
    code, out, err = run(capsys, "bench", "--methods", "BFGS", "--repeats", "1")
    assert code == 2 and out == "" and "unknown" in err


CONTRACT_JAM_KEYS = {
    "phi_c",
    "energy",
    "pressure",
    "z",
    "n_rattlers",
    "steps",
    "iterations",
    "seconds",
    "output",
}


def test_jam_compress_shear_chain_writes_files_tables_and_contract_keys(tmp_path, capsys):
    from athermal.io import count_frames
    from athermal.studies.tables import read_table

    jammed, steps = tmp_path / "j.gsd", tmp_path / "steps.gsd"
    code, out, err = run(
        capsys,
        "jam",
        "--n",
        "64",
        "--seed",
        "3",
        "--epsilon",
        "1e-5",
        "-o",
        str(jammed),
        "--trajectory",
        str(steps),
        "--json",
    )
    assert code == 0 and err == ""
    summary = json.loads(out)
    assert CONTRACT_JAM_KEYS <= set(summary)
    frame = read_gsd(jammed)
    assert float(frame.log["phi_c"]) == summary["phi_c"] == pytest.approx(frame.packing.phi)
    assert summary["phi_low"] < summary["phi_c"] == summary["phi_high"]
    assert summary["phi_high"] - summary["phi_low"] <= 1e-5
    assert float(frame.log["phi_low"]) == summary["phi_low"] and summary["checks_passed"]
    assert frame.seed == 3 and summary["energy"] > 0.0
    assert count_frames(steps) == summary["steps"] == len(read_table(tmp_path / "j.csv"))
    picture = tmp_path / "j.png"
    assert summary["picture"] == str(picture)
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and picture.stat().st_size > 10_000

    traj = tmp_path / "c.gsd"
    code, out, _ = run(
        capsys,
        "compress",
        str(jammed),
        "-o",
        str(traj),
        "--from",
        "1e-5",
        "--per-decade",
        "1",
        "--json",
    )
    assert code == 0
    summary = json.loads(out)
    assert {"table", "exponents"} <= set(summary)
    table = read_table(summary["table"])
    assert len(table) == count_frames(traj) == 5
    assert set(summary["exponents"]) == {"pressure", "shear_modulus", "z_excess"}
    assert summary["exponents"]["pressure"]["exponent"] > 0.5
    assert summary["phi_c"] == pytest.approx(float(frame.log["phi_c"]))

    code, out, _ = run(capsys, "moduli", str(traj), "--all-frames", "--json")
    assert code == 0
    frames = json.loads(out)["frames"]  # the moduli of each frame are the table's
    assert [f["frame"] for f in frames] == list(range(5))
    for row, measured in zip(table, frames, strict=True):
        assert measured["delta_phi"] == pytest.approx(row["delta_phi"], rel=1e-12)
        assert measured["bulk_phi"] == pytest.approx(row["bulk_modulus"], rel=1e-10)
        assert measured["shear"] == pytest.approx(row["shear_modulus"], rel=1e-10, abs=1e-15)

    sheared = tmp_path / "s.gsd"
    code, out, _ = run(
        capsys,
        "shear",
        str(traj),
        "-o",
        str(sheared),
        "--mode",
        "simple",
        "--strain",
        "2e-3",
        "--step",
        "1e-3",
        "--json",
    )
    assert code == 0
    summary = json.loads(out)
    rows = read_table(summary["table"])
    assert [r["strain"] for r in rows] == [0.0, 1e-3, 2e-3] and count_frames(sheared) == 3


def test_protocol_errors_are_one_line(tmp_path, capsys):
    code, out, err = run(
        capsys, "jam", "--n", "64", "--phi-init", "0.95", "-o", str(tmp_path / "x")
    )
    assert code == 2 and out == "" and "--phi-init" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def _run_with_terminal_stderr(argv, cwd):
    """Run ``athermal argv`` with stderr on a pseudo-terminal and stdout on a pipe."""
    import os
    import pty

    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "athermal.cli", *argv], cwd=cwd, stdout=subprocess.PIPE, stderr=slave
    )
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    out = proc.stdout.read().decode()
    proc.wait()
    os.close(master)
    return proc.returncode, out, b"".join(chunks).decode(errors="replace")


@pytest.mark.parametrize("quiet", [False, True])
def test_progress_goes_to_a_terminal_stderr_only_and_json_stays_clean(tmp_path, quiet):
    argv = ["jam", "--n", "48", "--seed", "2", "--epsilon", "1e-4", "--picture", "none"]
    argv += ["-o", "j.gsd", "--json"] + (["--quiet"] if quiet else [])
    code, out, terminal = _run_with_terminal_stderr(argv, tmp_path)
    assert code == 0
    assert CONTRACT_JAM_KEYS <= set(json.loads(out))
    if quiet:
        assert terminal == ""
    else:
        assert "step 0 start phi" in terminal and "bisection" in terminal


def test_compress_refuses_a_start_not_at_its_jamming_point_unless_asked(tmp_path, capsys):
    """Unjammed, unrelaxed or far above its phi_c: exit 2, one line, nothing written; with
    --from-unjammed the compression runs with one warning that says why."""
    from athermal.model.contact import ContactModel
    from athermal.model.objective import Objective
    from athermal.relaxation import minimize_objective

    model = ContactModel(2.0)
    loose = tmp_path / "loose.gsd"
    write_gsd(
        loose,
        minimize_objective(Objective(random_packing(64, 0.6, seed=1), model), rtol=1e-9).packing,
    )
    raw = tmp_path / "raw.gsd"
    write_gsd(raw, random_packing(64, 0.88, seed=1), model=model)
    dense = tmp_path / "dense.gsd"
    packing = minimize_objective(
        Objective(random_packing(64, 0.88, seed=1), model), rtol=1e-10
    ).packing
    write_gsd(dense, packing, model=model)
    cases = [
        (loose, [], "rattlers"),
        (raw, [], "above its jamming point"),
        (dense, ["--phi-c", str(packing.phi)], "above its jamming point"),
    ]
    for start, extra, why in cases:
        before = sorted(tmp_path.iterdir())
        code, out, err = run(capsys, "compress", str(start), "-o", str(tmp_path / "a.gsd"), *extra)
        assert code == 2 and out == "" and err.count("\n") == 1
        assert "not jammed" in err and why in err and "--from-unjammed" in err
        assert sorted(tmp_path.iterdir()) == before

    argv = ["compress", str(dense), "-o", str(tmp_path / "b.gsd"), "--phi-c", str(packing.phi)]
    argv += ["--from", "1e-3", "--per-decade", "1", "--json", "--from-unjammed"]
    code, out, err = run(capsys, *argv)
    assert code == 0 and set(json.loads(out)) >= {"exponents", "events", "phi_c"}
    warning = [line for line in err.splitlines() if "warning" in line]
    assert len(warning) == 1 and warning[0].startswith("athermal compress: warning: ")
    assert "above its jamming point" in warning[0]


def test_jam_prints_phi_c_as_a_number_with_its_bracket(tmp_path, capsys):
    argv = ["jam", "--n", "64", "--seed", "3", "--epsilon", "1e-5", "--picture", "none"]
    code, out, _ = run(capsys, *argv, "-o", str(tmp_path / "j.gsd"))
    line = next(line for line in out.splitlines() if line.startswith("phi_c "))
    value, bracket = line.split()[1], line.split("bracket ")[1].rstrip(")")
    assert code == 0 and len(value.split(".")[1]) == 5 and float(bracket) <= 1e-5


def test_version_is_printed():
    done = subprocess.run(
        [sys.executable, "-m", "athermal.cli", "--version"], capture_output=True, text=True
    )
    assert done.returncode == 0 and done.stdout.startswith("athermal ")


@pytest.fixture(scope="module")
def compression_file(tmp_path_factory):
    """A jammed 64-disk packing and its compression trajectory (Delta phi 1e-5 ... 1e-1)."""
    folder = tmp_path_factory.mktemp("chain")
    jammed, traj = folder / "j.gsd", folder / "c.gsd"
    base = ["--quiet", "--json"]
    jam = ["jam", "--n", "64", "--seed", "3", "--epsilon", "1e-5", "--picture", "none"]
    assert main([*jam, "-o", str(jammed), *base]) == 0
    compress = ["compress", str(jammed), "-o", str(traj), "--from", "1e-5", "--per-decade", "1"]
    assert main([*compress, *base]) == 0
    return traj


def test_shear_and_compress_start_from_the_frame_asked_for(compression_file, tmp_path, capsys):
    capsys.readouterr()
    shear = ["shear", str(compression_file), "--strain", "1e-3", "--step", "1e-3", "--json"]
    code, out, _ = run(capsys, *shear, "--delta-phi", "1.2e-3", "-o", str(tmp_path / "a.gsd"))
    picked = json.loads(out)
    assert code == 0 and picked["frame"] == 2
    assert picked["start"]["delta_phi"] == pytest.approx(1e-3)
    code, out, _ = run(capsys, *shear, "--frame", "-1", "-o", str(tmp_path / "b.gsd"))
    assert code == 0 and json.loads(out)["frame"] == 4
    first = read_gsd(tmp_path / "b.gsd", frame=0).packing
    assert np.array_equal(first.radii, read_gsd(compression_file, frame=4).packing.radii)
    code, _, err = run(capsys, *shear, "--frame", "9", "-o", str(tmp_path / "c.gsd"))
    assert code == 2 and "has 5 frames, no frame 9" in err and err.count("\n") == 1
    assert not (tmp_path / "c.gsd").exists()
    compress = ["compress", str(compression_file), "--frame", "0", "--from", "1e-3", "--json"]
    code, out, _ = run(capsys, *compress, "--per-decade", "1", "-o", str(tmp_path / "d.gsd"))
    assert code == 0 and json.loads(out)["frame"] == 0


def test_measure_prints_full_precision_and_the_frames_log(compression_file, capsys):
    frame = read_gsd(compression_file, frame=0)
    code, out, _ = run(capsys, "measure", str(compression_file), "--frame", "0")
    assert code == 0
    phi = next(line for line in out.splitlines() if line.startswith("packing fraction phi"))
    assert float(phi.split()[-1]) == frame.packing.phi  # every digit
    log = out[out.index("\nlog") :]
    assert "delta_phi" in log and "pressure" in log and "  index          0\n" in log
    code, out, _ = run(capsys, "measure", str(compression_file), "--frame", "0", "--json")
    assert json.loads(out)["log"]["delta_phi"] == float(frame.log["delta_phi"])


def test_plain_output_is_rounded_and_has_no_python_reprs(compression_file, tmp_path, capsys):
    jammed = compression_file.parent / "j.gsd"
    compress = ["compress", str(jammed), "-o", str(tmp_path / "e.gsd"), "--from", "1e-3"]
    code, out, _ = run(capsys, *compress, "--per-decade", "1")
    assert code == 0
    assert "np.float64" not in out and "{" not in out and "'" not in out
    # every number has at most 6 significant digits, packing fractions 10 (whether or not the
    # fits of this 64-disk run succeed: that depends on its trajectory)
    for line in out.splitlines():
        digits = 10 if line.strip().startswith("phi") else 6
        for token in line.split():
            mantissa = token.split("e")[0].lstrip("-")
            if mantissa.replace(".", "").isdigit():
                assert len(mantissa.replace(".", "").lstrip("0")) <= digits, line


def test_measure_of_a_sheared_copy_of_the_unit_cell_equals_the_unit_cell_s(tmp_path, capsys):
    """Cell ``[[1, 7], [0, 1]]`` is the unit square's lattice: the same observables, whether
    the file is athermal's (exact float64 state) or a plain HOOMD one (box tilt xy = 7)."""
    import gsd.hoomd

    from athermal.model.cell import Cell
    from athermal.model.packing import Packing

    square = random_packing(64, 0.86, seed=4)
    sheared = Packing(square.positions, square.radii, Cell(np.array([[1.0, 7.0], [0.0, 1.0]])))
    write_gsd(tmp_path / "square.gsd", square)
    write_gsd(tmp_path / "sheared.gsd", sheared)
    frame = gsd.hoomd.Frame()
    frame.configuration.dimensions = 2
    frame.configuration.box = [1.0, 1.0, 1.0, 7.0, 0.0, 0.0]
    frame.particles.N = square.n
    frame.particles.position = np.zeros((square.n, 3), dtype=np.float32)
    frame.particles.position[:, :2] = sheared.cell.wrap(sheared.positions)
    frame.particles.diameter = (2.0 * square.radii).astype(np.float32)
    with gsd.hoomd.open(str(tmp_path / "hoomd.gsd"), "w") as traj:
        traj.append(frame)
    measured = {}
    for name in ("square", "sheared", "hoomd"):
        code, out, err = run(capsys, "measure", str(tmp_path / f"{name}.gsd"), "--json")
        assert code == 0, err
        measured[name] = json.loads(out)
    want = measured["square"]
    assert want["contacts"] > 0 and want["pressure"] > 0.0
    for name, rel in (("sheared", 1e-12), ("hoomd", 1e-5)):  # HOOMD chunks are float32
        got = measured[name]
        assert (got["contacts"], got["n_rattlers"]) == (want["contacts"], want["n_rattlers"])
        for key in ("phi", "pressure", "energy", "z"):
            assert got[key] == pytest.approx(want[key], rel=rel), (name, key)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["bench", "--alphas", "1.5"], "--alphas: contact exponent must be a finite number >= 2"),
        (["bench", "--alphas", "2", "1.5", "--quick"], "--alphas: contact exponent must be a"),
        (["bench", "--alphas", "nan"], "--alphas: contact exponent must be a finite number >= 2"),
        (["bench", "--alphas", "3"], "--alphas: the Table has start configurations"),
        (["bench", "--quick", "--alphas", "2.5"], "--alphas: --quick sets its own"),
        (["bench", "--quick", "--repeats", "2"], "--repeats: --quick sets its own"),
        (["random", "--polydispersity", "-1", "-o", "{tmp}/x.gsd"], "--polydispersity: must"),
        (["random", "--seed", str(2**64), "-o", "{tmp}/x.gsd"], "--seed: must be an integer"),
        (["random", "--seed", "1" + "0" * 400, "-o", "{tmp}/x.gsd"], "--seed: must be"),
    ],
)
def test_list_valued_and_odd_numeric_options_are_checked_at_the_door(
    tmp_path, capsys, monkeypatch, argv, message
):
    """Refused in one line naming the flag, before any work (the Table never starts)."""
    from athermal.studies import bench

    def no_work(*args, **kwargs):
        raise AssertionError("the Table ran")

    monkeypatch.setattr(bench, "table1", no_work)
    code, out, err = run(capsys, *[a.format(tmp=tmp_path) for a in argv])
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and f"error: {message}" in err
    assert list(tmp_path.iterdir()) == []


def test_a_misspelt_option_is_named_before_a_missing_required_one(capsys):
    """``--ouput`` for ``-o``: argparse's unknown-option message, not "-o required"."""
    with pytest.raises(SystemExit) as stop:
        main(["jam", "--n", "64", "--ouput", "x.gsd"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.count("\n") == 1
    assert err.startswith("athermal jam: error: unrecognized arguments: --ouput x.gsd")
    with pytest.raises(SystemExit) as stop:  # nothing unknown: the missing one is named
        main(["jam", "--n", "64"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "required: -o/--output" in err
    for argv, required in (
        (["jam", "--help"], "-o OUTPUT"),
        (["ensemble", "jam", "-h"], "-o OUTPUT"),
    ):
        with pytest.raises(SystemExit) as stop:  # the usage shows a required option as such
            main(argv)
        usage = " ".join(capsys.readouterr().out.split())
        assert stop.value.code == 0 and required in usage and f"[{required}]" not in usage


def test_ensemble_with_an_unreachable_scheduler_leaves_nothing_behind(
    tmp_path, capsys, monkeypatch
):
    pytest.importorskip("dask.distributed")
    monkeypatch.setattr("athermal.studies.ensemble.CONNECT_TIMEOUT", 0.5)
    out = tmp_path / "E"
    argv = ["ensemble", "jam", "--realizations", "2", "--scheduler", "tcp://127.0.0.1:1"]
    code, stdout, err = run(capsys, *argv, "-o", str(out), "--quiet")
    assert code == 2 and stdout == "" and err.count("\n") == 1
    assert "error: --scheduler: cannot reach tcp://127.0.0.1:1" in err
    assert list(tmp_path.iterdir()) == []


def test_unknown_option_is_named_by_its_subcommand(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["jam", "-o", "x.gsd", "--no-such-option"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.startswith("athermal jam: error: unrecognized arguments")
    assert "athermal jam --help" in err and err.count("\n") == 1


@pytest.mark.parametrize(
    "command",
    ["random", "measure", "relax", "jam", "compress", "shear", "ensemble shear", "bench"],
)
def test_every_default_is_in_the_help(command, capsys):
    from athermal.cli.parser import build, subparser

    parser = build()
    for word in command.split():
        parser = subparser(parser, word)
    text = parser.format_help().replace("\n", " ")
    for action in parser._actions:
        if action.option_strings and action.default not in (None, False, "==SUPPRESS=="):
            help_text = " ".join(parser._get_formatter()._expand_help(action).split())
            assert "default" in help_text and help_text in " ".join(text.split()), action.dest


def test_help_shows_each_default_once_and_an_ensemble_protocol_its_own_options():
    from athermal.cli.parser import build, subparser

    jam = " ".join(subparser(build(), "jam").format_help().split())
    assert "(default: none, periodic)" in jam and "(default: )" not in jam
    ensemble = subparser(build(), "ensemble")
    own = " ".join(subparser(ensemble, "jam").format_help().split())
    assert "--dphi" in own and "--strain" not in own and "--from" not in own
    shear = " ".join(subparser(ensemble, "shear").format_help().split())
    assert "--strain" in shear and "--shear-delta-phi" in shear


@pytest.mark.parametrize(("dim", "n"), [(2, 128), (3, 256)])
def test_jam_a_polydisperse_packing_and_resume_only_the_same_sizes(tmp_path, capsys, dim, n):
    out = tmp_path / "j.gsd"
    argv = ["jam", "--n", str(n), "--dim", str(dim), "--seed", "4", "--epsilon", "1e-4"]
    argv += ["--picture", "none", "--quiet", "-o", str(out), "--sizes", "lognormal"]
    code, text, _ = run(capsys, *argv, "--polydispersity", "0.3", "--json")
    assert code == 0
    made = json.loads(text)
    assert made["checks_passed"] and made["jamming_check"]["excess_contacts"] >= 0
    radii = read_gsd(out).packing.radii
    assert np.unique(radii).size == n
    assert 0.15 < radii.std() / radii.mean() < 0.45  # N draws of width 0.3
    # the trajectory belongs to this size distribution: another width is another run
    code, _, err = run(capsys, *argv, "--polydispersity", "0.2", "--resume")
    assert code == 2 and "another run" in err


def test_moduli_by_finite_strain_agree_with_linear_response(tmp_path, capsys):
    """A packing well above jamming: the quasi-static measurement to 1e-5 gives the linear
    response's B and G to first order in the strain."""
    from athermal.model.contact import ContactModel
    from athermal.relaxation import relax

    packing = relax(random_packing(128, 0.9, seed=2), ContactModel(2.0), rtol=1e-12).packing
    write_gsd(tmp_path / "r.gsd", packing, model=ContactModel(2.0))
    path = str(tmp_path / "r.gsd")
    code, out, _ = run(capsys, "moduli", path, "--finite-strain", "1e-5", "--json")
    assert code == 0
    (row,) = json.loads(out)["frames"]
    assert row["shear"] > 0.0 and row["bulk"] > row["shear"]
    assert row["shear_finite"] == pytest.approx(row["shear"], rel=1e-3)
    assert row["bulk_finite"] == pytest.approx(row["bulk"], rel=1e-3)


@pytest.mark.parametrize(
    ("extra", "message"),
    [(["--finite-strain", "0"], "--finite-strain"), (["--frame", "5"], "frame")],
)
def test_moduli_bad_input_is_one_line(tmp_path, capsys, extra, message):
    write_gsd(tmp_path / "r.gsd", random_packing(32, 0.9, seed=1))
    code, _, err = run(capsys, "moduli", str(tmp_path / "r.gsd"), *extra)
    assert code == 2 and message in err and err.count("\n") == 1


def test_moduli_warns_about_a_frame_that_is_not_relaxed(tmp_path, capsys):
    write_gsd(tmp_path / "r.gsd", random_packing(32, 0.9, seed=1))
    code, out, err = run(capsys, "moduli", str(tmp_path / "r.gsd"))
    assert code == 0 and "frame 0 is not relaxed" in err and "bulk" in out


def test_figure_titles_name_the_frame_as_the_file_counts_it(tmp_path, capsys, monkeypatch):
    import athermal.cli.basic as basic

    titles = []
    real = basic.force_distribution_figure

    def recording(*args, title, **kwargs):
        titles.append(title)
        return real(*args, title=title, **kwargs)

    monkeypatch.setattr(basic, "force_distribution_figure", recording)
    write_gsd(tmp_path / "r.gsd", random_packing(32, 0.9, seed=1))
    figure = str(tmp_path / "f.png")
    assert run(capsys, "measure", str(tmp_path / "r.gsd"), "--forces-figure", figure)[0] == 0
    assert "frame 0:" in titles[0] and "frame -1" not in titles[0]


def test_plain_output_summarizes_long_lists_and_json_keeps_them():
    from athermal.cli.printer import LONGEST, lines, plain

    density = [0.5 * k for k in range(100)]
    text = "\n".join(lines(plain({"density": density, "pair": [1.0, 2.0]})))
    assert "100 values, 0 ... 49.5, mean 24.75" in text and "pair     1, 2" in text
    assert len(text.splitlines()) == 2 and len(density) > LONGEST
