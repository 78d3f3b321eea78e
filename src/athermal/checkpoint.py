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
from pathlib import Path
from typing import Any

import numpy as np

from .contact import ContactModel
from .errors import FileFormatError, InputError
from .io import Frame, append_gsd, claim, count_frames, read_gsd, write_gsd
from .observables import measure
from .protocols import CompressionStep, JammingStep, ShearStep
from .protocols.compress import EVENTS

PHASES = ("start", "increment", "bisection", "final")
NO_BRACKET = -1.0
"""``phi_high`` as stored before the first jammed step (every frame must carry the same log
names: gsd reads a name missing from a frame as frame 0's value)."""
Step = JammingStep | CompressionStep | ShearStep


def run_id(protocol: str, parameters: Mapping[str, Any]) -> float:
    """A 52-bit digest (exact in float64) of the protocol name and its parameters."""
    text = json.dumps({"protocol": protocol, **parameters}, sort_keys=True, default=str)
    return float(int(hashlib.sha256(text.encode()).hexdigest()[:13], 16))


def step_log(step: Step) -> dict[str, float]:
    """The numbers of ``step`` as frame observables: floats, the same names in every frame
    (``phase`` as its index in :data:`PHASES`, an open bracket as :data:`NO_BRACKET`, the events
    of a compression step as bits in the order of ``EVENTS``)."""
    out: dict[str, float | int | str] = dict(step.row())
    if isinstance(step, JammingStep):
        out["phase"] = PHASES.index(step.phase)
        if not np.isfinite(step.phi_high):
            out["phi_high"] = NO_BRACKET
    if isinstance(step, CompressionStep):
        out["events"] = sum(1 << EVENTS.index(e) for e in step.events)
    return {k: float(v) for k, v in out.items()}


def _number(frame: Frame, name: str) -> float:
    try:
        return float(frame.log[name].reshape(-1)[0])
    except KeyError:
        raise FileFormatError(f"frame has no {name!r}: not an athermal protocol step") from None


def jamming_step(frame: Frame) -> JammingStep:
    """The jamming step stored in ``frame``."""
    get = lambda name: _number(frame, name)  # noqa: E731
    return JammingStep(
        index=int(get("index")),
        phase=PHASES[int(get("phase"))],  # type: ignore[arg-type]
        origin=int(get("origin")),
        phi=get("phi"),
        jammed=bool(get("jammed")),
        energy=get("energy"),
        pressure=get("pressure"),
        contacts=int(get("contacts")),
        iterations=int(get("iterations")),
        evaluations=int(get("evaluations")),
        saddles=int(get("saddles")),
        seconds=get("seconds"),
        phi_low=get("phi_low"),
        phi_high=np.inf if get("phi_high") == NO_BRACKET else get("phi_high"),
        packing=frame.packing,
    )


def compression_step(frame: Frame) -> CompressionStep:
    """The compression step stored in ``frame``."""
    get = lambda name: _number(frame, name)  # noqa: E731
    return CompressionStep(
        index=int(get("index")),
        delta_phi=get("delta_phi"),
        phi=get("phi"),
        energy=get("energy"),
        pressure=get("pressure"),
        shear_stress=get("shear_stress"),
        contacts=int(get("contacts")),
        z=get("z"),
        z_excess=get("z_excess"),
        n_rattlers=int(get("n_rattlers")),
        bulk_modulus=get("bulk_modulus"),
        shear_modulus=get("shear_modulus"),
        saddles=int(get("saddles")),
        substeps=int(get("substeps")),
        events=tuple(e for k, e in enumerate(EVENTS) if int(get("events")) >> k & 1),
        iterations=int(get("iterations")),
        evaluations=int(get("evaluations")),
        seconds=get("seconds"),
        packing=frame.packing,
    )


def shear_step(frame: Frame, model: ContactModel) -> ShearStep:
    """The shear step stored in ``frame`` (its observables measured again, identically)."""
    get = lambda name: _number(frame, name)  # noqa: E731
    return ShearStep(
        index=int(get("index")),
        strain=get("strain"),
        tau=get("tau"),
        stress_drop=get("stress_drop"),
        plastic=bool(get("plastic")),
        saddles=int(get("saddles")),
        observables=measure(frame.packing, model),
        iterations=int(get("iterations")),
        evaluations=int(get("evaluations")),
        seconds=get("seconds"),
        packing=frame.packing,
    )


class Trajectory:
    """The checkpoint file of one protocol run, held by this run alone.

    ``Trajectory(path, identity, resume=..., overwrite=...)`` takes the file's one-writer lock
    (:func:`~athermal.io.claim`: a second run on the same file is refused, naming the first),
    then refuses an existing file unless ``resume`` (continue it: every frame must carry
    ``identity``) or ``overwrite`` (start afresh: the old file is replaced only when the first
    new step is appended, so a run that fails before that loses nothing); :attr:`frames` are the
    frames found when resuming.
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
    ) -> None:
        self.path = Path(path)
        self.identity = identity
        self.model = model
        self.seed = seed
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
        )
        self._replace = False
