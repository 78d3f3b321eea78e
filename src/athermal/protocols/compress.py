"""Quasi-static compression above jamming: the seed's scaling-law experiment (section 4.2).

From a jammed packing at ``phi_c`` the radii are grown to ``phi_c + Delta phi`` for log-spaced
``Delta phi`` (1e-7 ... 1e-1 by default), each state relaxed from the previous one. Every step
reports pressure, energy, contacts, z with rattlers removed and its distance ``z - z_iso`` from
the isostatic value of the non-rattlers, and the bulk and shear moduli by exact linear response
(:func:`~athermal.moduli.linear_response`); :func:`scaling_exponents` fits the power laws
``p ~ Delta phi^(alpha-1)``, ``G ~ Delta phi^(alpha-3/2)``, ``z - z_iso ~ Delta phi^(1/2)``.

The bulk modulus reported is the seed's ``B = phi dp/dphi`` along this protocol (radii growing in
a fixed cell). Growing the radii is cell compression followed by a uniform rescaling of lengths,
under which stresses scale as ``length^(alpha-d)``, so ``B = B_cell + (alpha - d) p / d`` with
``B_cell = -V dp/dV`` the fixed-radii modulus of the linear response.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validate import float_array
from ..contact import ContactModel
from ..errors import InputError
from ..fitting import PowerLaw, fit_jamming_point, fit_power_law
from ..moduli import linear_response
from ..objective import Objective
from ..observables import measure
from ..packing import Packing
from ._relax import GTOL_FLOOR, Minimizer, Relaxer, force_scale

RTOL = 1e-9
"""Default tolerance: ``max_i |grad_i| <= RTOL`` x the mean contact force at a step's start."""


def log_spaced(start: float = 1e-7, stop: float = 1e-1, per_decade: int = 4) -> NDArray[np.float64]:
    """``Delta phi`` values from ``start`` to ``stop``, ``per_decade`` per decade (both ends)."""
    if not 0.0 < start < stop:
        raise InputError(f"delta phi range: need 0 < start < stop, got {start}, {stop}")
    if int(per_decade) != per_decade or per_decade < 1:
        raise InputError(f"per_decade: must be an integer >= 1, got {per_decade!r}")
    count = round(float(np.log10(stop / start)) * per_decade) + 1
    return np.logspace(np.log10(start), np.log10(stop), count)


def isostatic_z(n_live: int, dim: int) -> float:
    """Isostatic coordination of ``n_live`` non-rattlers in a periodic cell:
    ``2 N_c / N'`` with ``N_c = d (N' - 1) + 1`` contacts (tends to ``2 d``)."""
    if n_live < 1:
        return 0.0
    return 2.0 * (dim * (n_live - 1) + 1) / n_live


@dataclass(frozen=True, eq=False)
class CompressionStep:
    """One relaxed state of the compression (units: ``k`` and the cell's lengths).

    ``bulk_modulus`` is ``phi dp/dphi`` along the protocol, ``shear_modulus`` the simple-shear
    ``G``, both by linear response; ``z_excess = z - z_iso`` over the non-rattlers (``-2 d``
    when every particle is a rattler).
    """

    index: int
    delta_phi: float
    phi: float
    energy: float
    pressure: float
    shear_stress: float
    contacts: int
    z: float
    z_excess: float
    n_rattlers: int
    bulk_modulus: float
    shear_modulus: float
    iterations: int
    evaluations: int
    seconds: float
    packing: Packing

    def row(self) -> dict[str, float | int]:
        """The step's numbers (no packing), for tables."""
        return {
            "index": self.index,
            "delta_phi": self.delta_phi,
            "phi": self.phi,
            "energy": self.energy,
            "pressure": self.pressure,
            "shear_stress": self.shear_stress,
            "contacts": self.contacts,
            "z": self.z,
            "z_excess": self.z_excess,
            "n_rattlers": self.n_rattlers,
            "bulk_modulus": self.bulk_modulus,
            "shear_modulus": self.shear_modulus,
            "iterations": self.iterations,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
        }


def compression_steps(
    jammed: Packing,
    model: ContactModel,
    *,
    phi_c: float | None = None,
    delta_phis: ArrayLike | None = None,
    minimizer: Minimizer | None = None,
    rtol: float = RTOL,
    resume: Sequence[CompressionStep] = (),
) -> Iterator[CompressionStep]:
    """Compress ``jammed`` quasi-statically, yielding each relaxed step.

    Parameters
    ----------
    jammed : a jammed packing (e.g. :func:`~athermal.protocols.jam`'s), the first start.
    model : contact law.
    phi_c : jamming fraction ``Delta phi`` is measured from; default ``jammed.phi``.
    delta_phis : increasing ``Delta phi > 0`` ``(k,)``; default :func:`log_spaced`.
    minimizer : how each step is relaxed (default L-BFGS).
    rtol : tolerance relative to the mean contact force at each step's start, floored at
        ``GTOL_FLOOR`` x ``k <r>^(alpha-1)`` (round-off).
    resume : the steps already done by an interrupted run with the same arguments; the run
        continues after the last one. Each step builds its objective from the previous step's
        packing alone, so the continued run matches an uninterrupted one bit for bit.
    """
    targets = float_array(log_spaced() if delta_phis is None else delta_phis, "delta_phis", (None,))
    if targets.size == 0 or np.any(targets <= 0.0) or np.any(np.diff(targets) <= 0.0):
        raise InputError("delta_phis: need increasing values > 0")
    phi_ref = jammed.phi if phi_c is None else float(phi_c)
    if not 0.0 < phi_ref < 1.0 or phi_ref > jammed.phi + 1e-12:
        raise InputError(f"phi_c: must lie in (0, phi of the packing = {jammed.phi:.9g}]")
    if phi_ref + targets[-1] >= 1.0:
        raise InputError(f"delta_phis: phi_c + {targets[-1]:g} reaches 1")
    config = minimizer or Minimizer()
    base, phi0 = jammed.radii, jammed.phi
    current = jammed
    first = 0
    if resume:
        if [s.index for s in resume] != list(range(len(resume))) or len(resume) > targets.size:
            raise InputError("resume: steps must be this run's steps 0, 1, ... in order")
        current, first = resume[-1].packing, len(resume)
    for index in range(first, targets.size):
        dphi = float(targets[index])
        t0 = time.perf_counter()
        phi = phi_ref + dphi
        if phi < phi0 - 1e-12:
            raise InputError(
                f"delta_phis: phi_c + {dphi:g} is below the jammed packing's phi {phi0:.9g}"
            )
        radii = base * (phi / phi0) ** (1.0 / jammed.dim)
        objective = Objective(Packing(current.positions, radii, jammed.cell), model)
        f0 = objective.mean_contact_force(objective.x0)
        gtol = max(rtol * f0, GTOL_FLOOR * force_scale(radii, model))
        result = Relaxer(objective, config).relax(
            objective.x0, gtol=gtol, what=f"compression step {index} (delta phi {dphi:g})"
        )
        current = result.packing
        obs = measure(current, model)
        moduli = linear_response(current, model)
        n_live = obs.n - obs.n_rattlers
        yield CompressionStep(
            index=index,
            delta_phi=dphi,
            phi=phi,
            energy=obs.energy,
            pressure=obs.pressure,
            shear_stress=obs.shear_stress,
            contacts=obs.contacts,
            z=obs.z,
            z_excess=obs.z - isostatic_z(n_live, jammed.dim) if n_live else -2.0 * jammed.dim,
            n_rattlers=obs.n_rattlers,
            bulk_modulus=moduli.bulk + (model.alpha - jammed.dim) * obs.pressure / jammed.dim,
            shear_modulus=moduli.shear,
            iterations=result.iterations,
            evaluations=result.evaluations,
            seconds=time.perf_counter() - t0,
            packing=current,
        )


@dataclass(frozen=True)
class ScalingExponents:
    """Power laws fitted to a compression: ``p``, ``G`` and ``z - z_iso`` against
    ``phi - phi_c``; ``None`` where fewer than 3 usable points fell in the window.

    ``phi_c`` is the jamming point the fits use: the protocol's, or (``refine``) the one of
    the fitted ``p = a (phi - phi_c)^b``; ``branch`` the steps fitted (see
    :func:`scaling_exponents`).
    """

    pressure: PowerLaw | None
    shear_modulus: PowerLaw | None
    z_excess: PowerLaw | None
    phi_c: float
    branch: int


def jammed_branch(steps: Sequence[CompressionStep]) -> list[CompressionStep]:
    """The steps after the last unjammed one (no pressure, or fewer contacts than isostatic):
    a finite packing can unjam during a compression step and jam again later, in another basin
    with its own jamming point."""
    last_free = max(
        (k for k, s in enumerate(steps) if not (s.pressure > 0.0 and s.z_excess > -1e-9)),
        default=-1,
    )
    return list(steps[last_free + 1 :])


def scaling_exponents(
    steps: Sequence[CompressionStep],
    *,
    lower: float = 0.0,
    upper: float = np.inf,
    refine: bool = True,
) -> ScalingExponents:
    """Fit the three power laws to the jammed branch (:func:`jammed_branch`) of ``steps``.

    With ``refine`` the jamming point is fitted too, ``p = a (phi - phi_c)^b`` with ``phi_c``
    free (:func:`~athermal.fitting.fit_jamming_point`, all branch points): the bisection leaves
    the jammed packing up to ~10 epsilon above the jamming point of its own basin, which bends
    ``p`` at ``Delta phi`` below ~1e-5. ``G`` and ``z - z_iso`` are then fitted against
    ``phi - phi_c`` within ``[lower, upper]``; without ``refine`` all three use the protocol's
    ``Delta phi`` and the window.
    """
    branch = jammed_branch(steps)
    phi = np.array([s.phi for s in branch])
    phi_c = float(branch[0].phi - branch[0].delta_phi) if branch else np.nan
    pressure_fit: PowerLaw | None = None
    if refine and len(branch) >= 4:
        phi_c, pressure_fit = fit_jamming_point(phi, [s.pressure for s in branch])
    dphi = phi - phi_c

    def fit(values: list[float]) -> PowerLaw | None:
        try:
            return fit_power_law(dphi, values, lower=lower, upper=upper)
        except InputError:
            return None

    return ScalingExponents(
        pressure=pressure_fit or fit([s.pressure for s in branch]),
        shear_modulus=fit([s.shear_modulus for s in branch]),
        z_excess=fit([s.z_excess for s in branch]),
        phi_c=phi_c,
        branch=len(branch),
    )
