"""Plastic events of athermal quasi-static shear, located by the end of their branch of minima:
the saddle-node's square root, events independent of the step, the bracket's two sides, the
records, unjammed packings, and the refusals."""

from __future__ import annotations

import numpy as np
import pytest

from athermal import ContactModel, jam, random_packing
from athermal.analysis.moduli import stability
from athermal.analysis.network import NetworkHessian
from athermal.errors import InputError
from athermal.model.contact import hessian
from athermal.protocols.events import (
    BranchState,
    CycleEnd,
    LimitCycle,
    PlasticEvent,
    _Shear,
    cyclic_shear,
    limit_cycle,
    plastic_events,
    soft_mode,
)
from athermal.protocols.shear import rough_walls, strained

HERTZ = ContactModel(2.5)
START = random_packing(32, 0.88, seed=3)


def events(model=HERTZ, start=START, **options) -> list[PlasticEvent]:
    return [e for e in plastic_events(start, model, **options) if isinstance(e, PlasticEvent)]


@pytest.fixture(scope="module")
def first() -> PlasticEvent:
    return events(strain=0.03, step=1e-3, tol=1e-10)[0]


def test_the_lowest_eigenvalue_vanishes_as_a_square_root(first):
    """A saddle-node: on the branch at ``gamma_c - delta`` the lowest nonzero eigenvalue goes as
    ``delta^(1/2)`` (measured slope 0.48 over delta = 1e-8 ... 1e-6, N = 32, Hertz), and the
    located strain lies within the bracket of the extrapolated ``gamma_c``."""
    gc = first.critical_strain
    assert first.strain <= gc <= first.strain_after + 1e-10
    run = _Shear(HERTZ, "simple", None)
    deltas = np.array([1e-6, 3e-7, 1e-7, 3e-8, 1e-8])
    lams = []
    for delta in deltas:
        packing, _ = run.relax(
            strained(first.before.packing, "simple", first.strain, gc - delta), 0
        )
        lams.append(soft_mode(packing, HERTZ)[0])
    slope = np.polyfit(np.log(deltas), np.log(lams), 1)[0]
    assert slope == pytest.approx(0.5, abs=0.04)
    assert np.all(np.diff(lams) < 0)  # it falls toward the end
    # lambda^2 / delta tends to a constant (the saddle-node's normal form)
    ratio = np.array(lams) ** 2 / deltas
    assert ratio.max() / ratio.min() < 1.4


def test_the_bracket_holds_a_minimum_below_and_another_above(first):
    """At ``strain`` a stable minimum, its eigenvalue small; at ``strain_after`` the packing has
    fallen into another: the energy dropped, particles moved, contacts changed."""
    assert first.strain_after - first.strain <= 1e-10
    assert stability(first.before.packing, HERTZ).stable
    assert 0.0 < first.before.lowest_eigenvalue < 1e-2 * first.after.lowest_eigenvalue
    assert first.energy_drop > 0.0
    assert first.max_displacement > 1e-3  # in mean diameters, far above SAME_STATE
    assert 2.0 <= first.moved <= START.n
    assert first.contacts_made + first.contacts_broken > 0
    row = first.row()
    assert row["stress_drop"] == first.before.tau - first.after.tau
    assert set(row) >= {"strain", "strain_after", "critical_strain", "energy_drop", "moved"}


def test_the_events_do_not_depend_on_the_step_or_the_sameness_threshold():
    """The same events at the same strains (to the tolerance) whatever the strain step and
    whatever the distance below which two states count as one minimum (1e-8 ... 1e-4 mean
    diameters about the default 1e-6)."""
    a = events(strain=0.03, step=1e-3, tol=1e-10)
    for other in (
        events(strain=0.03, step=4e-4, max_step=2e-3, tol=1e-10),
        events(strain=0.03, step=1e-3, max_step=1e-2, tol=1e-10),  # steps past the event
        events(strain=0.03, step=1e-3, tol=1e-10, same=1e-8),
        events(strain=0.03, step=1e-3, tol=1e-10, same=1e-4),
    ):
        assert len(a) == len(other) >= 1
        for x, y in zip(a, other, strict=True):
            assert abs(x.strain - y.strain) <= 2e-10
            assert x.energy_drop == pytest.approx(y.energy_drop, rel=1e-4)
    assert all(e.saddle_node for e in a)  # Hertzian contacts: every branch ends in a saddle-node


def test_an_event_whose_loop_lies_inside_a_step_is_found():
    """Hooke's law: this packing's first event has a hysteresis loop narrower than a step of
    1e-3 (its landing, strained back by that step, falls back onto the branch it left), so the
    return test alone would miss it in such a step; the step over which a contact opened is
    narrowed, and steps growing from 1e-3 to 1e-2 find the events that fixed steps of 1e-4 do
    (measured: the first at strain 0.017575)."""
    harmonic = ContactModel(2.0)
    jammed = jam(random_packing(32, 0.8, seed=1), harmonic)
    start = jammed.packing.at_phi(jammed.phi_c + 0.02)
    coarse = events(harmonic, start, strain=0.02, step=1e-3)
    fine = events(harmonic, start, strain=0.02, step=1e-4, max_step=1e-4)
    assert len(coarse) == len(fine) >= 1
    for x, y in zip(coarse, fine, strict=True):
        assert abs(x.strain - y.strain) <= 2e-9
    # golden: the same bits on every CPU (measured under native and generic numba targets and
    # OpenBLAS's SkylakeX, Haswell and Prescott kernels, on one thread and two)
    assert [e.strain.hex() for e in coarse] == ["0x1.1ff479afdef9bp-6", "0x1.2a98e87659f15p-6"]
    first, wide = coarse[0], 1e-3
    run = _Shear(harmonic, "simple", None)
    below = first.strain_after - wide
    back, _ = run.relax(strained(first.after.packing, "simple", first.strain_after, below), below)
    left, _ = run.relax(strained(first.before.packing, "simple", first.strain, below), below)
    assert run.same(back, run.state(left, below))


def test_states_between_events_stay_on_their_branch():
    """The states yielded between events: strains increasing, each a stable minimum, the step
    growing; every event followed by its ``after`` state."""
    items = list(plastic_events(START, HERTZ, strain=0.03, step=1e-3, tol=1e-9))
    states = [s for s in items if isinstance(s, BranchState)]
    strains = [s.strain for s in states]
    assert strains[0] == 0.0 and strains[-1] == pytest.approx(0.03)
    assert np.all(np.diff(strains) > 0)
    for k, item in enumerate(items):
        if isinstance(item, PlasticEvent):
            assert items[k + 1] is item.after


def test_an_unjammed_packing_has_no_branch_and_no_events():
    """Without a contact network the minimum is floppy (no branch to end): the strain is
    stepped through (the steps growing where allowed) without a search for events."""
    loose = random_packing(32, 0.6, seed=3)
    items = list(plastic_events(loose, HERTZ, strain=0.05, step=1e-3, max_step=1e-2))
    assert not any(isinstance(i, PlasticEvent) for i in items)
    assert items[-1].strain == pytest.approx(0.05) and len(items) < 12
    assert all(s.lowest_eigenvalue == np.inf for s in items)


def test_harmonic_packings_and_pure_shear_have_events():
    """Harmonic contacts (whose branch can also end where a contact opens, the Hessian losing
    its stiffness at once) and pure shear: events located, each releasing energy."""
    for model, mode in ((ContactModel(2.0), "simple"), (HERTZ, "pure")):
        found = events(model, strain=0.05, step=1e-3, tol=1e-9, mode=mode)
        assert found, mode
        for e in found:
            assert e.strain_after - e.strain <= 1e-9
            assert e.energy_drop > 0.0


def test_bad_settings_are_refused_before_any_work():
    with pytest.raises(InputError, match="step: need tol < step"):
        next(plastic_events(START, HERTZ, step=1e-9, tol=1e-9))
    with pytest.raises(InputError, match="strain"):
        next(plastic_events(START, HERTZ, strain=-1.0))
    with pytest.raises(InputError, match="mode"):
        next(plastic_events(START, HERTZ, mode="twist"))


def cycle(start, amplitude, cycles, stop=True):
    items = list(
        cyclic_shear(start, HERTZ, amplitude=amplitude, cycles=cycles, step=1e-3, stop=stop)
    )
    return items, [e for e in items if isinstance(e, CycleEnd)]


def test_cyclic_shear_finds_a_limit_cycle_that_an_independent_run_repeats():
    """Beyond the first cycles the packing's end state repeats: a limit cycle (N = 32, Hertz,
    amplitude 0.06: entered after cycle 1, period 1, measured 9 events a period). Checked
    independently: a fresh run from that end state, one period long, ends on it again, with
    the same events."""
    items, ends = cycle(START, 0.06, 10)
    found = limit_cycle(ends)
    assert found.reached and found.period is not None and found.cycle is not None
    assert found.events and found.events > 0
    entered = ends[found.cycle - 1].state if found.cycle else items[0]
    _, again_ends = cycle(entered.packing, 0.06, found.period, stop=False)
    run = _Shear(HERTZ, "simple", None)
    assert run.same(again_ends[-1].state.packing, entered)
    assert sum(e.events for e in again_ends) == found.events
    # the strain path: 0 -> A -> -A -> 0 each cycle, events on both legs
    strains = [e.strain for e in items if isinstance(e, PlasticEvent)]
    assert min(strains) < 0.0 < max(strains) and max(abs(s) for s in strains) <= 0.06


def test_small_amplitudes_are_elastic():
    """Below the first event the cycle is reversible: back where it started after one cycle,
    no event."""
    _, ends = cycle(START, 0.005, 5)
    found = limit_cycle(ends)
    assert found == LimitCycle(True, 0, 1, 0, 1)


def test_cyclic_settings_are_refused():
    with pytest.raises(InputError, match="cycles"):
        next(cyclic_shear(START, HERTZ, amplitude=0.01, cycles=0))
    with pytest.raises(InputError, match="amplitude"):
        next(cyclic_shear(START, HERTZ, amplitude=-0.01, cycles=2))


def test_the_command_writes_events_frames_and_tables(tmp_path, capsys):
    """``athermal shear --events``: the frames before and after each event, marked; the
    states' and the events' tables; the summary. ``--cycles``: the cycles' table and the limit
    cycle."""
    import json

    from athermal import read_gsd, write_gsd
    from athermal.cli import main
    from athermal.io import count_frames
    from athermal.studies.tables import read_table

    write_gsd(tmp_path / "start.gsd", START, model=HERTZ)
    out = tmp_path / "s.gsd"
    argv = ["shear", str(tmp_path / "start.gsd"), "-o", str(out), "--mode", "simple"]
    assert main([*argv, "--events", "--strain", "0.03", "--step", "1e-3", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    events = read_table(tmp_path / "s.events.csv")
    assert summary["events"] == len(events) >= 1
    assert count_frames(out) == 1 + 2 * len(events)
    before, after = read_gsd(out, frame=1), read_gsd(out, frame=2)
    assert float(before.log["event_before"]) == 0 and float(after.log["event_after"]) == 0
    assert float(before.log["strain"]) == events[0]["strain"]
    mode = before.log["soft_mode"]  # the critical mode: unit, one row per particle
    assert mode.shape == (START.n, 2) and np.linalg.norm(mode) == pytest.approx(1.0)
    assert len(read_table(tmp_path / "s.csv")) == summary["states"]
    assert summary["figure"] == str(tmp_path / "s.png") and (tmp_path / "s.png").stat().st_size
    cyclic = [*argv, "--cycles", "5", "--amplitude", "0.06", "--step", "1e-3", "--json"]
    assert main([*cyclic[:3], str(tmp_path / "c.gsd"), *cyclic[4:]]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["limit_cycle"]["reached"] and summary["limit_cycle"]["period"] == 1
    assert len(read_table(tmp_path / "c.cycles.csv")) == summary["limit_cycle"]["cycles_run"]
    quiet = ["--figure", "none", "--events", "--strain", "0.01", "--step", "1e-3", "--json"]
    assert main([*argv[:3], str(tmp_path / "f.gsd"), *quiet]) == 0
    assert not (tmp_path / "f.png").exists()


def test_plane_shear_between_rough_walls_has_events():
    """Plane shear (walls normal to y, their layers glued): events located, each releasing
    energy (measured: 10 events to strain 0.1, N = 64, phi 0.9)."""
    from athermal.model.cell import Cell

    start = random_packing(64, 0.9, seed=5, cell=Cell.unit(2, walls="y"))
    found = events(ContactModel(2.0), start, mode="plane", strain=0.1, step=1e-3, tol=1e-9)
    assert found
    for e in found:
        assert e.strain_after - e.strain <= 1e-9 and e.energy_drop > 0.0


@pytest.mark.parametrize("plane", [False, True])
def test_a_contact_opens_without_ending_the_branch_when_its_removal_is_below_one(plane):
    """Brute-force twin of the test that lets an opening pass without narrowing: for every
    contact of a relaxed harmonic state, ``k b^T H^-1 b < 1`` exactly where the dense Hessian of
    the free particles without that contact's term stays positive definite (translations
    aside); periodic simple shear, and plane shear with held layers and wall contacts."""
    from athermal.model.cell import Cell

    harmonic = ContactModel(2.0)
    if plane:
        start = random_packing(64, 0.9, seed=5, cell=Cell.unit(2, walls="y"))
        layers = rough_walls(start, None)
        run = _Shear(harmonic, "plane", layers)
    else:
        jammed = jam(random_packing(32, 0.8, seed=1), harmonic)
        run = _Shear(harmonic, "simple", None)
        start = jammed.packing.at_phi(jammed.phi_c + 0.02)
    state = run.first(start, 0.0)
    contacts, n, dim = state.contacts, state.packing.n, state.packing.dim
    moving = ~state.rattler if run.frozen is None else ~(state.rattler | run.frozen)
    dofs = (np.flatnonzero(moving)[:, None] * dim + np.arange(dim)).ravel()
    h = hessian(contacts, n).toarray()[np.ix_(dofs, dofs)]
    translations = 0 if plane else dim
    pairs = contacts.i.size
    walls = 0 if contacts.walls is None else contacts.walls.particle.size
    assert not plane or walls > 0
    network = NetworkHessian(state.packing, contacts, state.rattler, run.frozen)
    signs = []
    for c in range(pairs + walls):
        b = np.zeros(n * dim)
        if c < pairs:
            b[contacts.i[c] * dim : (contacts.i[c] + 1) * dim] += contacts.normal[c]
            b[contacts.j[c] * dim : (contacts.j[c] + 1) * dim] -= contacts.normal[c]
            k = contacts.stiffness[c]
        else:
            w = c - pairs
            b[contacts.walls.particle[w] * dim + contacts.walls.axis[w]] = 1.0
            k = contacts.walls.stiffness[w]
        values = np.linalg.eigvalsh(h - k * np.outer(b[dofs], b[dofs]))
        q = network.removal(c)
        lowest = values[translations]
        if abs(q - 1.0) > 1e-8:
            assert (q < 1.0) == (lowest > 1e-10 * values[-1]), (c, q, lowest)
            signs.append(q < 1.0)
    assert any(signs) and not all(signs)  # both kinds are there


@pytest.mark.parametrize(
    ("extra", "flag"),
    [
        (["--tol", "1e-8"], "--tol"),
        (["--max-step", "1e-3"], "--max-step"),
        (["--figure", "f.png"], "--figure"),
        (["--amplitude", "0.01"], "--amplitude"),
        (["--cycles", "2"], "--cycles"),
        (["--events", "--resume"], "--resume"),  # nothing to resume
        (["--events", "--rtol", "1e-6"], "--rtol"),
        (["--cycles", "2", "--amplitude", "0.01", "--strain", "0.1"], "--strain"),
    ],
)
def test_options_that_would_do_nothing_are_refused_in_one_line(tmp_path, capsys, extra, flag):
    """Each option of exact events without ``--events`` (or the other way round) is refused
    before any file is written, in one line naming it."""
    from athermal import write_gsd
    from athermal.cli import main

    write_gsd(tmp_path / "start.gsd", START, model=HERTZ)
    out = tmp_path / "s.gsd"
    assert main(["shear", str(tmp_path / "start.gsd"), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag in err[0]
    assert not out.exists()


class Killed(Exception):
    """Stands for a kill at a chosen moment of a run."""


def kill_at(which):
    """An ``on_item`` that raises :class:`Killed` at the ``which``-th item it is shown that
    passes ``which``'s test (a callable of the item and its count)."""
    seen = []

    def on_item(item):
        seen.append(item)
        if which(item, seen):
            raise Killed

    return on_item


@pytest.mark.parametrize("moment", ["at an event", "before its after state's row"])
def test_a_killed_event_run_resumes_to_the_same_events(tmp_path, moment):
    """Killed as the second event is found (its frames not yet written) or just after the first
    event's frames (its after state's row not yet in the table), the run resumed goes on from
    the last event: the same events (strains to 2e-10), one frame before and after each, the
    tables as an uninterrupted run's."""
    from athermal.io import count_frames, read_gsd
    from athermal.studies.plasticity import PlasticitySpec, run_plasticity

    spec = PlasticitySpec(mode="simple", strain=0.06, step=1e-3)
    whole = run_plasticity(START, HERTZ, spec, tmp_path / "whole.gsd")
    if moment == "at an event":
        stop = kill_at(lambda item, seen: sum(isinstance(s, PlasticEvent) for s in seen) == 2)
    else:
        first = []

        def stop_at(item, seen):
            if isinstance(item, PlasticEvent):
                first.append(item)
            return bool(first) and item is first[0].after

        stop = kill_at(stop_at)
    out = tmp_path / "cut.gsd"
    with pytest.raises(Killed):
        run_plasticity(START, HERTZ, spec, out, on_item=stop)
    cut = count_frames(out)
    again = run_plasticity(START, HERTZ, spec, out, resume=True)
    assert cut < count_frames(out) == 1 + 2 * len(whole.events) == 9
    assert len(again.events) == len(whole.events)
    for x, y in zip(again.events, whole.events, strict=True):
        assert x["index"] == y["index"] and abs(x["strain"] - y["strain"]) <= 2e-10
    assert [r["strain"] for r in again.states][:3] == [r["strain"] for r in whole.states][:3]
    assert len(again.states) == len(whole.states)
    marks = [float(read_gsd(out, k).log["event_before"]) for k in range(1, 9)]
    assert marks == [0, -1, 1, -1, 2, -1, 3, -1]  # each event's frames once, in order
    other = PlasticitySpec(mode="simple", strain=0.05, step=1e-3)
    with pytest.raises(InputError, match="another run"):
        run_plasticity(START, HERTZ, other, out, resume=True)
    from athermal import write_gsd

    write_gsd(tmp_path / "foreign.gsd", START)  # no run's file: refused, left as it was
    with pytest.raises(InputError, match="another run"):
        run_plasticity(START, HERTZ, spec, tmp_path / "foreign.gsd", resume=True)
    assert count_frames(tmp_path / "foreign.gsd") == 1


def test_a_killed_cyclic_run_resumes_from_its_last_cycle():
    """Killed in its second cycle, cyclic shear resumed from the end of the first reaches the
    same limit cycle as an uninterrupted run."""
    import tempfile
    from pathlib import Path

    from athermal.studies.plasticity import PlasticitySpec, run_plasticity

    folder = Path(tempfile.mkdtemp())
    spec = PlasticitySpec(mode="simple", step=1e-3, amplitude=0.06, cycles=5)
    whole = run_plasticity(START, HERTZ, spec, folder / "whole.gsd").summary()
    stop = kill_at(
        lambda item, seen: (
            sum(isinstance(s, CycleEnd) for s in seen) == 1 and isinstance(item, PlasticEvent)
        )
    )
    with pytest.raises(Killed):
        run_plasticity(START, HERTZ, spec, folder / "cut.gsd", on_item=stop)
    again = run_plasticity(START, HERTZ, spec, folder / "cut.gsd", resume=True).summary()
    assert again["limit_cycle"] == whole["limit_cycle"]
    assert [c["events"] for c in again["cycle_ends"]] == [c["events"] for c in whole["cycle_ends"]]
    assert again["events"] == whole["events"]


def test_the_jax_engine_locates_the_same_events():
    """Relaxed by the JAX engine (JAX's CPU build here), the same events at the same strains
    (to 2e-10) and drops as by the numba engine."""
    pytest.importorskip("jax")
    from athermal.relaxation import Minimizer

    numba = events(strain=0.03, step=1e-3, tol=1e-10)
    jax = events(strain=0.03, step=1e-3, tol=1e-10, minimizer=Minimizer(backend="jax"))
    assert len(jax) == len(numba) >= 1
    for x, y in zip(jax, numba, strict=True):
        assert abs(x.strain - y.strain) <= 2e-10
        assert x.stress_drop == pytest.approx(y.stress_drop, rel=1e-4)
