"""Minimization of H = U + P V over positions and cell: finite differences of H in every
variable (the cell ones above all), sigma = P I at the minimum, shear stability with the shape
free."""

import numpy as np
import pytest

from athermal.analysis.moduli import linear_response, stability
from athermal.analysis.observables import isostatic_contacts, measure
from athermal.enthalpy import Enthalpy, relax_at_pressure
from athermal.errors import InputError
from athermal.model.contact import ContactModel, find_contacts, total_energy
from athermal.model.objective import Objective
from athermal.model.packing import random_packing


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("cell", ["volume", "shape"])
def test_the_enthalpy_gradient_matches_finite_differences(dim, cell):
    model = ContactModel(2.5)
    packing = random_packing(64, 0.86 if dim == 2 else 0.66, dim=dim, seed=3)
    problem = Enthalpy(packing, model, 2e-3, cell)
    rng = np.random.default_rng(1)
    x = problem.x0.copy()
    x[: 64 * dim] += rng.normal(0.0, 1e-3, 64 * dim)
    x[64 * dim :] += np.triu(rng.normal(0.0, 3e-3, (dim, dim))).ravel() * problem.scale
    energy, grad = problem(x)
    deformed = problem.packing(x)
    assert energy == pytest.approx(
        total_energy(find_contacts(deformed, model)) + 2e-3 * deformed.cell.volume, rel=1e-14
    )
    cell_only = np.zeros(x.size)
    cell_only[64 * dim :] = rng.normal(size=dim * dim)
    for v in (rng.normal(size=x.size), cell_only):
        h = 1e-6 * problem.scale
        numeric = (problem(x + h * v)[0] - problem(x - h * v)[0]) / (2 * h)
        assert grad @ v == pytest.approx(numeric, rel=1e-6)
    fixed = grad[64 * dim :].reshape(dim, dim)
    assert np.all(fixed[np.tril_indices(dim, -1)] == 0)  # the lower triangle never moves
    if cell == "volume":
        assert np.count_nonzero(fixed) == 1


@pytest.mark.parametrize(
    ("cell", "precon"), [("volume", "none"), ("shape", "none"), ("shape", "exp")]
)
def test_an_unjammed_start_shrinks_to_a_minimum_at_the_pressure(cell, precon):
    model = ContactModel(2.0)
    start = random_packing(128, 0.8, seed=4)
    found = relax_at_pressure(start, model, 1e-3, cell=cell, precon=precon)
    assert found.result.converged
    assert found.pressure == pytest.approx(1e-3, rel=1e-6)
    assert found.packing.cell.volume < start.cell.volume
    # jammed: a rigid backbone of at least isostatic contacts (where it jams, 0.826-0.845 over
    # trajectories that differ in rounding only, is the protocol's luck at N = 128)
    obs = measure(found.packing, model)
    assert obs.contacts_nonrattler >= isostatic_contacts(obs.n - obs.n_rattlers, 2)
    # the forces balance in the relaxed cell
    objective = Objective(found.packing, model)
    force = objective.max_gradient(objective(objective.x0)[1])
    assert force < 1e-7 * find_contacts(found.packing, model).force_magnitude.mean()
    assert stability(found.packing, model).stable
    if cell == "shape":  # sigma = P I: no shear stress, and stable to shear
        np.testing.assert_allclose(found.stress, 1e-3 * np.eye(2), atol=1e-8 * 1e-3)
        assert linear_response(found.packing, model).shear >= -1e-9
        assert found.deformation[1, 0] == 0.0 and found.deformation[0, 1] != 0.0
    else:  # isotropic: F = lambda I
        assert found.deformation[0, 1] == 0.0
        assert found.deformation[0, 0] == pytest.approx(found.deformation[1, 1], rel=1e-15)


def test_bad_requests_are_refused():
    packing, model = random_packing(16, 0.8, seed=1), ContactModel()
    with pytest.raises(InputError, match="pressure"):
        relax_at_pressure(packing, model, 0.0)
    with pytest.raises(InputError, match="cell"):
        relax_at_pressure(packing, model, 1e-3, cell="strain")
    with pytest.raises(InputError, match="method"):
        relax_at_pressure(packing, model, 1e-3, method="newton")


def test_relax_pressure_writes_the_packing_in_its_relaxed_cell(tmp_path, capsys):
    import json

    from athermal.cli import main
    from athermal.io import read_gsd, write_gsd

    write_gsd(tmp_path / "r.gsd", random_packing(96, 0.8, seed=6), model=ContactModel())
    argv = ["relax", str(tmp_path / "r.gsd"), "-o", str(tmp_path / "p.gsd"), "--json"]
    assert main([*argv, "--pressure", "2e-3", "--cell", "shape"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["converged"] and report["pressure"] == pytest.approx(2e-3, rel=1e-6)
    assert abs(report["shear_stress"]) < 1e-8 * 2e-3
    frame = read_gsd(tmp_path / "p.gsd")
    np.testing.assert_allclose(
        frame.packing.cell.h, np.array(report["deformation"]) @ np.eye(2), rtol=1e-12
    )
