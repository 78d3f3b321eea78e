"""The AQS runs with exact plastic events as a product: a run of
:func:`~athermal.protocols.events.plastic_events` (to a strain) or
:func:`~athermal.protocols.events.cyclic_shear` (cycles of an amplitude), its files written as it
goes, and its summary.

Files: the trajectory (GSD) holds the start and, marked in each frame's log, the state just
before and just after every event (``event_before`` / ``event_after`` = the event's index, -1
otherwise) and every cycle's end (``cycle``), with the state's numbers (``lowest_eigenvalue``
-1 where the packing has no contact network) and its soft mode ``soft_mode`` ``(N, d)`` (before
an event: the critical mode); ``<output>.csv`` the branch states (the
stress-strain curve); ``<output>.events.csv`` the events; ``<output>.cycles.csv`` the cycles'
ends. Tables are rewritten atomically after each event and cycle and at the end, frames
appended. Each frame's log also holds the run's identity ``run`` (its spec and start), the
rows of ``states`` and ``events`` up to it and the ``seconds`` so far: a run resumed
(``resume``) goes on from its last event's frame (cyclic shear: its last cycle's end) whose rows
reached the tables.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .._records import Value
from ..errors import InputError
from ..io import append_gsd, claim, count_frames, read_gsd, truncate_gsd
from ..model.contact import ContactModel
from ..model.packing import Packing
from ..protocols.events import (
    EVENT_TOL,
    BranchState,
    Checkpoint,
    CycleEnd,
    PlasticEvent,
    cyclic_shear,
    limit_cycle,
    plastic_events,
)
from ..protocols.shear import ShearMode
from ..relaxation import Minimizer
from .checkpoint import fingerprint, run_id
from .tables import read_table, write_table

if TYPE_CHECKING:
    from matplotlib.figure import Figure


@dataclass(frozen=True)
class PlasticitySpec:
    """An AQS run: ``mode``, to ``strain`` or, with ``cycles``, ``cycles`` cycles of
    ``amplitude``; ``step``, ``max_step`` and ``tol`` as
    :func:`~athermal.protocols.events.plastic_events` takes them."""

    mode: ShearMode = "simple"
    strain: float = 0.1
    step: float = 1e-4
    max_step: float | None = None
    tol: float = EVENT_TOL
    amplitude: float | None = None
    cycles: int | None = None
    minimizer: Minimizer = field(default_factory=Minimizer)
    wall_layer: float | None = None


@dataclass(frozen=True)
class _CycleRow:
    """A cycle's end as its table row holds it (what :func:`limit_cycle` reads)."""

    cycle: int
    events: int
    repeats: int | None


@dataclass(frozen=True, eq=False)
class PlasticityRun:
    """What a run found, as its tables hold it: the rows of its states, events and cycles'
    ends (those of a resumed run's first part read back), the files it wrote, and the seconds
    it took (a resumed run's first part up to its last event or cycle's end included)."""

    states: list[dict[str, Value]]
    events: list[dict[str, Value]]
    cycles: list[dict[str, Value]]
    files: dict[str, str]
    seconds: float = 0.0

    def summary(self) -> dict[str, Any]:
        """The run in numbers: events, their drops (mean, largest), the strain between
        events, and for cyclic shear the limit cycle and each cycle's end."""
        drops = [float(e["stress_drop"]) for e in self.events]
        energy = [float(e["energy_drop"]) for e in self.events]
        out: dict[str, Any] = {
            "states": len(self.states),
            "events": len(self.events),
            "stress_drop_mean": statistics.fmean(drops) if drops else math.nan,
            "stress_drop_max": max(drops, default=math.nan),
            "energy_drop_mean": statistics.fmean(energy) if energy else math.nan,
            "moved_mean": (
                statistics.fmean(float(e["moved"]) for e in self.events) if drops else math.nan
            ),
            "relaxations_per_event": (
                statistics.fmean(float(e["trials"]) for e in self.events) if drops else math.nan
            ),
        }
        if len(self.events) > 1 and not self.cycles:
            strains = [float(e["strain"]) for e in self.events]
            out["strain_between_events"] = statistics.fmean(np.diff(strains).tolist())
        if self.cycles:
            out["limit_cycle"] = limit_cycle([_cycle_row(c) for c in self.cycles]).row()
            out["cycle_ends"] = self.cycles
        return out

    def figure(self, title: str = "") -> Figure:
        """The driven stress against strain with the events marked, and the distributions of
        their stress and energy drops (:func:`~athermal.studies.plot.events_figure`)."""
        from .plot import events_figure

        def column(rows: list[dict[str, Value]], name: str) -> list[float]:
            return [float(r[name]) for r in rows]

        curve = {"strain": column(self.states, "strain"), "tau": column(self.states, "tau")}
        events = {
            name: column(self.events, name)
            for name in ("strain", "tau_before", "stress_drop", "energy_drop")
        }
        return events_figure(curve, events, title=title)


def _cycle_row(row: dict[str, Value]) -> _CycleRow:
    """The :class:`_CycleRow` of a cycles table's row."""
    repeats = int(row["repeats"])
    return _CycleRow(int(row["cycle"]), int(row["events"]), None if repeats < 0 else repeats)


def run_plasticity(
    start: Packing,
    model: ContactModel,
    spec: PlasticitySpec,
    output: str | Path,
    *,
    seed: int | None = None,
    overwrite: bool = False,
    resume: bool = False,
    on_item: Callable[[BranchState | PlasticEvent | CycleEnd], None] | None = None,
) -> PlasticityRun:
    """Run ``spec`` from ``start`` and write its files next to ``output`` (module docstring);
    ``on_item`` sees every state, event and cycle end as it comes. With ``resume`` a run
    interrupted there (the same spec and start, else :class:`InputError`) goes on from its last
    event (from its last cycle's end in cyclic shear); its frames and rows after that point are
    dropped and found again."""
    target = Path(output)
    files = {
        "trajectory": str(target),
        "states": str(target.with_suffix(".csv")),
        "events": str(target.with_suffix(".events.csv")),
    }
    if spec.cycles is not None:
        files["cycles"] = str(target.with_suffix(".cycles.csv"))
    identity = run_id("plasticity", {**asdict(spec), "start": fingerprint(start)})
    lock = claim(target)
    try:
        done = None
        if resume and target.exists():
            done = _read_back(target, files, identity, spec.cycles is not None)
        elif target.exists() and not overwrite:
            raise InputError(f"output: {target} exists; replace it with overwrite")
        if done is None:
            target.unlink(missing_ok=True)
        return _run(start, model, spec, target, files, seed, identity, done, on_item)
    finally:
        lock.close()


@dataclass(frozen=True, eq=False)
class _Done:
    """A run read back: where it goes on from, and its rows so far."""

    checkpoint: Checkpoint
    run: PlasticityRun


def _read_back(target: Path, files: dict[str, str], identity: float, cyclic: bool) -> _Done | None:
    """The interrupted run in ``target``: its frames after the last event (the last cycle's
    end) dropped, its checkpoint there and its rows up to there; None when it was stopped
    before its first table (it starts again)."""
    if float(read_gsd(target, 0).log.get("run", np.nan)) != identity:
        raise InputError(
            f"resume: {target} holds another run (its settings or start differ); drop resume or "
            "write elsewhere"
        )
    if not _rows(files["states"]):
        return None
    frames = [read_gsd(target, k) for k in range(count_frames(target))]
    marked = "cycle" if cyclic else "event_after"
    events, cycles = _rows(files["events"]), _rows(files.get("cycles"))

    def tabled(log: dict[str, NDArray[np.float64]]) -> bool:  # its rows all in the tables
        return int(log["events"]) <= len(events) and int(log["cycle"]) <= len(cycles)

    last = max(
        (k for k, f in enumerate(frames) if float(f.log[marked]) >= 0 and tabled(f.log)),
        default=0,
    )
    truncate_gsd(target, last + 1)
    log = frames[last].log
    states = _rows(files["states"])[: int(log["states"])]
    if len(states) < int(log["states"]):  # killed before the table was written
        states.append({name: _infinite(name, float(log[name])) for name in states[0]})
    events = events[: int(log["events"])]
    cycles = cycles[: max(int(log["cycle"]), 0)]
    ends = [frames[0]] + [f for f in frames[1 : last + 1] if float(f.log["cycle"]) >= 1]
    checkpoint = Checkpoint(
        frames[last].packing,
        float(log["strain"]),
        len(events),
        tuple(f.packing for f in ends) if cyclic else (),
    )
    seconds = float(log["seconds"]) if "seconds" in log else 0.0
    return _Done(checkpoint, PlasticityRun(states, events, cycles, dict(files), seconds))


def _rows(path: str | None) -> list[dict[str, Value]]:
    """The rows of the table at ``path`` (none where there is no table)."""
    if path is None or not Path(path).exists():
        return []
    return [dict(row) for row in read_table(path)]


def _run(
    start: Packing,
    model: ContactModel,
    spec: PlasticitySpec,
    target: Path,
    files: dict[str, str],
    seed: int | None,
    identity: float,
    done: _Done | None,
    on_item: Callable[[BranchState | PlasticEvent | CycleEnd], None] | None,
) -> PlasticityRun:
    """:func:`run_plasticity` with its output claimed (``done``: a run read back)."""
    options: dict[str, Any] = {
        "mode": spec.mode,
        "step": spec.step,
        "max_step": spec.max_step,
        "tol": spec.tol,
        "minimizer": spec.minimizer,
        "wall_layer": spec.wall_layer,
        "checkpoint": None if done is None else done.checkpoint,
    }
    items = (
        plastic_events(start, model, strain=spec.strain, **options)
        if spec.cycles is None
        else cyclic_shear(
            start, model, amplitude=spec.amplitude or 0.0, cycles=spec.cycles, **options
        )
    )
    run = PlasticityRun([], [], [], files) if done is None else done.run
    t0 = time.perf_counter()

    def seconds() -> float:
        return run.seconds + time.perf_counter() - t0

    def frame(state: BranchState, states: int, **marks: Value) -> None:
        log: dict[str, Value] = {"event_before": -1, "event_after": -1, "cycle": -1}
        log.update(marks, run=identity, states=states, events=len(run.events), seconds=seconds())
        append_gsd(
            target,
            state.packing,
            model=model,
            seed=seed,
            observables={**_finite(state.row()), **log, "soft_mode": state.mode},
        )

    def tables() -> None:
        write_table(files["states"], run.states)
        if run.events:
            write_table(files["events"], run.events)
        if run.cycles:
            write_table(files["cycles"], run.cycles)

    after = None
    for item in items:
        if on_item is not None:
            on_item(item)
        if isinstance(item, BranchState):
            if not run.states:
                frame(item, 1)
            run.states.append(item.row())
            if item is after or len(run.states) == 1:
                tables()
        elif isinstance(item, PlasticEvent):
            frame(item.before, len(run.states), event_before=item.index)
            run.events.append(item.row())
            frame(item.after, len(run.states) + 1, event_after=item.index)
            tables()
            after = item.after
        else:
            run.cycles.append(item.row())
            frame(item.state, len(run.states), cycle=item.cycle)
            tables()
    tables()
    if not run.events:
        files.pop("events")
    return replace(run, seconds=seconds())


def _infinite(name: str, value: float) -> float:
    """A frame's logged number as its row holds it (the inverse of :func:`_finite`)."""
    return float("inf") if name == "lowest_eigenvalue" and value == -1.0 else value


def _finite(row: dict[str, Value]) -> dict[str, float]:
    """``row`` as frame observables: floats, an infinite eigenvalue (no contact network: the
    packing unjammed) written as -1, which no minimum's Hessian has."""
    return {k: float(v) if math.isfinite(float(v)) else -1.0 for k, v in row.items()}
