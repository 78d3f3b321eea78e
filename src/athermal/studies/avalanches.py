"""Plasticity over realizations: what an ensemble's realization shears (:class:`EventsSpec`),
what it records (:class:`EventsRecord` of an AQS run's events, :class:`CyclesRecord` of cyclic
shear at several amplitudes), and the ensemble's statistics: avalanche sizes (the stress and
energy drops after the transient, log-binned, with their exponents) and the yielding amplitude
(the amplitudes at which the realizations reach a limit cycle).

Each realization shears its jammed packing at ``phi_c + delta_phi`` (radii scaled from the
packing at its own jamming point), located as :func:`~athermal.protocols.events.plastic_events`
and :func:`~athermal.protocols.events.cyclic_shear` do.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import choice, positive_scalar
from ..analysis.avalanches import log_binned, power_law_tail
from ..analysis.fitting import sample_stats
from ..errors import InputError
from ..model.contact import ContactModel
from ..model.packing import Packing
from ..protocols.events import EVENT_TOL, check_cycles, check_steps
from ..protocols.shear import SHEAR_MODES, ShearMode
from ..relaxation import Minimizer
from .plasticity import PlasticitySpec, run_plasticity

EVENT_COLUMNS = ("strain", "tau_before", "stress_drop", "energy_drop", "moved", "saddle_node")
"""What a realization keeps of each event."""


@dataclass(frozen=True)
class EventsSpec:
    """The AQS shear of every realization (protocols ``events`` and ``cycles``): the jammed
    packing at ``phi_c + delta_phi``, sheared in ``mode`` to ``strain`` (``events``; the events
    below ``transient`` are recorded but left out of the statistics) or ``cycles`` cycles at
    each of ``amplitudes`` (``cycles``, each from the same start), with ``step``, ``max_step``
    and ``tol`` as :func:`~athermal.protocols.events.plastic_events` takes them (in cyclic shear
    at most half the amplitude)."""

    delta_phi: float = 0.01
    mode: ShearMode = "simple"
    strain: float = 0.2
    transient: float = 0.05
    step: float = 1e-4
    max_step: float | None = None
    tol: float = EVENT_TOL
    amplitudes: tuple[float, ...] = (0.02, 0.05, 0.1)
    cycles: int = 20
    minimizer: Minimizer = field(default_factory=Minimizer)

    def __post_init__(self) -> None:
        positive_scalar(self.delta_phi, "delta_phi")
        choice(self.mode, "mode", SHEAR_MODES)
        check_steps(self.step, self.max_step, self.tol, self.strain)
        if not 0.0 <= self.transient < self.strain:
            raise InputError(
                f"transient: need 0 <= transient < strain, got {self.transient:g}, {self.strain:g}"
            )
        if not self.amplitudes:
            raise InputError("amplitudes: need at least one")
        for amplitude in self.amplitudes:
            check_cycles(amplitude, self.cycles)
            check_steps(*self.cycle_steps(amplitude), self.tol, amplitude)

    def cycle_steps(self, amplitude: float) -> tuple[float, float | None]:
        """The step and largest step of cyclic shear at ``amplitude``: at most half of it."""
        half = amplitude / 2.0
        return min(self.step, half), None if self.max_step is None else min(self.max_step, half)

    def plasticity(self, amplitude: float | None = None) -> PlasticitySpec:
        """The run of one realization: the shear to ``strain``, or with ``amplitude`` its cycles
        there (:meth:`cycle_steps`)."""
        if amplitude is None:
            return PlasticitySpec(
                self.mode, self.strain, self.step, self.max_step, self.tol, minimizer=self.minimizer
            )
        step, largest = self.cycle_steps(amplitude)
        return PlasticitySpec(
            self.mode,
            step=step,
            max_step=largest,
            tol=self.tol,
            amplitude=amplitude,
            cycles=self.cycles,
            minimizer=self.minimizer,
        )


@dataclass(frozen=True)
class EventsRecord:
    """A realization's AQS run: the strain reached, its states and events (each with
    :data:`EVENT_COLUMNS`, drops in the cell's units), its seconds, and the units of energy and
    stress of its particles: ``k d^alpha`` and ``k d^(alpha - dim)`` for the law's
    :meth:`~athermal.model.law.ContactLaw.energy_unit` at the largest stiffness ``k`` and the
    mean diameter ``d``."""

    delta_phi: float
    strain: float
    states: int
    events: tuple[dict[str, float], ...]
    seconds: float
    energy_unit: float
    stress_unit: float


@dataclass(frozen=True)
class CyclesRecord:
    """A realization's cyclic shear at each amplitude: per amplitude whether a limit cycle
    came, after which cycle, its period and events, the cycles run, all events and seconds."""

    delta_phi: float
    rows: tuple[dict[str, Any], ...]


def start_of(packing: Packing, phi_c: float, spec: EventsSpec) -> Packing:
    """The sheared start: ``packing`` (jammed at ``phi_c``) at ``phi_c + spec.delta_phi``."""
    return packing.at_phi(phi_c + spec.delta_phi)


def shear_events(
    start: Packing, model: ContactModel, spec: EventsSpec, output: Path
) -> EventsRecord:
    """The :class:`EventsRecord` of ``start`` sheared as ``spec`` says, the run's files written
    next to ``output`` (:func:`~athermal.studies.plasticity.run_plasticity`: the trajectory with
    the states just before and after each event, the tables of states and events). A run
    interrupted there goes on from its last event, to the same events as a run never stopped;
    the files of another run are refused (:class:`~athermal.errors.InputError`)."""
    run = run_plasticity(start, model, spec.plasticity(), output, resume=True)
    diameter = 2.0 * float(np.mean(start.radii))
    energy = model.law.energy_unit(float(model.kmat.max()), diameter)
    return EventsRecord(
        spec.delta_phi,
        float(run.states[-1]["strain"]),
        len(run.states),
        tuple({k: float(e[k]) for k in EVENT_COLUMNS} for e in run.events),
        run.seconds,
        energy,
        energy / diameter**start.dim,
    )


def shear_cycles(start: Packing, model: ContactModel, spec: EventsSpec, stem: Path) -> CyclesRecord:
    """The :class:`CyclesRecord` of ``start`` sheared in cycles at each amplitude ``A`` of
    ``spec`` (:meth:`EventsSpec.plasticity`), each run's files written next to
    ``<stem>.A<A>.gsd`` and an interrupted one gone on from its last cycle's end
    (:func:`~athermal.studies.plasticity.run_plasticity`)."""
    rows = []
    for amplitude in spec.amplitudes:
        output = Path(f"{stem}.A{amplitude:g}.gsd")
        run = run_plasticity(start, model, spec.plasticity(amplitude), output, resume=True)
        rows.append(
            {
                "amplitude": amplitude,
                **run.summary()["limit_cycle"],
                "events": sum(int(c["events"]) for c in run.cycles),
                "seconds": run.seconds,
            }
        )
    return CyclesRecord(spec.delta_phi, tuple(rows))


def pooled_drops(records: list[EventsRecord], transient: float) -> dict[str, list[float]]:
    """The stress and energy drops (``stress_drop``, ``energy_drop``) of the events after
    ``transient`` of all ``records``, each in its record's units (``stress_unit``,
    ``energy_unit``): comparable across sizes and densities."""
    drops: dict[str, list[float]] = {"stress_drop": [], "energy_drop": []}
    for r in records:
        kept = [e for e in r.events if e["strain"] >= transient]
        drops["stress_drop"] += [e["stress_drop"] / r.stress_unit for e in kept]
        drops["energy_drop"] += [e["energy_drop"] / r.energy_unit for e in kept]
    return drops


def avalanche_statistics(records: list[EventsRecord], transient: float) -> dict[str, Any]:
    """The events after ``transient`` pooled over ``records``: how many, the mean stress and
    energy drops (in the records' units) and strain between events (with standard errors), the
    driven stress where events start (``stress``: its ``sd`` the steady state's stress
    fluctuation), the saddle-node fraction, the fitted exponents of both drops' distributions
    (:func:`~athermal.analysis.avalanches.power_law_tail`) and their log-binned densities."""
    kept = [[e for e in r.events if e["strain"] >= transient] for r in records]
    pooled = [e for events in kept for e in events]
    drops = pooled_drops(records, transient)
    gaps = [b["strain"] - a["strain"] for ev in kept for a, b in pairwise(ev)]
    out: dict[str, Any] = {
        "realizations": len(records),
        "events": len(pooled),
        "strain_sheared": sum(max(r.strain - transient, 0.0) for r in records),
        "strain_between_events": sample_stats(gaps),
        "saddle_node_fraction": sample_stats([e["saddle_node"] for e in pooled])["mean"],
        "moved": sample_stats([e["moved"] for e in pooled]),
        "stress": sample_stats(
            [
                e["tau_before"] / r.stress_unit
                for r, ev in zip(records, kept, strict=True)
                for e in ev
            ]
        ),
    }
    for name, sizes in drops.items():
        out[name] = sample_stats(sizes)
        fit = power_law_tail(sizes)
        out[f"{name}_exponent"] = None if fit is None else asdict(fit)
        centres, density, counts = log_binned(sizes)
        out[f"{name}_density"] = {
            "centres": centres.tolist(),
            "density": density.tolist(),
            "counts": counts.tolist(),
        }
    return out


def yielding(records: list[CyclesRecord]) -> dict[str, Any]:
    """Per amplitude over ``records`` (one flat row each): the fraction of realizations that
    reached a limit cycle, the cycles to reach it, the period and the events per period (means
    and standard errors over those that did, NaN where none did); and the
    yielding amplitude's bracket: the largest amplitude at which most (more than half) reached
    one, below the smallest at which most did not (None where there is no such pair)."""
    amplitudes = sorted({row["amplitude"] for r in records for row in r.rows})
    table = []
    for amplitude in amplitudes:
        rows = [row for r in records for row in r.rows if row["amplitude"] == amplitude]
        reached = [row for row in rows if row["reached"]]
        entry: dict[str, Any] = {
            "amplitude": amplitude,
            "realizations": len(rows),
            "fraction_reached": len(reached) / len(rows),
        }
        for name, column in (
            ("cycles_to_reach", "cycle"),
            ("period", "period"),
            ("events_per_period", "events_per_period"),
        ):
            stats = sample_stats([float(row[column]) for row in reached])
            entry[name], entry[f"{name}_stderr"] = stats["mean"], stats["stderr"]
        table.append(entry)
    below = [t["amplitude"] for t in table if t["fraction_reached"] > 0.5]
    above = [t["amplitude"] for t in table if t["fraction_reached"] <= 0.5]
    bracket = None
    if below and above and max(below) < min(above):
        bracket = [max(below), min(above)]
    return {"amplitudes": table, "yielding_bracket": bracket}
