"""One realization of an ensemble: what it runs (:class:`EnsembleSpec`), what it records
(:class:`Realization`, with the compression, shear and force records) and
:func:`run_realization`, which runs it into the ensemble directory, resumable from its trajectory
(:mod:`athermal.studies.ensemble` runs many)."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .. import engines
from .._validate import choice
from ..analysis.forces import (
    ForceStatistics,
    force_statistics,
)
from ..atomic import write_text
from ..errors import InputError
from ..model.packing import POLYDISPERSITY
from ..protocols.compress import excess_z
from ..protocols.shear import check_mode
from .avalanches import (
    CyclesRecord,
    EventsRecord,
    EventsSpec,
    shear_cycles,
    shear_events,
    start_of,
)
from .checkpoint import Trajectory, jamming_step, run_id
from .experiments import (
    Compression,
    CompressSpec,
    IterationCounts,
    IterationSpec,
    JamSpec,
    ShearSpec,
    compress,
    iteration_counts,
    jam_packing,
    shear,
)
from .tables import Row

Protocol = Literal["jam", "compress", "shear", "iterations", "events", "cycles"]
PROTOCOLS: tuple[str, ...] = ("jam", "compress", "shear", "iterations", "events", "cycles")


@dataclass(frozen=True)
class EnsembleSpec:
    """What every realization runs: the protocol and the specs of its studies.

    ``protocol``: ``jam`` (jamming by growth and bisection, ``jam``), ``compress`` (jam, then
    compress as ``compress`` says and fit the scaling laws), ``shear`` (jam, compress, then
    shear from the state nearest ``shear.delta_phi``), ``iterations`` (jam, then the paper's
    iteration experiment, ``iterations``), ``events`` (jam, then AQS shear with every plastic
    event located, ``events``) or ``cycles`` (jam, then cyclic AQS shear at each amplitude of
    ``events``).
    """

    protocol: Protocol
    jam: JamSpec = field(default_factory=JamSpec)
    compress: CompressSpec = field(default_factory=CompressSpec)
    shear: ShearSpec = field(default_factory=ShearSpec)
    iterations: IterationSpec = field(default_factory=IterationSpec)
    events: EventsSpec = field(default_factory=EventsSpec)

    def __post_init__(self) -> None:
        choice(self.protocol, "protocol", PROTOCOLS)
        cell = self.jam.cell
        if self.protocol == "shear":
            check_mode(self.shear.mode, self.shear.strain, cell)
        if self.protocol in ("events", "cycles"):
            check_mode(self.events.mode, self.events.strain, cell)
        if self.protocol == "iterations" and {0, 1} & set(cell.walls):
            raise InputError(
                "protocol: the iteration experiment shears x along y, which walls normal to x "
                "or y do not allow"
            )

    def identity(self) -> float:
        """Digest of the spec: a directory holds the realizations of one spec only."""
        return run_id("ensemble", self.parameters())

    def parameters(self) -> dict[str, Any]:
        """The spec as a dictionary, without the fields added later (:data:`LATER_FIELDS`)
        while they hold their defaults: a directory made before they existed still matches."""
        out = asdict(self)
        for (*path, name), default in LATER_FIELDS.items():
            inner = out
            for key in path:
                inner = inner[key]
            if inner.get(name) == default:
                del inner[name]
        return out


LATER_FIELDS: dict[tuple[str, ...], Any] = {
    ("jam", "sizes"): "bidisperse",
    ("jam", "polydispersity"): POLYDISPERSITY,
    ("jam", "walls"): "",
    ("jam", "minimizer", "backend"): engines.DEFAULT,
    ("compress", "minimizer", "backend"): engines.DEFAULT,
    ("shear", "minimizer", "backend"): engines.DEFAULT,
    ("events",): asdict(EventsSpec()),
}
"""Spec fields (their path: section, ..., name) that joined after the first ensembles, with
their defaults."""


@dataclass(frozen=True)
class CompressionRecord:
    """A realization's compression: its table rows, fitted exponents (None: no fit), the
    free-fit jamming point (None: no fit) and event counts."""

    rows: tuple[Row, ...]
    exponents: dict[str, float | None]
    phi_c_fitted: float | None
    events: dict[str, int]

    @classmethod
    def of(cls, compression: Compression) -> CompressionRecord:
        """The record of a :class:`~athermal.studies.experiments.Compression`."""
        fits = compression.fits
        laws = {"p": fits.pressure, "G": fits.shear_modulus, "z": fits.z_excess}
        return cls(
            tuple(s.row() for s in compression.steps),
            {k: None if f is None else f.exponent for k, f in laws.items()},
            fits.phi_c_fitted if np.isfinite(fits.phi_c_fitted) else None,
            dict(fits.events),
        )


@dataclass(frozen=True)
class ShearRecord:
    """A realization's shear run: its table rows, plastic events and start ``Delta phi``."""

    rows: tuple[Row, ...]
    plastic_events: int
    delta_phi: float


@dataclass(frozen=True)
class ForceRecord:
    """A jammed packing's force network (:class:`~athermal.analysis.forces.ForceStatistics`): its
    histogram of ``f / <f>`` on :data:`~athermal.analysis.forces.EDGES`, the fitted tail decay
    (None: no fit) and the anisotropies."""

    counts: tuple[int, ...]
    overflow: int
    mean_force: float
    tail_decay: float | None
    contact_anisotropy: float
    force_anisotropy: float

    @classmethod
    def of(cls, stats: ForceStatistics) -> ForceRecord:
        """The record of :func:`~athermal.analysis.forces.force_statistics`' result."""
        return cls(
            tuple(int(c) for c in stats.counts),
            stats.overflow,
            stats.mean_force,
            None if stats.tail is None else stats.tail.decay,
            stats.contact_anisotropy,
            stats.force_anisotropy,
        )


@dataclass(frozen=True)
class Realization:
    """One realization's result: its jammed packing's numbers and checks, and the sections of
    its protocol (None where the protocol has none)."""

    index: int
    seed: int
    phi_c: float
    phi_low: float
    energy: float
    pressure: float
    z: float
    z_iso: float
    n_rattlers: int
    excess_contacts: int
    unjams_when_decompressed: bool
    stable: bool
    checks_passed: bool
    steps: int
    iterations: int
    seconds: float
    compression: CompressionRecord | None = None
    shear: ShearRecord | None = None
    iteration_counts: IterationCounts | None = None
    forces: ForceRecord | None = None
    events: EventsRecord | None = None
    cycles: CyclesRecord | None = None

    def to_json(self) -> dict[str, Any]:
        """A JSON object (``realization-KKKK.json``, the ``--json`` output)."""
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Realization:
        """The realization :meth:`to_json` wrote."""
        sections: dict[str, Any] = {}
        if data.get("compression") is not None:
            c = data["compression"]
            sections["compression"] = CompressionRecord(
                tuple(c["rows"]), c["exponents"], c["phi_c_fitted"], c["events"]
            )
        if data.get("shear") is not None:
            h = data["shear"]
            sections["shear"] = ShearRecord(tuple(h["rows"]), h["plastic_events"], h["delta_phi"])
        if data.get("iteration_counts") is not None:
            i = data["iteration_counts"]
            sections["iteration_counts"] = IterationCounts(
                tuple(i["delta_phi"]),
                {k: tuple(v) for k, v in i["iterations"].items()},
                {k: tuple(v) for k, v in i["seconds"].items()},
            )
        if data.get("forces") is not None:  # absent from realizations run before it existed
            f = data["forces"]
            sections["forces"] = ForceRecord(**{**f, "counts": tuple(f["counts"])})
        if data.get("events") is not None:
            e = data["events"]
            sections["events"] = EventsRecord(**{**e, "events": tuple(e["events"])})
        if data.get("cycles") is not None:
            c = data["cycles"]
            sections["cycles"] = CyclesRecord(c["delta_phi"], tuple(c["rows"]))
        plain = {k: v for k, v in data.items() if k not in sections and k in _FIELDS}
        return cls(**plain, **sections)


_SECTIONS = {"compression", "shear", "iteration_counts", "forces", "events", "cycles"}
_FIELDS = set(Realization.__dataclass_fields__) - _SECTIONS


def write_json(path: Path, data: dict[str, Any]) -> None:
    write_text(path, json.dumps(data, indent=1) + "\n")


def run_realization(spec: EnsembleSpec, index: int, seed: int, directory: str) -> Realization:
    """Run realization ``index`` (its ``seed``) of ``spec`` into ``directory``; return its result.

    The jamming trajectory is a checkpoint: a retried realization continues it; so are the AQS
    runs (``realization-NNNN.shear.gsd`` of ``events``, ``realization-NNNN.A<A>.gsd`` of
    ``cycles`` at each amplitude, and their tables), from their last event or cycle's end.
    """
    t0 = time.perf_counter()
    stem = Path(directory) / f"realization-{index:04d}"
    model = spec.jam.model
    identity = run_id("realization", {**spec.parameters(), "index": index, "seed": seed})
    trajectory = Trajectory(
        f"{stem}.gsd",
        identity,
        model=model,
        seed=seed,
        resume=True,
    )
    done = [jamming_step(f) for f in trajectory.frames]
    try:
        jammed = jam_packing(spec.jam, seed, resume=done, on_step=trajectory.append)
    finally:  # a retry of this realization, in this process, takes the lock again
        trajectory.close()
    obs, check = jammed.observables, jammed.check
    sections: dict[str, Any] = {}
    if spec.protocol in ("compress", "shear"):
        compression = compress(jammed.packing, model, jammed.phi_c, spec.compress)
        sections["compression"] = CompressionRecord.of(compression)
        if spec.protocol == "shear":
            run = shear(compression, model, spec.shear)
            sections["shear"] = ShearRecord(
                tuple(s.row() for s in run.steps), run.plastic_events, run.delta_phi
            )
    elif spec.protocol == "iterations":
        sections["iteration_counts"] = iteration_counts(
            jammed.packing, model, jammed.phi_c, spec.iterations
        )
    elif spec.protocol in ("events", "cycles"):
        start = start_of(jammed.packing, jammed.phi_c, spec.events)
        if spec.protocol == "events":
            output = Path(f"{stem}.shear.gsd")
            sections["events"] = shear_events(start, model, spec.events, output)
        else:
            sections["cycles"] = shear_cycles(start, model, spec.events, stem)
    sections["forces"] = ForceRecord.of(force_statistics(jammed.packing, model))
    result = Realization(
        index=index,
        seed=seed,
        phi_c=jammed.phi_c,
        phi_low=jammed.phi_low,
        energy=obs.energy,
        pressure=obs.pressure,
        z=obs.z,
        z_iso=obs.z - excess_z(obs, jammed.packing.cell.periodic_axes),
        n_rattlers=obs.n_rattlers,
        excess_contacts=check.excess_contacts,
        unjams_when_decompressed=check.unjams,
        stable=check.stable,
        checks_passed=check.passed,
        steps=jammed.steps,
        iterations=jammed.iterations,
        seconds=time.perf_counter() - t0,
        **sections,
    )
    write_json(Path(f"{stem}.json"), result.to_json())
    return result
