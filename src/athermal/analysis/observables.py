"""Macroscopic observables of a packing (seed section 2.4): stress, pressure, fabric, contacts,
rattlers and the coordination number.

Sign convention: ``sigma = (1/V) sum_c l_c (x) f_c`` with ``l_c = x_i - x_j`` and ``f_c`` the
(repulsive) force on ``i`` from ``j``, so the pressure ``trace(sigma) / d`` is positive under
compression and the shear stress is ``-sigma[0, 1]``. Stress in units of ``k`` x length^(alpha-d).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._portable import outer_sum
from ..model.cell import AXES, Cell, particle_volumes
from ..model.contact import ContactModel, Contacts, find_contacts, gradient, total_energy
from ..model.packing import Packing
from ..model.walls import wall_pressures, wall_stress


def stress(contacts: Contacts, cell: Cell) -> NDArray[np.float64]:
    """Stress tensor ``(1/V) sum_c l_c (x) f_c`` ``(d, d)`` (symmetric), wall contacts included
    (:mod:`athermal.model.walls`)."""
    sigma = outer_sum(contacts.branch, contacts.force) / cell.volume
    if contacts.walls is not None:
        sigma += wall_stress(contacts.walls, cell)
    return sigma


def pressure(sigma: NDArray[np.float64]) -> float:
    """``trace(sigma) / d``."""
    return float(np.trace(sigma) / sigma.shape[0])


def shear_stress(sigma: NDArray[np.float64]) -> float:
    """``-sigma[0, 1]``, the paper's shear stress for simple shear ``x += gamma y``."""
    return float(-sigma[0, 1])


def fabric(contacts: Contacts, radii: NDArray[np.float64], cell: Cell) -> NDArray[np.float64]:
    """Fabric tensor ``(1/V) sum_c (v_i + v_j) n_c (x) n_c`` ``(d, d)``, dimensionless.

    ``v`` is the particle area ``pi r^2`` in 2D (the paper's formula) and volume in 3D.
    """
    vol = particle_volumes(radii, cell.dim)
    weight = vol[contacts.i] + vol[contacts.j]
    n = contacts.normal
    return outer_sum(weight[:, None] * n, n) / cell.volume


def isotropic_part(tensor: NDArray[np.float64]) -> float:
    """Mean eigenvalue of a symmetric tensor, ``trace / d``: ``(lambda_1 + lambda_2) / 2`` in
    2D."""
    return float(np.trace(tensor) / tensor.shape[0])


def deviatoric_part(tensor: NDArray[np.float64]) -> float:
    """``(lambda_max - lambda_min) / 2``: the paper's ``|lambda_1 - lambda_2| / 2`` in 2D, there
    ``sqrt(((t_xx - t_yy) / 2)^2 + t_xy^2)`` (correctly rounded steps; in 3D LAPACK's
    eigenvalues)."""
    if tensor.shape[0] == 2:
        half = 0.5 * (tensor[0, 0] - tensor[1, 1])
        off = 0.5 * (tensor[0, 1] + tensor[1, 0])
        return float(np.sqrt(half * half + off * off))
    eig = np.linalg.eigvalsh(tensor)
    return float((eig[-1] - eig[0]) / 2.0)


def rattlers(
    contacts: Contacts, n: int, dim: int, fixed: NDArray[np.bool_] | None = None
) -> NDArray[np.bool_]:
    """Mask ``(N,)`` of rattlers: particles with fewer than ``d + 1`` contacts, removed
    iteratively (removing one can turn a neighbour into a rattler). A contact with a wall
    counts as one contact of its particle: the wall is fixed, so it never becomes a rattler;
    so are the particles of the mask ``fixed`` ``(N,)`` (frozen ones), never rattlers."""
    keep = contacts.i != contacts.j
    i, j = contacts.i[keep], contacts.j[keep]
    on_walls = np.bincount(_wall_particles(contacts), minlength=n)
    rattler = np.zeros(n, dtype=bool)
    while True:
        live = ~(rattler[i] | rattler[j])
        counts = np.bincount(i[live], minlength=n) + np.bincount(j[live], minlength=n)
        new = (counts + on_walls < dim + 1) & ~rattler
        if fixed is not None:
            new &= ~fixed
        if not new.any():
            return rattler
        rattler |= new


def coordination(contacts: Contacts, rattler: NDArray[np.bool_]) -> tuple[float, int]:
    """Coordination ``z`` over non-rattlers and the contact count ``C'`` among them: pairs
    ``C_p`` and wall contacts ``C_w`` of non-rattlers, ``C' = C_p + C_w`` and
    ``z = (2 C_p + C_w) / N'`` (each particle's contacts, averaged).

    ``z`` is 0 when every particle is a rattler (an unjammed packing).
    """
    live = ~(rattler[contacts.i] | rattler[contacts.j]) & (contacts.i != contacts.j)
    n_live = int((~rattler).sum())
    pairs = int(live.sum())
    walls = int((~rattler[_wall_particles(contacts)]).sum())
    return ((2.0 * pairs + walls) / n_live if n_live else 0.0), pairs + walls


def isostatic_contacts(n_live: int, dim: int, periodic: int | None = None) -> int:
    """Contacts of ``n_live`` non-rattlers at isostaticity: ``N_iso = d N' - t + 1`` with
    ``t = periodic`` the rigid translations (the cell's periodic axes, default ``d``: a
    periodic cell, ``d (N' - 1) + 1``), 0 without non-rattlers.

    Counting: ``d N'`` coordinates, less the ``t`` translations that move no contact (along
    a walled axis the walls hold the packing), must be fixed by the contacts, and one more
    contact fixes the packing fraction at the jamming point."""
    t = dim if periodic is None else periodic
    return dim * n_live - t + 1 if n_live >= 1 else 0


def _wall_particles(contacts: Contacts) -> NDArray[np.int64]:
    """The particle of each wall contact ``(W,)`` (empty without walls)."""
    return np.zeros(0, np.int64) if contacts.walls is None else contacts.walls.particle


@dataclass(frozen=True)
class Observables:
    """Everything :func:`measure` reports. Tensors are ``(d, d)`` arrays. ``contacts`` counts
    pairs and wall contacts; ``walls`` names the walled axes (``"y"``; ``""`` periodic) and
    ``wall_pressure`` the force per unit area on each wall (``{"y-": ..., "y+": ...}``,
    :func:`athermal.model.walls.wall_pressures`)."""

    n: int
    dim: int
    phi: float
    energy: float
    pressure: float
    shear_stress: float
    stress: NDArray[np.float64]
    fabric: NDArray[np.float64]
    stress_iso: float
    stress_dev: float
    fabric_iso: float
    fabric_dev: float
    contacts: int
    contacts_nonrattler: int
    z: float
    n_rattlers: int
    max_gradient: float
    mean_contact_force: float
    walls: str = ""
    wall_pressure: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (tensors as nested lists)."""
        out = asdict(self)
        for key, value in out.items():
            if isinstance(value, np.ndarray):
                out[key] = value.tolist()
        return out


def measure(
    packing: Packing, model: ContactModel, fixed: NDArray[np.bool_] | None = None
) -> Observables:
    """All observables of ``packing`` under the contact ``model``; the particles of the mask
    ``fixed`` (plane shear's glued ones) are never rattlers."""
    contacts = find_contacts(packing, model)
    sigma = stress(contacts, packing.cell)
    fab = fabric(contacts, packing.radii, packing.cell)
    rattler = rattlers(contacts, packing.n, packing.dim, fixed)
    z, c_live = coordination(contacts, rattler)
    grad = gradient(contacts, packing.n)
    forces = contacts.force_magnitude
    return Observables(
        n=packing.n,
        dim=packing.dim,
        phi=packing.phi,
        energy=total_energy(contacts),
        pressure=pressure(sigma),
        shear_stress=shear_stress(sigma),
        stress=sigma,
        fabric=fab,
        stress_iso=isotropic_part(sigma),
        stress_dev=deviatoric_part(sigma),
        fabric_iso=isotropic_part(fab),
        fabric_dev=deviatoric_part(fab),
        contacts=contacts.count,
        contacts_nonrattler=c_live,
        z=z,
        n_rattlers=int(rattler.sum()),
        max_gradient=float(np.sqrt((grad**2).sum(axis=1)).max()),
        mean_contact_force=float(forces.mean()) if forces.size else 0.0,
        walls="".join(AXES[a] for a in packing.cell.walls),
        wall_pressure={}
        if contacts.walls is None
        else wall_pressures(contacts.walls, packing.cell),
    )


def file_observables(obs: Observables) -> dict[str, float | np.ndarray]:
    """The observables written with a configuration."""
    return {
        "energy": obs.energy,
        "pressure": obs.pressure,
        "stress": obs.stress,
        "fabric": obs.fabric,
        "phi": obs.phi,
        "z": obs.z,
    }
