"""The Hessian of a contact network: its soft mode from the pinned factor's solves (ARPACK on
``H^+``) is the dense spectrum's lowest eigenpair that is no translation, periodic and between
walls with held particles, in 2D and 3D."""

from __future__ import annotations

import numpy as np
import pytest

from athermal import ContactModel, jam, random_packing
from athermal.analysis.moduli import nonrattler_contacts
from athermal.analysis.network import DENSE_SOFT_MODE_DOFS, NetworkHessian
from athermal.model.cell import Cell
from athermal.model.objective import Objective
from athermal.protocols.shear import rough_walls
from athermal.relaxation import Minimizer, Relaxer, force_tolerance

HARMONIC = ContactModel(2.0)


def relaxed(packing, frozen=None):
    objective = Objective(packing, HARMONIC, frozen=frozen)
    result, _ = Relaxer(objective, Minimizer()).relax_to_minimum(
        objective.x0, gtol=force_tolerance(packing, HARMONIC, 0.0)
    )
    return result.packing


@pytest.mark.parametrize(("dim", "n", "walls"), [(2, 256, False), (3, 200, False), (2, 256, True)])
def test_the_soft_mode_by_the_inverse_is_the_dense_one(dim, n, walls):
    """Above :data:`DENSE_SOFT_MODE_DOFS` rows the soft mode comes from ARPACK on ``H^+``; it
    agrees with the dense ``eigh`` of the same Hessian (its translations skipped) in the
    eigenvalue to 1e-9 and in the mode's direction."""
    if walls:
        start = random_packing(n, 0.9, seed=5, cell=Cell.unit(2, walls="y"))
        layers = rough_walls(start, None)
        frozen = layers[0] | layers[1]
        packing = relaxed(start, frozen)
    else:
        frozen = None
        jammed = jam(random_packing(n, 0.8 if dim == 2 else 0.6, seed=2, dim=dim), HARMONIC)
        packing = relaxed(jammed.packing.at_phi(jammed.phi_c + 0.02))
    contacts, rattler = nonrattler_contacts(packing, HARMONIC, frozen)
    network = NetworkHessian(packing, contacts, rattler, frozen)
    assert network.h.shape[0] > DENSE_SOFT_MODE_DOFS and network.factor is not None
    value, mode = network.soft_mode()
    values, vectors = np.linalg.eigh(network.h.toarray())
    lowest = values[network.translations]  # the translations are the lowest (zero) ones
    assert abs(values[: network.translations]).max(initial=0.0) < 1e-9 * values[-1]
    assert value == pytest.approx(lowest, rel=1e-9)
    direction = np.zeros_like(mode)
    direction.reshape(-1)[network.dofs] = vectors[:, network.translations]
    assert abs(float(np.sum(direction * mode))) == pytest.approx(1.0, abs=1e-8)
