"""GSD files: exact round trips, the HOOMD chunks of the contract, foreign files, errors."""

from __future__ import annotations

from pathlib import Path

import gsd.fl
import gsd.hoomd
import numpy as np
import pytest

import athermal.atomic
from athermal.errors import FileFormatError, InputError
from athermal.io import append_gsd, count_frames, read_gsd, write_gsd
from athermal.model.cell import Cell, simple_shear
from athermal.model.contact import ContactModel
from athermal.model.packing import Packing, random_packing


def sheared_unwrapped(dim: int, seed: int, n: int = 64) -> Packing:
    """Bidisperse packing in a sheared cell, positions moved by random lattice vectors."""
    p = random_packing(n, 0.6, dim=dim, seed=seed).deform(simple_shear(0.3, dim))
    shifts = np.random.default_rng(seed).integers(-3, 4, size=(n, dim))
    return p.with_positions(p.positions + shifts @ p.cell.h.T)


def observables_for(p: Packing) -> dict[str, object]:
    stress = np.arange(p.dim * p.dim, dtype=np.float64).reshape(p.dim, p.dim) / 7.0
    return {
        "energy": 1.0 / 3.0,
        "pressure": np.float64(2.0e-5),
        "stress": stress,
        "phi": p.phi,
        "overlap_per_particle": np.linspace(0.0, 1.0, p.n) ** np.pi,
    }


def foreign_frame(box, dim: int, positions, diameter=None, log=None) -> gsd.hoomd.Frame:
    """A HOOMD frame as another tool would write it (no log/athermal unless given)."""
    frame = gsd.hoomd.Frame()
    frame.configuration.box = box
    frame.configuration.dimensions = dim
    frame.particles.N = len(positions)
    frame.particles.position = positions
    if diameter is not None:
        frame.particles.diameter = diameter
    frame.log = dict(log or {})
    return frame


def write_foreign(path: Path, *frames: gsd.hoomd.Frame) -> None:
    with gsd.hoomd.open(str(path), "w") as traj:
        for frame in frames:
            traj.append(frame)


def assert_same_packing(a: Packing, b: Packing) -> None:
    assert np.array_equal(a.positions, b.positions)
    assert np.array_equal(a.radii, b.radii)
    assert np.array_equal(a.cell.h, b.cell.h)
    assert a.positions.dtype == a.radii.dtype == a.cell.h.dtype == np.float64


@pytest.mark.parametrize("dim", [2, 3])
def test_round_trip_is_bit_identical(tmp_path, dim):
    p = sheared_unwrapped(dim, seed=dim)
    assert not np.array_equal(p.positions, p.cell.wrap(p.positions))  # really unwrapped
    model = ContactModel(2.5, np.array([[1.0, 0.7], [0.7, 1.0 / 3.0]]))
    obs = observables_for(p)
    path = tmp_path / "p.gsd"
    write_gsd(path, p, model=model, seed=2**63 + 5, observables=obs)

    frame = read_gsd(path)
    assert_same_packing(frame.packing, p)
    assert frame.model is not None
    assert frame.model.alpha == 2.5 and np.array_equal(frame.model.kmat, model.kmat)
    assert frame.seed == 2**63 + 5 and isinstance(frame.seed, int)
    assert set(frame.log) == set(obs)
    for name, value in obs.items():
        got = frame.log[name]
        assert got.dtype == np.float64 and got.shape == np.shape(value), name
        assert np.array_equal(got, value), name
    assert frame.log["stress"].shape == (dim, dim)
    assert count_frames(path) == 1


def test_round_trip_without_extras_and_with_a_scalar_stiffness(tmp_path):
    p = random_packing(32, 0.5, seed=4)
    write_gsd(tmp_path / "bare.gsd", p)
    bare = read_gsd(tmp_path / "bare.gsd")
    assert bare.model is None and bare.seed is None and bare.log == {}
    assert_same_packing(bare.packing, p)

    write_gsd(str(tmp_path / "scalar.gsd"), p, model=ContactModel(2.0, 3.5), seed=0)
    frame = read_gsd(tmp_path / "scalar.gsd", frame=0)
    assert frame.model is not None and frame.seed == 0
    assert frame.model.stiffness == 3.5 and frame.model.kmat.shape == (1, 1)


@pytest.mark.parametrize("dim", [2, 3])
def test_hoomd_chunks_hold_what_the_contract_says(tmp_path, dim):
    p = sheared_unwrapped(dim, seed=10 + dim)
    write_gsd(tmp_path / "p.gsd", p, model=ContactModel(2.0), seed=3)
    with gsd.hoomd.open(str(tmp_path / "p.gsd"), "r") as traj:
        assert len(traj) == 1
        snap = traj[0]
    assert snap.configuration.dimensions == dim
    np.testing.assert_array_equal(snap.configuration.box, p.cell.to_hoomd().astype(np.float32))
    if dim == 2:
        assert snap.configuration.box[2] == 1.0
        assert snap.configuration.box[4] == snap.configuration.box[5] == 0.0
    assert snap.configuration.box[3] == pytest.approx(0.3)
    assert snap.particles.N == p.n
    pos = snap.particles.position
    assert pos.shape == (p.n, 3) and pos.dtype == np.float32
    if dim == 2:
        assert np.all(pos[:, 2] == 0.0)
    # inside the box centred on the origin, as HOOMD-blue computes it from the stored chunks
    box_cell = Cell.from_hoomd(snap.configuration.box.astype(np.float64), dim)
    s = box_cell.fractional(pos[:, :dim].astype(np.float64))
    assert np.all(s >= -0.5) and np.all(s < 0.5)
    np.testing.assert_allclose(pos[:, :dim], p.cell.wrap(p.positions), rtol=0, atol=1e-7)
    np.testing.assert_array_equal(snap.particles.diameter, (2.0 * p.radii).astype(np.float32))
    small = p.radii == p.radii.min()
    assert np.all(snap.particles.typeid[small] == 0) and np.all(snap.particles.typeid[~small] == 1)
    assert snap.particles.types == ["A", "B"]
    assert snap.log["athermal/position"].dtype == np.float64
    assert np.array_equal(snap.log["athermal/position"], p.positions)
    assert np.array_equal(snap.log["athermal/radius"], p.radii)
    assert np.array_equal(snap.log["athermal/cell"], p.cell.h)
    assert snap.log["athermal/alpha"].tolist() == [2.0]
    assert snap.log["athermal/seed"].tolist() == [3]


def test_particles_on_a_face_are_written_strictly_inside_the_box(tmp_path):
    cell = Cell.box([1.0, 1.0])
    edge = 0.5 - 1e-9  # rounds to 0.5 in float32
    x = np.array([[edge, edge], [-0.5, -0.5], [0.5, -edge], [np.nextafter(0.5, 0.0), 0.0]])
    p = Packing(x, np.full(4, 0.05), cell)
    write_gsd(tmp_path / "edge.gsd", p)
    with gsd.hoomd.open(str(tmp_path / "edge.gsd"), "r") as traj:
        pos = traj[0].particles.position[:, :2].astype(np.float64)
    assert np.all(pos >= -0.5) and np.all(pos < 0.5)
    np.testing.assert_allclose(pos, cell.wrap(x), rtol=0, atol=2e-6)
    assert np.array_equal(read_gsd(tmp_path / "edge.gsd").packing.positions, x)


@pytest.mark.parametrize(
    ("dim", "box"),
    [(2, [10.0, 8.0, 1.0, 0.25, 0.0, 0.0]), (3, [10.0, 9.0, 8.0, 0.2, -0.3, 0.4])],
)
def test_file_written_by_gsd_alone_is_read_from_the_hoomd_chunks(tmp_path, dim, box):
    rng = np.random.default_rng(5)
    cell = Cell.from_hoomd(np.array(box, dtype=np.float32).astype(np.float64), dim)
    pos = np.zeros((20, 3), dtype=np.float32)
    pos[:, :dim] = cell.cartesian(rng.random((20, dim)) - 0.5)
    diameter = rng.choice([1.0, 1.4], size=20).astype(np.float32)
    write_foreign(tmp_path / "f.gsd", foreign_frame(box, dim, pos, diameter))

    frame = read_gsd(tmp_path / "f.gsd")
    assert frame.model is None and frame.seed is None and frame.log == {}
    assert np.array_equal(frame.packing.cell.h, cell.h)
    assert frame.packing.positions.shape == (20, dim)
    assert np.array_equal(frame.packing.positions, pos[:, :dim].astype(np.float64))
    assert np.array_equal(frame.packing.radii, diameter.astype(np.float64) / 2.0)


def test_foreign_file_with_default_diameters_is_accepted(tmp_path):
    pos = np.array([[0.0, 0.0, 0.0], [3.0, 3.0, 0.0]], dtype=np.float32)
    write_foreign(tmp_path / "f.gsd", foreign_frame([10.0, 10.0, 0.0, 0.0, 0.0, 0.0], 2, pos))
    frame = read_gsd(tmp_path / "f.gsd")
    assert np.array_equal(frame.packing.radii, [0.5, 0.5])
    assert np.array_equal(frame.packing.cell.h, np.diag([10.0, 10.0]))


def test_trajectory_append_and_random_access(tmp_path):
    path = tmp_path / "traj.gsd"
    packings = [sheared_unwrapped(2, seed=k, n=40 + k) for k in range(3)]
    seeds = [7, None, 9]
    for k, (p, seed) in enumerate(zip(packings, seeds, strict=True)):
        assert append_gsd(path, p, seed=seed, observables={"step": float(k)}) == k + 1
        assert count_frames(path) == k + 1
    for k, (p, seed) in enumerate(zip(packings, seeds, strict=True)):
        frame = read_gsd(path, frame=k)
        assert_same_packing(frame.packing, p)
        assert frame.seed == seed  # not inherited from frame 0
        assert frame.log["step"] == k and frame.log["step"].shape == ()
    assert_same_packing(read_gsd(path).packing, packings[-1])
    assert_same_packing(read_gsd(path, frame=-3).packing, packings[0])
    with gsd.hoomd.open(str(path), "r") as traj:
        assert [int(f.configuration.step) for f in traj] == [0, 1, 2]
        assert [int(f.particles.N) for f in traj] == [40, 41, 42]


def test_append_to_a_single_frame_file_and_to_a_non_gsd_file(tmp_path):
    p = random_packing(16, 0.5, seed=1)
    write_gsd(tmp_path / "one.gsd", p)
    assert append_gsd(tmp_path / "one.gsd", p.scale_radii(1.1)) == 2
    assert np.array_equal(read_gsd(tmp_path / "one.gsd").packing.radii, p.radii * 1.1)

    text = tmp_path / "notes.gsd"
    text.write_text("not a gsd file\n")
    with pytest.raises(FileFormatError, match=r"notes\.gsd"):
        append_gsd(text, p)
    assert text.read_text() == "not a gsd file\n"


def assert_one_line_error(call, path: Path, match: str) -> None:
    with pytest.raises(FileFormatError, match=match) as info:
        call()
    message = str(info.value)
    assert str(path) in message and "\n" not in message


def test_unreadable_files_raise_file_format_errors(tmp_path):
    missing = tmp_path / "missing.gsd"
    assert_one_line_error(lambda: read_gsd(missing), missing, "no such file")
    assert_one_line_error(lambda: count_frames(missing), missing, "no such file")
    assert_one_line_error(lambda: read_gsd(tmp_path), tmp_path, "not a regular file")

    text = tmp_path / "text.gsd"
    text.write_text("hello\n" * 100)
    assert_one_line_error(lambda: read_gsd(text), text, "not a readable GSD")

    good = tmp_path / "good.gsd"
    write_gsd(good, random_packing(64, 0.5, seed=2), observables={"energy": 1.0})
    cut = tmp_path / "cut.gsd"
    data = good.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    assert_one_line_error(lambda: read_gsd(cut), cut, "not a readable GSD")
    assert_one_line_error(lambda: count_frames(cut), cut, "not a readable GSD")

    other = tmp_path / "other.gsd"
    with gsd.fl.open(str(other), "w", application="t", schema="other", schema_version=(1, 0)) as f:
        f.write_chunk("value", np.ones(3))
        f.end_frame()
    assert_one_line_error(lambda: read_gsd(other), other, "HOOMD schema")

    empty = tmp_path / "empty.gsd"
    write_foreign(empty)
    assert count_frames(empty) == 0
    assert_one_line_error(lambda: read_gsd(empty), empty, "no frames")


def test_frame_index_out_of_range(tmp_path):
    path = tmp_path / "p.gsd"
    write_gsd(path, random_packing(16, 0.5, seed=3))
    assert_one_line_error(lambda: read_gsd(path, frame=1), path, "frame 1 out of range")
    assert_one_line_error(lambda: read_gsd(path, frame=-2), path, "out of range")
    with pytest.raises(InputError, match="frame"):
        read_gsd(path, frame=True)


def test_invalid_content_is_reported_with_the_path(tmp_path):
    p = random_packing(8, 0.5, seed=6)
    box = p.cell.to_hoomd()
    pos = np.zeros((8, 3), dtype=np.float32)
    exact = {
        "athermal/position": p.positions.copy(),
        "athermal/radius": p.radii,
        "athermal/cell": p.cell.h,
    }
    exact["athermal/position"][3, 1] = np.nan
    nan_file = tmp_path / "nan.gsd"
    write_foreign(nan_file, foreign_frame(box, 2, pos, 2 * p.radii, exact))
    assert_one_line_error(lambda: read_gsd(nan_file), nan_file, "positions: contains NaN")

    zero = tmp_path / "zero.gsd"
    write_foreign(zero, foreign_frame(box, 2, pos, np.zeros(8)))
    assert_one_line_error(lambda: read_gsd(zero), zero, "radii: must be > 0")

    shapes = tmp_path / "shapes.gsd"
    bad = {**exact, "athermal/position": p.positions[:5]}
    write_foreign(shapes, foreign_frame(box, 2, pos, 2 * p.radii, bad))
    assert_one_line_error(lambda: read_gsd(shapes), shapes, r"position has shape \(5, 2\)")

    partial = tmp_path / "partial.gsd"
    write_foreign(partial, foreign_frame(box, 2, pos, 2 * p.radii, {"athermal/radius": p.radii}))
    assert_one_line_error(lambda: read_gsd(partial), partial, "missing position, cell")


def test_bad_arguments_raise_input_errors_and_write_nothing(tmp_path):
    p = random_packing(16, 0.5, seed=1)
    path = tmp_path / "p.gsd"
    bad_calls = [
        lambda: write_gsd(path, p.positions),  # type: ignore[arg-type]
        lambda: write_gsd(path, p, seed=-1),
        lambda: write_gsd(path, p, seed=1.5),  # type: ignore[arg-type]
        lambda: write_gsd(path, p, model=ContactModel(2.0, np.ones((3, 3)))),
        lambda: write_gsd(path, p, observables={"radius": 1.0}),
        lambda: write_gsd(path, p, observables={"energy": np.nan}),
        lambda: write_gsd(path, p, observables={"cube": np.ones((2, 2, 2))}),
        lambda: write_gsd(path, p, observables={"column": np.ones((3, 1))}),
        lambda: append_gsd(path, p, observables={"": 1.0}),
    ]
    for call in bad_calls:
        with pytest.raises(InputError):
            call()
        assert list(tmp_path.iterdir()) == []


def test_write_replaces_an_existing_file(tmp_path):
    path = tmp_path / "p.gsd"
    write_gsd(path, random_packing(16, 0.5, seed=1))
    q = random_packing(20, 0.6, dim=3, seed=2)
    write_gsd(path, q)
    assert count_frames(path) == 1
    assert_same_packing(read_gsd(path).packing, q)
    assert [f.name for f in tmp_path.iterdir()] == ["p.gsd"]


def failing_fsync(path: Path) -> None:
    raise OSError(28, "No space left on device")


def failing_append(self: object, frame: object) -> None:
    raise RuntimeError("interrupted while writing")


def test_failed_write_leaves_the_existing_file_and_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "p.gsd"
    write_gsd(path, random_packing(16, 0.5, seed=1), seed=1)
    before = path.read_bytes()
    q = random_packing(32, 0.7, seed=2)

    monkeypatch.setattr(athermal.atomic, "_fsync", failing_fsync)
    with pytest.raises(FileFormatError, match="No space left"):
        write_gsd(path, q)
    assert path.read_bytes() == before
    assert [f.name for f in tmp_path.iterdir()] == ["p.gsd"]

    monkeypatch.undo()
    monkeypatch.setattr(gsd.hoomd.HOOMDTrajectory, "append", failing_append)
    with pytest.raises(FileFormatError, match="interrupted"):  # gsd's errors, one line
        write_gsd(path, q)
    assert path.read_bytes() == before
    assert [f.name for f in tmp_path.iterdir()] == ["p.gsd"]

    monkeypatch.undo()
    assert read_gsd(path).seed == 1


def test_a_particle_far_outside_the_cell_is_written_with_its_contacts(tmp_path):
    from athermal.model.contact import find_contacts

    packing = random_packing(64, 0.6, dim=3, seed=1)
    moved = packing.positions.copy()
    moved[3] += 40.0  # forty cells away: the same packing
    far = packing.with_positions(moved)
    write_gsd(tmp_path / "far.gsd", far, model=ContactModel(2.0))
    assert np.array_equal(read_gsd(tmp_path / "far.gsd").packing.positions, moved)
    with gsd.hoomd.open(str(tmp_path / "far.gsd")) as traj:
        assert traj[0].bonds.N == find_contacts(packing, ContactModel(2.0)).i.size > 0


def test_files_get_the_umask_permissions_or_keep_those_they_replace(tmp_path):
    import os
    import stat

    packing = random_packing(16, 0.5, seed=1)
    mask = os.umask(0o022)
    os.umask(mask)
    expected = 0o666 & ~mask
    write_gsd(tmp_path / "one.gsd", packing)
    append_gsd(tmp_path / "traj.gsd", packing)
    append_gsd(tmp_path / "traj.gsd", packing)
    for name in ("one.gsd", "traj.gsd"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == expected
    os.chmod(tmp_path / "one.gsd", 0o600)
    write_gsd(tmp_path / "one.gsd", packing)
    assert stat.S_IMODE((tmp_path / "one.gsd").stat().st_mode) == 0o600


def test_a_killed_writers_temporary_file_is_swept_by_the_next_write(tmp_path):
    import os
    import subprocess
    import sys

    from athermal.atomic import _HOST, write_text

    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        text=True,
        capture_output=True,
        check=True,
    )
    target = tmp_path / "t.gsd"
    names = {
        "dead": f".t.{_HOST}.{int(dead.stdout)}.0123abcd.tmp.gsd",
        "alive": f".t.{_HOST}.{os.getpid()}.0123abcd.tmp.gsd",
        "elsewhere": f".t.another-host.{int(dead.stdout)}.0123abcd.tmp.gsd",
        "other target": f".u.{_HOST}.{int(dead.stdout)}.0123abcd.tmp.gsd",
    }
    for name in names.values():
        (tmp_path / name).write_bytes(b"half a frame")
    write_text(target, "done")
    left = {p.name for p in tmp_path.iterdir()}
    assert left == {"t.gsd", *names.values()} - {names["dead"]}
