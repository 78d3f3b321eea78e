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
appended.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .._records import Value
from ..errors import InputError
from ..io import append_gsd, claim
from ..model.contact import ContactModel
from ..model.packing import Packing
from ..protocols.events import (
    EVENT_TOL,
    BranchState,
    CycleEnd,
    PlasticEvent,
    cyclic_shear,
    limit_cycle,
    plastic_events,
)
from ..protocols.shear import ShearMode
from ..relaxation import Minimizer
from .tables import write_table

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


@dataclass(frozen=True, eq=False)
class PlasticityRun:
    """What a run found: its states, events and cycles' ends, and the files it wrote."""

    states: list[BranchState]
    events: list[PlasticEvent]
    cycles: list[CycleEnd]
    files: dict[str, str]

    def summary(self) -> dict[str, Any]:
        """The run in numbers: events, their drops (mean, largest), the strain between
        events, and for cyclic shear the limit cycle and each cycle's end."""
        drops = [e.stress_drop for e in self.events]
        energy = [e.energy_drop for e in self.events]
        out: dict[str, Any] = {
            "states": len(self.states),
            "events": len(self.events),
            "stress_drop_mean": statistics.fmean(drops) if drops else math.nan,
            "stress_drop_max": max(drops, default=math.nan),
            "energy_drop_mean": statistics.fmean(energy) if energy else math.nan,
            "moved_mean": statistics.fmean(e.moved for e in self.events) if drops else math.nan,
            "relaxations_per_event": (
                statistics.fmean(e.trials for e in self.events) if drops else math.nan
            ),
        }
        if len(self.events) > 1 and not self.cycles:
            gaps = [b.strain - a.strain for a, b in zip(self.events, self.events[1:], strict=False)]
            out["strain_between_events"] = statistics.fmean(gaps)
        if self.cycles:
            found = limit_cycle(self.cycles)
            out["limit_cycle"] = {
                "reached": found.reached,
                "cycle": found.cycle,
                "period": found.period,
                "events_per_period": found.events,
                "cycles_run": found.cycles,
            }
            out["cycle_ends"] = [c.row() for c in self.cycles]
        return out

    def figure(self, title: str = "") -> Figure:
        """The driven stress against strain with the events marked, and the distributions of
        their stress and energy drops (:func:`~athermal.studies.plot.events_figure`)."""
        from .plot import events_figure

        curve = {"strain": [s.strain for s in self.states], "tau": [s.tau for s in self.states]}
        events = {
            "strain": [e.strain for e in self.events],
            "tau_before": [e.before.tau for e in self.events],
            "stress_drop": [e.stress_drop for e in self.events],
            "energy_drop": [e.energy_drop for e in self.events],
        }
        return events_figure(curve, events, title=title)


def run_plasticity(
    start: Packing,
    model: ContactModel,
    spec: PlasticitySpec,
    output: str | Path,
    *,
    seed: int | None = None,
    overwrite: bool = False,
    on_item: Callable[[BranchState | PlasticEvent | CycleEnd], None] | None = None,
) -> PlasticityRun:
    """Run ``spec`` from ``start`` and write its files next to ``output`` (module docstring);
    ``on_item`` sees every state, event and cycle end as it comes."""
    target = Path(output)
    files = {
        "trajectory": str(target),
        "states": str(target.with_suffix(".csv")),
        "events": str(target.with_suffix(".events.csv")),
    }
    if spec.cycles is not None:
        files["cycles"] = str(target.with_suffix(".cycles.csv"))
    lock = claim(target)
    try:
        if target.exists() and not overwrite:
            raise InputError(f"output: {target} exists; replace it with overwrite")
        target.unlink(missing_ok=True)
        return _run(start, model, spec, target, files, seed, on_item)
    finally:
        lock.close()


def _run(
    start: Packing,
    model: ContactModel,
    spec: PlasticitySpec,
    target: Path,
    files: dict[str, str],
    seed: int | None,
    on_item: Callable[[BranchState | PlasticEvent | CycleEnd], None] | None,
) -> PlasticityRun:
    """:func:`run_plasticity` with its output claimed."""
    options: dict[str, Any] = {
        "mode": spec.mode,
        "step": spec.step,
        "max_step": spec.max_step,
        "tol": spec.tol,
        "minimizer": spec.minimizer,
        "wall_layer": spec.wall_layer,
    }
    items = (
        plastic_events(start, model, strain=spec.strain, **options)
        if spec.cycles is None
        else cyclic_shear(
            start, model, amplitude=spec.amplitude or 0.0, cycles=spec.cycles, **options
        )
    )
    run = PlasticityRun([], [], [], files)

    def frame(state: BranchState, **marks: Value) -> None:
        log: dict[str, Value] = {"event_before": -1, "event_after": -1, "cycle": -1}
        log.update(marks)
        append_gsd(
            target,
            state.packing,
            model=model,
            seed=seed,
            observables={**_finite(state.row()), **log, "soft_mode": state.mode},
        )

    for item in items:
        if on_item is not None:
            on_item(item)
        if isinstance(item, BranchState):
            if not run.states:
                frame(item)
            run.states.append(item)
        elif isinstance(item, PlasticEvent):
            frame(item.before, event_before=item.index)
            frame(item.after, event_after=item.index)
            run.events.append(item)
            write_table(files["events"], [e.row() for e in run.events])
            write_table(files["states"], [s.row() for s in run.states])
        else:
            frame(item.state, cycle=item.cycle)
            run.cycles.append(item)
            write_table(files["cycles"], [c.row() for c in run.cycles])
    write_table(files["states"], [s.row() for s in run.states])
    if not run.events:
        files.pop("events")
    return run


def _finite(row: dict[str, Value]) -> dict[str, float]:
    """``row`` as frame observables: floats, an infinite eigenvalue (no contact network: the
    packing unjammed) written as -1, which no minimum's Hessian has."""
    return {k: float(v) if math.isfinite(float(v)) else -1.0 for k, v in row.items()}
