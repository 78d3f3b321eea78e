import numpy as np
import pytest

from athermal.analysis.observables import (
    coordination,
    deviatoric_part,
    fabric,
    isotropic_part,
    measure,
    rattlers,
)
from athermal.model.cell import Cell, isotropic
from athermal.model.contact import ContactModel, find_contacts
from athermal.model.packing import Packing, random_packing


@pytest.mark.parametrize("name", ["table1_N4096_alpha2.npz", "table1_N4096_alpha2.5.npz"])
def test_reference_configurations_reproduce_their_recorded_observables(name):
    from conftest import DATA

    ref = np.load(DATA / name)
    p = Packing(ref["positions"], ref["radii"], Cell.box(ref["box"]))
    obs = measure(p, ContactModel(float(ref["alpha"]), float(ref["k"])))
    assert obs.energy == pytest.approx(float(ref["energy"]), rel=1e-12)
    assert obs.pressure == pytest.approx(float(ref["pressure"]), rel=1e-12)
    assert obs.mean_contact_force == pytest.approx(float(ref["mean_contact_force"]), rel=1e-12)
    assert obs.phi == pytest.approx(float(ref["phi"]), rel=1e-14)
    assert obs.contacts == int(ref["n_contacts"])
    assert obs.n_rattlers == int(ref["n_rattlers"])
    assert obs.z == pytest.approx(float(ref["Z_nonrattler"]), rel=1e-14)
    assert obs.max_gradient < 1e-10 * obs.mean_contact_force  # round-off floor ~3e-11 F0


def test_jammed_packing_is_nearly_isostatic(jammed_packing_2d):
    p, _ = jammed_packing_2d
    obs = measure(p, ContactModel(2.0))
    n_live = p.n - obs.n_rattlers
    isostatic = 2 * (n_live - 1) + 1
    assert obs.contacts_nonrattler >= isostatic  # a stable packing has at least N_c contacts
    assert obs.z == pytest.approx(4.0, abs=0.2)


def test_pressure_is_positive_under_compression_and_grows_with_it():
    p = random_packing(300, 0.9, seed=1)
    model = ContactModel(2.0)
    low = measure(p, model)
    high = measure(p.deform(isotropic(0.99)), model)
    assert 0 < low.pressure < high.pressure
    assert low.stress_iso == pytest.approx(low.pressure)


def test_fabric_of_a_triangle_by_hand():
    r, side = 0.1, 0.18
    angles = np.deg2rad([90.0, 210.0, 330.0])
    x = side / np.sqrt(3.0) * np.column_stack([np.cos(angles), np.sin(angles)])
    p = Packing(x, np.full(3, r), Cell.box([1.0, 1.0]))
    c = find_contacts(p, ContactModel())
    f = fabric(c, p.radii, p.cell)
    # three directions 120 degrees apart: sum n n^T = 3/2 I; weight pi (r^2 + r^2) each
    np.testing.assert_allclose(f, 3 * np.pi * r**2 * np.eye(2), atol=1e-15)
    assert isotropic_part(f) == pytest.approx(3 * np.pi * r**2)
    assert deviatoric_part(f) == pytest.approx(0.0, abs=1e-15)
    # every disk has two contacts < d + 1: all are rattlers, z = 0
    rattler = rattlers(c, 3, 2)
    assert rattler.all()
    assert coordination(c, rattler) == (0.0, 0)


def test_isotropic_and_deviatoric_parts_follow_the_eigenvalue_definition():
    t = np.array([[3.0, 1.0], [1.0, 1.0]])
    lam = np.linalg.eigvalsh(t)
    assert isotropic_part(t) == pytest.approx(lam.mean())
    assert deviatoric_part(t) == pytest.approx(abs(lam[1] - lam[0]) / 2)


def test_rattler_removal_is_iterative_and_idempotent():
    # a square of four disks each touching two others, plus a chain hanging off one corner
    cell = Cell.box([10.0, 10.0])
    x = np.array([[0, 0], [1.9, 0], [0, 1.9], [1.9, 1.9], [3.8, 0.0], [5.7, 0.0]], dtype=float)
    p = Packing(x, np.ones(6), cell)
    c = find_contacts(p, ContactModel())
    counts = np.bincount(np.concatenate([c.i, c.j]), minlength=6)
    assert counts.tolist() == [2, 3, 2, 2, 2, 1]
    assert rattlers(c, 6, 2).all()  # removing 5 leaves 4 with 1, then 1 with 2, ...
    p2 = random_packing(400, 0.9, seed=3)
    c2 = find_contacts(p2, ContactModel())
    first = rattlers(c2, p2.n, 2)
    keep = ~(first[c2.i] | first[c2.j])
    live_counts = np.bincount(c2.i[keep], minlength=p2.n) + np.bincount(c2.j[keep], minlength=p2.n)
    assert np.all(live_counts[~first] >= 3)
    assert np.all(live_counts[first] == 0)


def test_three_dimensional_observables():
    p = random_packing(300, 0.7, dim=3, seed=2)
    obs = measure(p, ContactModel(2.5))
    assert obs.stress.shape == (3, 3) and obs.fabric.shape == (3, 3)
    assert obs.pressure == pytest.approx(np.trace(obs.stress) / 3)
    live = p.n - obs.n_rattlers
    assert obs.z == pytest.approx(2 * obs.contacts_nonrattler / live)
    assert obs.z >= 4.0  # every non-rattler has at least d + 1 = 4 contacts
