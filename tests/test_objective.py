import numpy as np
import pytest

from athermal.contact import ContactModel, packing_energy
from athermal.errors import InputError
from athermal.objective import Objective
from athermal.packing import random_packing


def test_evaluations_are_cached_counted_and_match_the_packing_energy():
    packing = random_packing(200, 0.9, seed=5)
    obj = Objective(packing, ContactModel(2.5))
    energy, _ = obj(obj.x0)
    obj(obj.x0.copy())
    assert obj.n_evaluations == 1
    assert energy == pytest.approx(packing_energy(packing, ContactModel(2.5)), rel=1e-12)
    np.testing.assert_array_equal(obj.packing(obj.x0).positions, packing.positions)


@pytest.mark.parametrize("factor", [1.001, 1.02, 1.3, 0.9])
def test_set_radii_gives_the_energy_of_the_grown_packing(factor):
    """Small growth keeps the Verlet list (it spends skin), large growth rebuilds it; either
    way the energy equals that of a packing built with the new radii."""
    packing = random_packing(300, 0.8, seed=6)
    model = ContactModel(2.0)
    obj = Objective(packing, model)
    obj(obj.x0)
    obj.set_radii(packing.radii * factor)
    energy, _ = obj(obj.x0)
    grown = packing.scale_radii(factor)
    assert energy == pytest.approx(packing_energy(grown, model), rel=1e-12, abs=1e-300)
    assert obj.n_rebuilds == (1 if factor < 1.05 else 2)


def test_set_radii_then_moving_particles_still_sees_every_contact():
    packing = random_packing(300, 0.8, seed=7)
    model = ContactModel(2.0)
    obj = Objective(packing, model)
    obj(obj.x0)
    obj.set_radii(packing.radii * 1.01)  # growth ~0.01 r: most of the skin still available
    rng = np.random.default_rng(0)
    shift = rng.uniform(-1.0, 1.0, obj.x0.shape) * 0.06 * packing.radii.mean()
    x = obj.x0 + shift
    energy, _ = obj(x)
    assert obj.n_rebuilds == 1
    expected = packing_energy(obj.packing(x), model)  # a fresh neighbour list
    assert obj.packing(x).radii == pytest.approx(packing.radii * 1.01, rel=1e-15)
    assert energy == pytest.approx(expected, rel=1e-12)


def test_set_radii_rejects_bad_radii():
    obj = Objective(random_packing(16, 0.5, seed=1), ContactModel())
    with pytest.raises(InputError, match="radii"):
        obj.set_radii(np.full(15, 0.1))
    with pytest.raises(InputError, match="radii"):
        obj.set_radii(np.full(16, -0.1))
