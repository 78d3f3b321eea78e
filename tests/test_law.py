"""A contact law defined here alone, not a power law, runs through the package: its compiled
loops, a relaxation, the stress and the moduli (against finite differences), and the refusals
of the forms it does not have."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import pytest

from athermal import ContactLaw, ContactModel, NumbaForm, Objective, PowerContact, random_packing
from athermal.analysis.moduli import linear_response
from athermal.analysis.observables import stress
from athermal.certify import certify
from athermal.errors import InputError
from athermal.model.cell import simple_shear
from athermal.model.contact import find_contacts, gradient, hessian, total_energy
from athermal.model.law import power_curvature, power_pair, power_total
from athermal.model.loops import kernels
from athermal.protocols import finite_strain_shear
from athermal.relaxation import minimize_objective
from conftest import network_strain

SOFT = 0.05
"""The stiffening length of :class:`Stiffening`: the cubic term doubles the force at
``delta = SOFT``."""


@numba.njit
def _stiffening_pair(delta, k, alpha):  # type: ignore[no-untyped-def]
    force = k * (delta + delta * delta / SOFT)
    return k * delta * delta * (0.5 + delta / (3.0 * SOFT)), force


@numba.njit
def _plain_total(total, alpha):  # type: ignore[no-untyped-def]
    return total


@numba.njit
def _stiffening_curvature(delta, dist, k, alpha):  # type: ignore[no-untyped-def]
    pull = k * (delta + delta * delta / SOFT) / dist
    return k * (1.0 + 2.0 * delta / SOFT) + pull, pull


@dataclass(frozen=True)
class Stiffening(ContactLaw):
    """``E = k (delta^2 / 2 + delta^3 / (3 s))``: a Hookean spring that stiffens at overlaps
    beyond ``s`` (:data:`SOFT`); harmonic at small overlap (alpha = 2)."""

    name = "stiffening"
    numba = NumbaForm(_stiffening_pair, _plain_total, _stiffening_curvature)

    @property
    def alpha(self) -> float:
        return 2.0

    def energy(self, delta, k):  # type: ignore[no-untyped-def]
        return k * delta * delta * (0.5 + delta / (3.0 * SOFT))

    def force(self, delta, k):  # type: ignore[no-untyped-def]
        return k * (delta + delta * delta / SOFT)

    def stiffness(self, delta, k):  # type: ignore[no-untyped-def]
        return k * (1.0 + 2.0 * delta / SOFT)


@numba.njit
def _copied_pair(delta, k, alpha):  # type: ignore[no-untyped-def]
    return power_pair(delta, k, alpha)


@dataclass(frozen=True)
class CopiedPower(PowerContact):
    """The power law through other compiled functions: the loops are compiled once more."""

    name = "copied power"
    numba = NumbaForm(_copied_pair, power_total, power_curvature)


MODEL = ContactModel(law=Stiffening(), stiffness=1.0)


def relaxed(n=96, phi=0.9, seed=3):
    result = minimize_objective(Objective(random_packing(n, phi, seed=seed), MODEL), rtol=1e-12)
    assert result.converged
    return result.packing


def test_the_law_is_its_own_derivatives():
    """The numpy forms: force and stiffness are the central differences of energy and force."""
    law, delta, h = Stiffening(), np.linspace(0.01, 0.2, 7), 1e-6
    for f, df in ((law.energy, law.force), (law.force, law.stiffness)):
        fd = (f(delta + h, 2.0) - f(delta - h, 2.0)) / (2 * h)
        np.testing.assert_allclose(fd, df(delta, 2.0), rtol=1e-8)


def test_the_compiled_loops_agree_with_the_numpy_forms():
    """Energy and gradient from the loops compiled for the law equal the vectorized sums, and
    the compiled Hessian the assembled one."""
    packing = random_packing(64, 0.9, seed=1)
    objective = Objective(packing, MODEL)
    energy, grad = objective(objective.x0)
    contacts = find_contacts(objective.packing(objective.x0, internal=True), MODEL)
    assert energy == pytest.approx(total_energy(contacts), rel=1e-13)
    reference = gradient(contacts, packing.n).ravel()
    np.testing.assert_allclose(grad, reference, atol=1e-14 * np.abs(reference).max())
    compiled = objective.hessian(objective.x0).matrix().toarray()
    np.testing.assert_allclose(compiled, hessian(contacts, packing.n).toarray(), atol=1e-12)
    assert kernels(Stiffening())["evaluate"] is not kernels(PowerContact())["evaluate"]


def test_compiled_once_more_the_power_law_is_the_same_bits():
    """The loops compiled for other compiled functions of the same law give its bits."""
    packing = random_packing(64, 0.9, seed=2)
    own = Objective(packing, ContactModel(2.0))
    copied = Objective(packing, ContactModel(law=CopiedPower(2.0)))
    assert kernels(CopiedPower(2.0))["evaluate"] is not kernels(PowerContact(2.0))["evaluate"]
    (e1, g1), (e2, g2) = own(own.x0), copied(copied.x0)
    assert e1 == e2
    np.testing.assert_array_equal(g1, g2)


def test_it_relaxes_and_its_stress_is_the_energy_derivative():
    """A relaxation converges; the stress equals ``-(1/V) dE/d epsilon`` by finite differences
    of the affinely deformed packing."""
    packing = relaxed()
    objective = Objective(packing, MODEL)
    _, grad = objective(objective.x0)
    contacts = find_contacts(packing, MODEL)
    assert np.abs(grad).max() < 1e-10 * contacts.force_magnitude.mean()  # at round-off
    sigma = stress(contacts, packing.cell)
    h, volume = 1e-6, packing.cell.volume
    for a, b in ((0, 0), (0, 1), (1, 1)):
        strain = np.zeros((2, 2))
        strain[a, b] = h
        energies = [
            total_energy(find_contacts(packing.deform(np.eye(2) + s * strain), MODEL))
            for s in (1.0, -1.0)
        ]
        fd = -(energies[0] - energies[1]) / (2 * h * volume)
        assert sigma[a, b] == pytest.approx(fd, rel=1e-6, abs=1e-9 * abs(sigma[0, 0]))


def test_its_moduli_match_finite_strain():
    """The linear-response shear modulus equals the relaxed stress response to small strain
    steps; the stiffening makes it differ from the Hookean packing's."""
    packing = relaxed()
    response = linear_response(packing, MODEL)
    assert 0.0 < response.shear < response.shear_affine
    d1 = simple_shear(1.0, 2) - np.eye(2)
    top = min(1e-5, 0.25 * network_strain(packing, MODEL, d1, True))
    measured = finite_strain_shear(packing, MODEL, np.linspace(0.1, 1.0, 10) * top)
    np.testing.assert_array_equal(measured.contacts, measured.contacts_initial)
    assert measured.modulus == pytest.approx(response.shear, rel=2e-3)
    hooke = linear_response(packing, ContactModel(2.0))
    assert abs(hooke.shear - response.shear) > 0.05 * response.shear


def test_forms_it_lacks_are_refused_in_one_line():
    """No double-double form: certification refuses; no JAX form: the JAX engine refuses;
    alpha and a law together are refused."""
    packing = relaxed(n=32, phi=0.88)
    with pytest.raises(InputError, match="law stiffening: extended precision"):
        certify(packing, MODEL)
    with pytest.raises(InputError, match="give alpha or a law"):
        ContactModel(2.5, law=Stiffening())
    pytest.importorskip("jax")
    from athermal import engines

    with pytest.raises(InputError, match="law stiffening: it has no JAX form"):
        engines.engine("jax").bind(Objective(packing, MODEL), "none", A=0.0, solver="auto")
