"""Protocol trajectories as checkpoints: one GSD frame per completed step, read back to resume.

Every frame holds the step's packing (exact float64 state) and its numbers under
``log/athermal/`` together with ``run_id``, a 52-bit digest of the run's parameters, so that
``--resume`` continues only the run that wrote the file. A step is appended once it is complete,
so a run killed at any moment (SIGKILL included) leaves a file of whole steps.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from .._records import as_numbers, columns_as_text, from_numbers, number_names
from ..analysis.observables import measure
from ..atomic import replacing
from ..certify.bisection import MarchState
from ..errors import FileFormatError, InputError
from ..io import Frame, append_gsd, claim, count_frames, read_gsd, write_gsd
from ..model.contact import ContactModel
from ..model.packing import Packing
from ..protocols import CompressionStep, JammingStep, ShearStep

BRACKET = "phi_high"
"""The field of a jamming step that is infinite while the bracket is open."""
NO_BRACKET = -1.0
"""``phi_high`` as stored before the first jammed step (every frame must carry the same log
names: gsd reads a name missing from a frame as frame 0's value)."""
Step = JammingStep | CompressionStep | ShearStep
S = TypeVar("S", JammingStep, CompressionStep, ShearStep)


def run_id(protocol: str, parameters: Mapping[str, Any]) -> float:
    """A 52-bit digest (exact in float64) of the protocol name and its parameters."""
    text = json.dumps({"protocol": protocol, **parameters}, sort_keys=True, default=str)
    return float(int(hashlib.sha256(text.encode()).hexdigest()[:13], 16))


def fingerprint(packing: Packing) -> str:
    """Digest of a start configuration, so a resumed run checks it starts from the same one."""
    digest = hashlib.sha256()
    for arr in (packing.positions, packing.radii, packing.cell.h):
        digest.update(np.ascontiguousarray(arr).tobytes())
    if packing.cell.walls:  # (a periodic start's digest as before)
        digest.update(bytes(packing.cell.walls))
    return digest.hexdigest()


def save_march(path: str | os.PathLike[str], state: MarchState, key: str) -> None:
    """Write a double-double march's ``state`` (:func:`~athermal.certify.bisection.
    bisect_jamming_point`'s ``on_checkpoint``) to ``path`` (``.npz``) atomically, under ``key``
    (the identity of the march: :func:`march_key`)."""
    arrays: dict[str, Any] = {f.name: np.asarray(getattr(state, f.name)) for f in fields(state)}
    with replacing(path, what="cannot write the march's checkpoint") as temporary:
        with open(temporary, "wb") as handle:
            np.savez(handle, key=np.array(key), **arrays)


def load_march(path: str | os.PathLike[str], key: str) -> MarchState | None:
    """The march state :func:`save_march` wrote to ``path`` under ``key``; None when there is
    none, or it is another march's."""
    if not Path(path).is_file():
        return None
    with np.load(path) as data:
        if str(data["key"]) != key:
            return None
        a = {name: np.array(data[name]) for name in data.files}
    return MarchState(
        a["source_positions"],
        a["source_radii"],
        a["first"],
        a["bonds"],
        a["rattler"],
        a["hi"],
        a["lo"],
        a["radii"],
        float(a["high"]),
        float(a["low"]),
        float(a["step"]),
        tuple(int(c) for c in a["counts"]),
    )


def march_key(packing: Packing, model: ContactModel, epsilon: float) -> str:
    """The identity of the march that brackets ``packing``'s jamming point to ``epsilon``."""
    return f"{fingerprint(packing)} {model.alpha!r} {model.kmat.tolist()!r} {epsilon!r}"


def step_log(step: Step) -> dict[str, float]:
    """The numbers of ``step``'s row as frame observables: floats, the same names in every frame
    (:func:`~athermal._records.as_numbers`: ``phase`` as its index among the phases, the events
    of a compression step as bits; an open bracket as :data:`NO_BRACKET`)."""
    log = as_numbers(step, step.row())
    if not np.isfinite(log.get(BRACKET, 0.0)):
        log[BRACKET] = NO_BRACKET
    return log


def readable_log(log: Mapping[str, Any]) -> dict[str, Any]:
    """A frame's log with the coded numbers of a protocol step as their table text (a jamming
    step's ``phase`` by name, a compression step's ``events`` as ``a;b``, empty for none); the
    log of any other frame as it is."""
    out = dict(log)

    def number(name: str) -> float:
        return float(np.reshape(log[name], -1)[0])

    for cls in (JammingStep, CompressionStep, ShearStep):
        if number_names(cls) <= out.keys():
            return out | columns_as_text(cls, number)
    return out


def _number(frame: Frame, name: str) -> float:
    try:
        return float(frame.log[name].reshape(-1)[0])
    except KeyError:
        raise FileFormatError(f"frame has no {name!r}: not an athermal protocol step") from None


def _step(cls: type[S], frame: Frame, **given: Any) -> S:
    """The ``cls`` step stored in ``frame`` by :func:`step_log` (its packing the frame's)."""

    def number(name: str) -> float:
        value = _number(frame, name)
        return np.inf if name == BRACKET and value == NO_BRACKET else value

    return from_numbers(cls, number, packing=frame.packing, **given)


def jamming_step(frame: Frame) -> JammingStep:
    """The jamming step stored in ``frame``."""
    return _step(JammingStep, frame)


def compression_step(frame: Frame) -> CompressionStep:
    """The compression step stored in ``frame``."""
    return _step(CompressionStep, frame)


def shear_step(
    frame: Frame, model: ContactModel, fixed: NDArray[np.bool_] | None = None
) -> ShearStep:
    """The shear step stored in ``frame`` (its observables measured again, identically: with
    plane shear's glued particles ``fixed``, never rattlers)."""
    return _step(ShearStep, frame, observables=measure(frame.packing, model, fixed))


class Trajectory:
    """The checkpoint file of one protocol run, held by this run alone.

    ``Trajectory(path, identity, resume=..., overwrite=...)`` takes the file's one-writer lock
    (:func:`~athermal.io.claim`: a second run on the same file is refused, naming the first),
    then refuses an existing file unless ``resume`` (continue it: every frame must carry
    ``identity``) or ``overwrite`` (start afresh: the old file is replaced only when the first
    new step is appended, so a run that fails before that loses nothing); :attr:`frames` are the
    frames found when resuming. ``glued`` (plane shear's glued particles) is written with every
    frame (:func:`~athermal.io.write_gsd`).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        identity: float,
        *,
        model: ContactModel,
        seed: int | None,
        resume: bool = False,
        overwrite: bool = False,
        glued: NDArray[np.bool_] | None = None,
    ) -> None:
        self.path = Path(path)
        self.identity = identity
        self.model = model
        self.seed = seed
        self.glued = glued
        self.frames: list[Frame] = []
        self._lock = claim(self.path)
        self._replace = False
        if not self.path.exists():
            return
        if resume:
            count = count_frames(self.path)
            self.frames = [read_gsd(self.path, frame=k) for k in range(count)]
            for k, frame in enumerate(self.frames):
                if "run_id" not in frame.log or _number(frame, "run_id") != identity:
                    raise InputError(
                        f"--resume: {self.path} frame {k} was written by another run (other "
                        "parameters or another command); remove it or drop --resume"
                    )
        elif overwrite:
            self._replace = True
        else:
            raise InputError(
                f"{self.path} exists: continue it with --resume, or replace it with --overwrite"
            )

    def close(self) -> None:
        """Release the file's one-writer lock (the trajectory takes no more steps)."""
        self._lock.close()

    def append(self, step: Step) -> None:
        """Append ``step`` as one frame (its packing, numbers and the run identity); the first
        step of an ``overwrite`` run replaces the old file."""
        write = write_gsd if self._replace else append_gsd
        write(
            self.path,
            step.packing,
            model=self.model,
            seed=self.seed,
            observables={**step_log(step), "run_id": self.identity},
            glued=self.glued,
        )
        self._replace = False
