"""GSD files in the HOOMD schema, with the exact float64 state kept under ``log/athermal/``.

Each configuration is one frame that OVITO, freud, HOOMD-blue and ``gsd.hoomd`` can read:
``configuration.box`` / ``dimensions``, ``particles.position`` (wrapped into the cell centred on
the origin, float32, ``z = 0`` in 2D), ``particles.diameter`` = 2 r, ``particles.typeid`` /
``types`` from :meth:`Packing.types`. Because those chunks are float32, the packing is also stored
exactly in ``log/athermal/``: ``position`` ``(N, d)`` (as given, not wrapped), ``radius``
``(N,)``, ``cell`` ``(d, d)``, ``walls`` (int8, the walled axes: 1 = ``y``; absent for a
periodic cell); then ``alpha`` and ``stiffness`` ``(T, T)`` of the contact model (and
``wall_stiffness`` when set), ``seed`` (uint64) and the observables of the frame. Reading
prefers that copy, so a round trip is bit-identical; a file written by another tool is read
from the HOOMD chunks (as a periodic cell).

Walls: the box is the cell, and its faces normal to a walled axis are the walls, so OVITO's
simulation cell is the container; HOOMD's box has no notion of walls (its periodic flags are
not in the schema), so a reader must take them from ``log/athermal/walls``.

Float32 positions cannot resolve the contacts of a packing near jamming (overlaps of 1e-8 of a
diameter): each frame therefore carries its contact network, found in float64 when it is written, as
HOOMD bonds (``bonds/N``, ``types = ["contact"]``, ``typeid``, ``group`` the particle pairs ``(i,
j)``), with ``log/bonds/overlap`` and, when a contact model is given, ``log/bonds/force`` (the
contact law's normal force ``f(delta)``) per bond, and ``log/particles/rattler`` (1 for a rattler:
fewer than ``d + 1`` contacts, removed iteratively), which OVITO imports as bond and particle
properties; between walls, with a model, ``log/particles/wall_force`` is the force each particle's
wall contacts exert on it (0 for a particle touching no wall), and a plane shear's frames add
``log/particles/glued`` (1 for a particle glued to a wall). A simulation code that reads bonds as
bonded interactions (HOOMD-blue's neighbour lists exclude bonded pairs by default) must drop them
first.

Every failure raises :class:`~athermal.errors.FileFormatError` (bad arguments:
:class:`~athermal.errors.InputError`) with a one-line message that names the file.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from math import isqrt
from pathlib import Path
from typing import IO

import gsd.fl
import gsd.hoomd
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validate import float_array
from .analysis.observables import rattlers
from .atomic import replacing
from .errors import FileFormatError, InputError, one_line
from .model.cell import Cell
from .model.contact import ContactModel, find_contacts
from .model.packing import Packing

PathLike = str | os.PathLike[str]

SEED_BOUND = 2**64
"""Seeds lie in ``[0, SEED_BOUND)``: a file stores its seed as uint64."""

_LOG = "athermal/"
_STATE = ("position", "radius", "cell")
_RESERVED = (*_STATE, "walls", "position_lo", "alpha", "stiffness", "wall_stiffness", "seed")
# Wrapped positions are kept this far (in fractional units) inside the faces of the cell, so
# that float32 rounding of positions and box never puts a particle on or outside a face.
_FACE_MARGIN = 2.0**-20
# What gsd raises for unreadable, corrupt or non-HOOMD files.
_GSD_ERRORS = (RuntimeError, ValueError, OSError, KeyError)


@dataclass(frozen=True, eq=False)
class Frame:
    """One configuration read from a GSD file.

    Attributes
    ----------
    packing : positions ``(N, d)``, radii ``(N,)`` and cell, float64.
    model : contact model from ``log/athermal/alpha`` and ``stiffness``; None when absent.
    seed : the seed written with the frame; None when absent.
    log : every other ``log/athermal/<name>`` quantity of the frame (``energy``, ``pressure``,
        ``stress``, ``phi``, ...) as read-only float64 arrays of the shape written (scalars as
        0-d arrays).
    position_lo : ``(N, d)`` the low parts of double-double positions
        ``packing.positions + position_lo`` (a certified packing, :mod:`athermal.certify`);
        None when absent.
    """

    packing: Packing
    model: ContactModel | None
    seed: int | None
    log: dict[str, NDArray[np.float64]]
    position_lo: NDArray[np.float64] | None = None


def write_gsd(
    path: PathLike,
    packing: Packing,
    *,
    model: ContactModel | None = None,
    seed: int | None = None,
    observables: Mapping[str, ArrayLike] | None = None,
    position_lo: ArrayLike | None = None,
    glued: NDArray[np.bool_] | None = None,
) -> None:
    """Write ``packing`` as a one-frame GSD file, atomically.

    The frame goes to a temporary file in the same directory, which is flushed to disk and then
    renamed onto ``path``; on any error the temporary file is removed and a file already at
    ``path`` is left untouched.

    Parameters
    ----------
    path : file to create or replace.
    packing : the configuration (lengths in the packing's units).
    model : contact model, stored as ``alpha`` and ``stiffness`` (its ``kmat``, ``(T, T)``).
    seed : integer in ``[0, 2**64)``, stored as uint64.
    observables : name -> float or array (at most 2D), stored as float64 under
        ``log/athermal/<name>`` (scalars as shape ``(1,)``).
    position_lo : ``(N, d)`` low parts of double-double positions, stored as
        ``log/athermal/position_lo`` (:attr:`Frame.position_lo`).
    glued : mask ``(N,)`` of the particles glued to a wall (plane shear's rough walls), stored
        as ``log/particles/glued`` (1 glued, 0 free); they are never rattlers in
        ``log/particles/rattler``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from athermal.model.packing import random_packing
    >>> p = random_packing(16, 0.5, seed=1)
    >>> name = pathlib.Path(tempfile.mkdtemp()) / "p.gsd"
    >>> write_gsd(name, p, seed=1, observables={"energy": 0.0})
    >>> np.array_equal(read_gsd(name).packing.positions, p.positions)
    True
    """
    target = Path(path)
    frame = _hoomd_frame(packing, model, seed, observables, 0, position_lo, glued)
    _write_atomic(target, frame)


def append_gsd(
    path: PathLike,
    packing: Packing,
    *,
    model: ContactModel | None = None,
    seed: int | None = None,
    observables: Mapping[str, ArrayLike] | None = None,
    glued: NDArray[np.bool_] | None = None,
) -> int:
    """Append ``packing`` as one frame to a trajectory; returns the number of frames now in it.

    A missing file is created (atomically, as by :func:`write_gsd`). An existing file that is not
    a readable GSD file in the HOOMD schema raises :class:`FileFormatError` and is not modified.
    ``configuration.step`` is set to the frame's index. Arguments as in :func:`write_gsd`.
    """
    target = Path(path)
    if not target.exists():
        _write_atomic(target, _hoomd_frame(packing, model, seed, observables, 0, glued=glued))
        return 1
    with _open_read(target) as traj:
        count = len(traj)
    frame = _hoomd_frame(packing, model, seed, observables, count, glued=glued)
    # appended to a copy that replaces the file once complete: an append that fails (a full
    # disk, a kill) leaves the trajectory exactly as it was
    what = "cannot append a frame"
    with replacing(target, what=what, why=lambda exc: _why(exc, target)) as temporary:
        shutil.copyfile(target, temporary)
        with gsd.hoomd.open(str(temporary), "r+") as traj:
            traj.append(frame)
            traj.flush()
            count = len(traj)
    return count


def read_gsd(path: PathLike, frame: int = -1) -> Frame:
    """Read frame ``frame`` (negative counts from the end) of a GSD file in the HOOMD schema.

    The float64 state in ``log/athermal/`` is used when present (bit-identical round trip);
    otherwise the cell comes from ``configuration.box``, positions from ``particles.position``
    ``[:, :d]`` and radii from ``particles.diameter / 2``, with no model and no seed.
    """
    source = Path(path)
    with _open_read(source) as traj:
        index = _frame_index(source, frame, len(traj))
        try:
            snapshot = traj[index]
            names = traj.file.find_matching_chunk_names("log/" + _LOG)
            stored = {
                name[len("log/" + _LOG) :]: np.asarray(traj.file.read_chunk(frame=index, name=name))
                for name in names
                if traj.file.chunk_exists(frame=index, name=name)
            }
        except _GSD_ERRORS as exc:
            raise FileFormatError(
                f"{source}: frame {index} cannot be read ({one_line(exc)})"
            ) from None
    where = f"{source}: frame {index}"
    packing = _packing(where, snapshot, stored)
    lo = None
    if "position_lo" in stored:
        lo = np.asarray(stored["position_lo"], dtype=np.float64)
        _expect_shape(where, "log/athermal/position_lo", lo, packing.positions.shape)
    return Frame(
        packing=packing,
        model=_model(where, stored),
        seed=_seed(where, stored),
        log={name: _observable(value) for name, value in stored.items() if name not in _RESERVED},
        position_lo=lo,
    )


def truncate_gsd(path: PathLike, count: int) -> None:
    """Keep the first ``count`` frames (>= 1) of a trajectory and drop the rest, atomically
    (a copy of those frames, chunk for chunk, replaces the file); nothing happens when it has
    no more than ``count``."""
    if not 1 <= count:
        raise InputError(f"count: must be >= 1, got {count}")
    target = Path(path)
    with _open_read(target) as traj:
        total = len(traj)
    if count >= total:
        return
    what = "cannot drop its last frames"
    with replacing(target, what=what, why=lambda exc: _why(exc, target)) as temporary:
        with gsd.fl.open(str(target), "r") as source:
            names = source.find_matching_chunk_names("")
            with gsd.fl.open(
                str(temporary),
                "w",
                application=source.application,
                schema=source.schema,
                schema_version=source.schema_version,
            ) as copy:
                for frame in range(count):
                    for name in names:
                        if source.chunk_exists(frame=frame, name=name):
                            copy.write_chunk(name, source.read_chunk(frame=frame, name=name))
                    copy.end_frame()


def count_frames(path: PathLike) -> int:
    """Number of frames in a GSD file in the HOOMD schema."""
    with _open_read(Path(path)) as traj:
        return len(traj)


def _open_read(source: Path) -> gsd.hoomd.HOOMDTrajectory:
    if not source.exists():
        raise FileFormatError(f"{source}: no such file")
    if not source.is_file():
        raise FileFormatError(f"{source}: not a regular file")
    try:
        return gsd.hoomd.open(str(source), "r")
    except _GSD_ERRORS as exc:
        raise FileFormatError(
            f"{source}: not a readable GSD file in the HOOMD schema ({one_line(exc)})"
        ) from None


def _frame_index(source: Path, frame: int, count: int) -> int:
    if isinstance(frame, bool) or not isinstance(frame, int | np.integer):
        raise InputError(f"frame: expected an integer index, got {frame!r}")
    if count == 0:
        raise FileFormatError(f"{source}: the file has no frames")
    if not -count <= frame < count:
        raise FileFormatError(f"{source}: frame {frame} out of range (the file has {count})")
    return int(frame) % count


class Claim:
    """The one-writer lock of an output (:func:`claim`); :meth:`close` releases it."""

    def __init__(self, lock: Path, handle: IO[str]) -> None:
        self.lock, self.handle = lock, handle

    def close(self) -> None:
        """Remove the lock file and release the lock (idempotent)."""
        if not self.handle.closed:
            self.lock.unlink(missing_ok=True)
            self.handle.close()

    def __del__(self) -> None:
        self.close()


def claim(path: PathLike) -> Claim:
    """Take the one-writer lock of the output ``path``: an exclusive ``flock`` on the hidden
    file ``.NAME.lock`` beside it, held until :meth:`Claim.close` (or the process ends, so a
    dead run leaves no stale lock). A second claim, from any process, raises
    :class:`InputError` naming the holder's pid."""
    import fcntl

    target = Path(path)
    lock = target.with_name(f".{target.name}.lock")
    while True:
        handle = open(lock, "a+")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            handle.close()
            raise InputError(
                f"{target} is being written by another athermal run (pid {holder}); wait for "
                "it to end or stop it"
            ) from None
        try:  # the holder before us may have removed the file we locked: then lock anew
            if os.stat(lock).st_ino == os.fstat(handle.fileno()).st_ino:
                break
        except FileNotFoundError:
            pass
        handle.close()
    handle.seek(0)
    handle.truncate()
    handle.write(str(os.getpid()))
    handle.flush()
    return Claim(lock, handle)


def _write_atomic(target: Path, frame: gsd.hoomd.Frame) -> None:
    with replacing(target, why=lambda exc: _why(exc, target)) as temporary:
        with gsd.hoomd.open(str(temporary), "x") as traj:
            traj.append(frame)


def _why(exc: BaseException, target: Path) -> str:
    """One line for a failed write; gsd reports a full disk only as "Invalid gsd argument"."""
    if isinstance(exc, RuntimeError):
        needed = 2 * (target.stat().st_size if target.exists() else 0) + 2**20
        if shutil.disk_usage(target.parent).free < needed:
            return f"no space left on the device ({one_line(exc)})"
    return one_line(exc)


def _hoomd_frame(
    packing: Packing,
    model: ContactModel | None,
    seed: int | None,
    observables: Mapping[str, ArrayLike] | None,
    step: int,
    position_lo: ArrayLike | None = None,
    glued: NDArray[np.bool_] | None = None,
) -> gsd.hoomd.Frame:
    """HOOMD-schema frame with the exact state in ``log/athermal/`` (arguments validated here)."""
    if not isinstance(packing, Packing):
        raise InputError(f"packing: expected a Packing, got {type(packing).__name__}")
    log: dict[str, NDArray[np.generic]] = {  # contiguous: gsd warns on stdout otherwise
        _LOG + "position": np.ascontiguousarray(packing.positions),
        _LOG + "radius": np.ascontiguousarray(packing.radii),
        _LOG + "cell": np.ascontiguousarray(packing.cell.h),
    }
    if packing.cell.walls:
        log[_LOG + "walls"] = np.array(packing.cell.walls, dtype=np.int8)
    if model is not None:
        if not isinstance(model, ContactModel):
            raise InputError(f"model: expected a ContactModel, got {type(model).__name__}")
        model.typeid(packing)  # the stiffness matrix must match the packing's species
        log[_LOG + "alpha"] = np.array([model.alpha])
        log[_LOG + "stiffness"] = model.kmat
        if model.wall_stiffness is not None:
            log[_LOG + "wall_stiffness"] = np.array([model.wall_stiffness])
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
            raise InputError(f"seed: expected an integer, got {seed!r}")
        if not 0 <= int(seed) < SEED_BOUND:
            raise InputError(f"seed: must lie in [0, 2**64), got {seed}")
        log[_LOG + "seed"] = np.array([int(seed)], dtype=np.uint64)
    for name, value in (observables or {}).items():
        log[_LOG + _observable_name(name)] = _observable_array(name, value)
    if position_lo is not None:
        lo = np.asarray(position_lo, dtype=np.float64)
        if lo.shape != packing.positions.shape or not np.all(np.isfinite(lo)):
            raise InputError(
                f"position_lo: expected finite values of shape {packing.positions.shape}, got "
                f"shape {lo.shape}"
            )
        log[_LOG + "position_lo"] = lo

    contacts = find_contacts(_near_the_cell(packing), model or ContactModel())
    log["bonds/overlap"] = contacts.overlap
    if model is not None:
        log["bonds/force"] = contacts.force_magnitude
    if glued is not None:
        glued = np.asarray(glued)
        if glued.shape != (packing.n,) or glued.dtype != np.bool_:
            raise InputError(f"glued: expected a boolean mask of shape ({packing.n},)")
        log["particles/glued"] = glued.astype(np.uint8)
    log["particles/rattler"] = rattlers(contacts, packing.n, packing.dim, glued).astype(np.uint8)
    if contacts.walls is not None and model is not None:
        on_walls = contacts.walls
        log["particles/wall_force"] = np.bincount(
            on_walls.particle, on_walls.force_magnitude, packing.n
        ).astype(np.float64)

    typeid, types = packing.types()
    frame = gsd.hoomd.Frame()
    frame.bonds.N = int(contacts.i.size)
    frame.bonds.types = ["contact"]
    frame.bonds.typeid = np.zeros(contacts.i.size, dtype=np.uint32)
    frame.bonds.group = np.stack([contacts.i, contacts.j], axis=1).astype(np.uint32)
    frame.configuration.step = step
    frame.configuration.dimensions = packing.dim
    frame.configuration.box = packing.cell.to_hoomd()
    frame.particles.N = packing.n
    frame.particles.position = _hoomd_positions(packing)
    frame.particles.diameter = 2.0 * packing.radii
    frame.particles.typeid = typeid
    frame.particles.types = types
    frame.log = log
    return frame


def _near_the_cell(packing: Packing) -> Packing:
    """``packing`` with each particle more than one cell away from the cell moved back by
    whole lattice vectors (the contacts' search takes positions within a few cells); the others
    unchanged, bit for bit."""
    cells = np.floor(packing.cell.fractional(packing.positions))
    far = np.where(np.abs(cells) > 1.0, cells, 0.0)
    if not far.any():
        return packing
    return packing.with_positions(packing.positions - packing.cell.cartesian(far))


def _observable_name(name: str) -> str:
    if not isinstance(name, str) or not name or "/" in name:
        raise InputError(f"observables: name {name!r} must be a non-empty string without '/'")
    if name in _RESERVED:
        raise InputError(
            f"observables: name {name!r} is reserved ({', '.join(_RESERVED)} are written from "
            "the packing, model and seed)"
        )
    return name


def _observable_array(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """``value`` as float64 in a shape that GSD stores and gives back unchanged."""
    shape = np.shape(value)
    arr = float_array(value, f"observables[{name!r}]", (None,) * len(shape))
    if arr.ndim == 0:
        return arr.reshape(1)
    if arr.size == 0 or arr.ndim > 2 or arr.shape[-1] == 1:
        raise InputError(
            f"observables[{name!r}]: shape {arr.shape} cannot be stored faithfully in GSD "
            "(use a scalar, a 1D array of length >= 2 or a 2D array with >= 2 columns)"
        )
    return np.ascontiguousarray(arr)


def _hoomd_positions(packing: Packing) -> NDArray[np.float32]:
    """Positions ``(N, 3)`` float32 wrapped into the centred cell along its periodic axes
    (``z = 0`` in 2D)."""
    cell = packing.cell
    s = cell.fractional(cell.wrap(packing.positions))
    np.clip(s, -0.5 + _FACE_MARGIN, 0.5 - _FACE_MARGIN, out=s)
    out = np.zeros((packing.n, 3), dtype=np.float32)
    out[:, : packing.dim] = cell.cartesian(s)
    return out


def _expect_shape(where: str, name: str, arr: NDArray[np.generic], shape: tuple[int, ...]) -> None:
    if arr.shape != shape:
        raise FileFormatError(f"{where}: {name} has shape {arr.shape}, expected {shape}")


def _packing(
    where: str, snapshot: gsd.hoomd.Frame, stored: dict[str, NDArray[np.generic]]
) -> Packing:
    dim = int(snapshot.configuration.dimensions)
    n = int(snapshot.particles.N)
    if dim not in (2, 3):
        raise FileFormatError(f"{where}: configuration/dimensions is {dim}, expected 2 or 3")
    present = [name for name in _STATE if name in stored]
    try:
        if len(present) == len(_STATE):
            positions, radii, h = (np.asarray(stored[name], dtype=np.float64) for name in _STATE)
            _expect_shape(where, "log/athermal/position", positions, (n, dim))
            _expect_shape(where, "log/athermal/radius", radii, (n,))
            _expect_shape(where, "log/athermal/cell", h, (dim, dim))
            walls = stored.get("walls", np.zeros(0, np.int8))
            if walls.ndim != 1 or not np.issubdtype(walls.dtype, np.integer):
                raise FileFormatError(f"{where}: log/athermal/walls is not a list of axes")
            cell = Cell(h, tuple(int(a) for a in walls))
        elif present:
            missing = ", ".join(name for name in _STATE if name not in stored)
            raise FileFormatError(f"{where}: incomplete log/athermal state (missing {missing})")
        else:
            position = np.asarray(snapshot.particles.position)
            diameter = np.asarray(snapshot.particles.diameter)
            _expect_shape(where, "particles/position", position, (n, 3))
            _expect_shape(where, "particles/diameter", diameter, (n,))
            cell = Cell.from_hoomd(np.asarray(snapshot.configuration.box, dtype=np.float64), dim)
            positions = position[:, :dim].astype(np.float64)
            radii = diameter.astype(np.float64) / 2.0
        return Packing(positions, radii, cell)
    except FileFormatError:
        raise
    except InputError as exc:
        raise FileFormatError(f"{where}: {exc}") from None


def _model(where: str, stored: dict[str, NDArray[np.generic]]) -> ContactModel | None:
    if "alpha" not in stored and "stiffness" not in stored:
        return None
    if "alpha" not in stored or "stiffness" not in stored:
        raise FileFormatError(f"{where}: log/athermal has only one of alpha and stiffness")
    alpha, stiffness = stored["alpha"], stored["stiffness"]
    types = isqrt(stiffness.size)
    if alpha.size != 1 or types == 0 or types * types != stiffness.size:
        raise FileFormatError(
            f"{where}: log/athermal alpha {alpha.shape} / stiffness {stiffness.shape} are not "
            "a scalar and a square matrix"
        )
    try:
        kmat = np.asarray(stiffness, dtype=np.float64).reshape(types, types)
        wall = stored.get("wall_stiffness")
        if wall is not None and wall.size != 1:
            raise FileFormatError(f"{where}: log/athermal/wall_stiffness is not a scalar")
        wall_stiffness = None if wall is None else float(wall.reshape(()))
        return ContactModel(float(alpha.reshape(())), kmat, wall_stiffness)
    except InputError as exc:
        raise FileFormatError(f"{where}: {exc}") from None


def _seed(where: str, stored: dict[str, NDArray[np.generic]]) -> int | None:
    if "seed" not in stored:
        return None
    seed = stored["seed"]
    if seed.shape != (1,) or not np.issubdtype(seed.dtype, np.integer):
        raise FileFormatError(f"{where}: log/athermal/seed is not one integer ({seed.dtype})")
    return int(seed[0])


def _observable(value: NDArray[np.generic]) -> NDArray[np.float64]:
    out = np.array(value.reshape(()) if value.shape == (1,) else value, dtype=np.float64)
    out.setflags(write=False)
    return out
