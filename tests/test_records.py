"""One serialization of a step: rows (CSV tables, ensemble records) and checkpoint logs are a file
format, so their columns, their order and the numbers a checkpoint stores are pinned here, and
every step reads back from a frame to the step that was written."""

import dataclasses
from typing import get_args

import numpy as np
import pytest

from athermal import ContactModel, random_packing
from athermal._records import as_row, from_numbers
from athermal.analysis.observables import measure
from athermal.io import read_gsd, write_gsd
from athermal.protocols import EVENTS, CompressionStep, JammingStep, ShearStep
from athermal.protocols.jamming import Phase
from athermal.studies.checkpoint import (
    Trajectory,
    compression_step,
    jamming_step,
    shear_step,
    step_log,
)

MODEL = ContactModel(2.0)
PACKING = random_packing(12, 0.86, seed=3)

JAMMING_COLUMNS = [
    "index", "phase", "origin", "phi", "jammed", "energy", "pressure", "contacts",
    "iterations", "evaluations", "saddles", "seconds", "phi_low", "phi_high",
]  # fmt: skip
COMPRESSION_COLUMNS = [
    "index", "n", "delta_phi", "phi", "energy", "pressure", "shear_stress", "contacts", "z",
    "z_excess", "n_rattlers", "bulk_modulus", "shear_modulus", "saddles", "substeps", "events",
    "iterations", "evaluations", "seconds",
]  # fmt: skip
SHEAR_COLUMNS = [
    "index", "strain", "tau", "stress_drop", "plastic", "saddles", "energy", "pressure",
    "stress_iso", "stress_dev", "fabric_iso", "fabric_dev", "contacts", "z", "n_rattlers",
    "iterations", "evaluations", "seconds",
]  # fmt: skip


def jamming(phase="bisection", jammed=True, phi_high=0.8425):
    return JammingStep(
        index=7, phase=phase, origin=5, phi=0.1 + 0.74, jammed=jammed, energy=1.5e-9,
        pressure=2.5e-5, contacts=23, iterations=140, evaluations=151, saddles=1,
        seconds=0.25, phi_low=0.84, phi_high=phi_high, packing=PACKING,
    )  # fmt: skip


def compression(events=("pressure drop", "unstable to shear")):
    return CompressionStep(
        index=2, delta_phi=1e-3, phi=0.843, energy=3e-8, pressure=4e-4, shear_stress=-1e-6,
        contacts=25, z=4.2, z_excess=0.2, n_rattlers=1, bulk_modulus=0.3, shear_modulus=-1e-3,
        saddles=0, substeps=2, events=events, iterations=90, evaluations=99, seconds=0.5,
        packing=PACKING,
    )  # fmt: skip


def shear(plastic=True):
    return ShearStep(
        index=3, strain=3e-3, tau=1e-4, stress_drop=2e-5, plastic=plastic, saddles=0,
        observables=measure(PACKING, MODEL), iterations=40, evaluations=44, seconds=0.125,
        packing=PACKING,
    )  # fmt: skip


def fields(step):
    """Every field but the packing (compared by its arrays) and the observables (their dict)."""
    out = {}
    for f in dataclasses.fields(step):
        value = getattr(step, f.name)
        if f.name == "observables":
            value = repr(value.to_dict())
        elif f.name != "packing":
            value = (type(value), value)
        out[f.name] = value
    del out["packing"]
    return out


def test_rows_keep_their_columns_in_order():
    assert list(jamming().row()) == JAMMING_COLUMNS
    assert list(compression().row()) == COMPRESSION_COLUMNS
    assert list(shear().row()) == SHEAR_COLUMNS


def test_rows_write_bools_as_0_1_events_as_text_and_observables_by_name():
    assert jamming().row()["jammed"] == 1 and jamming(jammed=False).row()["jammed"] == 0
    assert jamming().row()["phase"] == "bisection"
    row = compression().row()
    assert row["events"] == "pressure drop;unstable to shear" and row["n"] == PACKING.n == 12
    assert compression(events=()).row()["events"] == ""
    row, obs = shear().row(), measure(PACKING, MODEL)
    assert row["plastic"] == 1 and row["z"] == obs.z and row["n_rattlers"] == obs.n_rattlers


def test_phases_and_events_keep_their_order_it_is_the_checkpoint_format():
    assert get_args(Phase) == ("start", "increment", "bisection", "final")
    assert EVENTS == ("unjammed", "pressure drop", "saddle left", "unstable to shear")


def test_checkpoint_logs_are_pinned():
    """The numbers a checkpoint frame has always stored (phase index, event bits, 0/1, the open
    bracket as -1)."""
    assert step_log(jamming()) == {
        "index": 7.0, "phase": 2.0, "origin": 5.0, "phi": 0.1 + 0.74, "jammed": 1.0,
        "energy": 1.5e-9, "pressure": 2.5e-5, "contacts": 23.0, "iterations": 140.0,
        "evaluations": 151.0, "saddles": 1.0, "seconds": 0.25, "phi_low": 0.84,
        "phi_high": 0.8425,
    }  # fmt: skip
    assert step_log(jamming(phase="start", jammed=False, phi_high=np.inf))["phi_high"] == -1.0
    log = step_log(compression())
    assert list(log) == COMPRESSION_COLUMNS and log["events"] == 2.0 + 8.0 and log["n"] == 12.0
    log = step_log(shear())
    assert list(log) == SHEAR_COLUMNS and log["plastic"] == 1.0


@pytest.mark.parametrize(
    "step",
    [
        jamming(),
        jamming(phase="start", jammed=False, phi_high=np.inf),
        jamming(phase="final"),
        compression(),
        compression(events=()),
        compression(events=EVENTS),
        shear(),
        shear(plastic=False),
    ],
    ids=lambda s: type(s).__name__,
)
def test_steps_read_back_from_their_frames_unchanged(tmp_path, step):
    trajectory = Trajectory(tmp_path / "t.gsd", 42.0, model=MODEL, seed=1)
    trajectory.append(step)
    frame = read_gsd(tmp_path / "t.gsd")
    read = {
        JammingStep: jamming_step,
        CompressionStep: compression_step,
        ShearStep: lambda f: shear_step(f, MODEL),
    }[type(step)]
    back = read(frame)
    assert type(back) is type(step) and fields(back) == fields(step)
    np.testing.assert_array_equal(back.packing.positions, step.packing.positions)
    assert back.row() == step.row()


def test_a_frame_written_by_hand_in_the_format_reads_back(tmp_path):
    """A log as the hand-written serializers wrote it before the fields drove it."""
    log = {
        "index": 4.0, "phase": 1.0, "origin": 3.0, "phi": 0.81, "jammed": 0.0, "energy": 0.0,
        "pressure": 0.0, "contacts": 0.0, "iterations": 12.0, "evaluations": 13.0,
        "saddles": 0.0, "seconds": 0.5, "phi_low": 0.81, "phi_high": -1.0, "run_id": 1.0,
    }  # fmt: skip
    write_gsd(tmp_path / "j.gsd", PACKING, model=MODEL, observables=log)
    step = jamming_step(read_gsd(tmp_path / "j.gsd"))
    assert (step.index, step.phase, step.origin, step.jammed) == (4, "increment", 3, False)
    assert step.phi_high == np.inf and type(step.contacts) is int and type(step.jammed) is bool
    log = {
        **dict.fromkeys(COMPRESSION_COLUMNS, 1.0),
        "events": 5.0,
        "run_id": 1.0,
    }
    write_gsd(tmp_path / "c.gsd", PACKING, model=MODEL, observables=log)
    assert compression_step(read_gsd(tmp_path / "c.gsd")).events == ("unjammed", "saddle left")


def test_a_field_that_is_not_a_number_must_be_given():
    with pytest.raises(TypeError, match=r"ShearStep\.observables"):
        from_numbers(ShearStep, lambda name: 0.0, packing=PACKING)
    step = from_numbers(CompressionStep, lambda name: 0.0, packing=PACKING)
    assert step.events == () and as_row(step, {"index": {"n": 12}})["n"] == 12
