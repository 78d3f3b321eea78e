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
import warnings
from collections.abc import Collection, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validate import float_array
from ..contact import ContactModel, find_contacts
from ..errors import InputError
from ..fitting import PowerLaw, fit_jamming_point, fit_power_law
from ..minimize import RTOL, MinimizeResult
from ..moduli import linear_response
from ..objective import Objective
from ..observables import Observables, isostatic_contacts, measure
from ..packing import Packing
from ._relax import Minimizer, Relaxer, force_tolerance
from .jamming import overlap_distance

EVENTS = ("unjammed", "pressure drop", "saddle left", "unstable to shear")
"""What a compression step reports when it happens (``CompressionStep.events``): no load borne
(:func:`is_unjammed`); a pressure below the previous step's; a saddle left along its negative
mode (:meth:`~athermal.protocols._relax.Relaxer.relax_to_minimum`); a minimum with a negative
linear-response shear modulus, unstable to shear at fixed cell (Dagois-Bohy et al., PRL 109,
095703 (2012): physical near jamming, where ``p N^2`` is small)."""
MAX_SPLITS = 4
"""A compression step whose pressure drops (or that unjams) is redone in halves, down to
``2^MAX_SPLITS`` substeps: a one-shot relaxation can jump out of a stable basin (measured: from a
packing 5.6e-5 above jamming, L-BFGS and CG relaxed the growth to 1e-4 into an unjammed state,
while FIRE and ten L-BFGS substeps followed the basin to p = 4.1e-5). A drop that persists at
the finest substep is an instability of the packing (reported)."""
UNJAMMED_FORCE = 1e3
"""A relaxed step counts as unjammed when its mean contact force is at most this many times the
force tolerance it was relaxed to: such forces are the residual the minimizer may leave, not a
load. Seen (N = 1024, alpha = 2, realization 2 of root seed 0 compressed from 1e-4 to 1e-3 above
``phi_c``, ``benchmarks/spectrum.py``): a packing that rearranged into a looser one over 8
substeps stopped at p = 1.5e-12, its mean contact force 4.8e-14 only 6.7 times the tolerance of
its last substep, and was reported jammed with a pressure drop (a shear step of 1e-6 then
relaxed it to zero energy); the jammed steps of that compression carried 5e6-7e8 times theirs."""
UNJAMMED_DROP = 1e-3
"""With a loose ``rtol`` a jammed step's forces are only ``~1 / rtol`` times its tolerance, so the
factor :data:`UNJAMMED_FORCE` is capped at ``UNJAMMED_DROP / rtol``: an unjammed step's forces
must also have fallen this far below those it started from (``rtol`` = 1e-3: to the tolerance
itself)."""
FIT_LOWER = 1e-6
"""Smallest ``Delta phi`` fitted by default: the jamming protocol's default ``epsilon``, below
which ``Delta phi`` is not known to better than itself."""
FAR_ABOVE = 10.0
""":func:`compression_steps` warns when the start's overlaps (:func:`overlap_distance`) put it
more than this many times ``max(phi - phi_c, first Delta phi)`` above its jamming point."""


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
    return 2.0 * isostatic_contacts(n_live, dim) / n_live if n_live >= 1 else 0.0


@dataclass(frozen=True, eq=False)
class CompressionStep:
    """One relaxed state of the compression (units: ``k`` and the cell's lengths).

    ``bulk_modulus`` is ``phi dp/dphi`` along the protocol, ``shear_modulus`` the simple-shear
    ``G``, both by linear response (negative for a minimum unstable to shear: the event
    ``unstable to shear``, and no modulus in the fits); ``z_excess = z - z_iso`` over the
    non-rattlers (``-2 d`` when every particle is a rattler); ``events`` what happened
    (names from :data:`EVENTS`), ``saddles`` how many saddles were left on the way and
    ``substeps`` how many relaxations the step took (more than 1 after a pressure drop,
    :data:`MAX_SPLITS`).
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
    saddles: int
    substeps: int
    events: tuple[str, ...]
    iterations: int
    evaluations: int
    seconds: float
    packing: Packing

    def row(self) -> dict[str, float | int | str]:
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
            "saddles": self.saddles,
            "substeps": self.substeps,
            "events": ";".join(self.events),
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
    jammed : a jammed packing (e.g. :func:`~athermal.protocols.jam`'s), the first start;
        refused when it has no energy, pressure or rigid backbone (every particle a rattler),
        and a ``UserWarning`` when its overlaps put
        it far above ``phi_c`` (:data:`FAR_ABOVE`).
    model : contact law.
    phi_c : jamming fraction ``Delta phi`` is measured from; default ``jammed.phi``.
    delta_phis : increasing ``Delta phi > 0`` ``(k,)``; default :func:`log_spaced`.
    minimizer : how each step is relaxed (default L-BFGS).
    rtol : tolerance relative to the mean contact force at each step's start, floored at
        round-off (:func:`~athermal.protocols._relax.round_off_floor`). Every step is checked to
        be a local minimum; a saddle is left along its negative mode (``saddles``, ``events``).
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
    start = measure(jammed, model)
    if not (start.energy > 0.0 and start.pressure > 0.0 and start.n_rattlers < start.n):
        raise InputError(
            f"jammed: the start packing is not jammed (E = {start.energy:.3e}, p = "
            f"{start.pressure:.3e}, {start.n_rattlers} of {start.n} particles rattlers: no rigid "
            "backbone); jam it first (athermal jam)"
        )
    above = overlap_distance(find_contacts(jammed, model), jammed)
    if above > FAR_ABOVE * max(jammed.phi - phi_ref, float(targets[0])):
        warnings.warn(
            f"compression: the start's overlaps are those of a packing ~{above:.1e} above its "
            f"jamming point, but phi - phi_c = {jammed.phi - phi_ref:.1e}: Delta phi is not "
            "measured from its own jamming point",
            UserWarning,
            stacklevel=2,
        )
    config = minimizer or Minimizer()
    base, phi0 = jammed.radii, jammed.phi

    def advance(
        packing: Packing, p_start: float, phi: float, depth: int, index: int
    ) -> tuple[MinimizeResult, int, int]:
        """Grow ``packing`` (pressure ``p_start``) to ``phi`` and relax; on a pressure drop or
        unjamming of a jammed start, redo it in two halves (to depth :data:`MAX_SPLITS`).
        Returns the last relaxation (iterations and evaluations summed over the substeps), the
        saddles left and the number of substeps."""
        radii = base * (phi / phi0) ** (1.0 / jammed.dim)
        grown = Packing(packing.positions, radii, jammed.cell)
        objective = Objective(grown, model)
        result, saddles = Relaxer(objective, config).relax_to_minimum(
            objective.x0,
            gtol=force_tolerance(grown, model, rtol),
            what=f"compression step {index} (phi {phi:.9g})",
        )
        p_end = measure(result.packing, model).pressure
        if depth == MAX_SPLITS or p_start <= 0.0 or (p_end >= p_start and p_end > 0.0):
            return result, saddles, 1
        middle = 0.5 * (packing.phi + phi)
        first, s1, n1 = advance(packing, p_start, middle, depth + 1, index)
        p_mid = measure(first.packing, model).pressure
        second, s2, n2 = advance(first.packing, p_mid, phi, depth + 1, index)
        spent = result.iterations + first.iterations, result.evaluations + first.evaluations
        return (
            replace(
                second,
                iterations=spent[0] + second.iterations,
                evaluations=spent[1] + second.evaluations,
            ),
            s1 + s2,  # the discarded one-shot relaxation's saddles are not in the result
            n1 + n2,
        )

    current, p_prev = jammed, start.pressure
    first = 0
    if resume:
        if [s.index for s in resume] != list(range(len(resume))) or len(resume) > targets.size:
            raise InputError("resume: steps must be this run's steps 0, 1, ... in order")
        current, p_prev, first = resume[-1].packing, resume[-1].pressure, len(resume)
    for index in range(first, targets.size):
        dphi = float(targets[index])
        t0 = time.perf_counter()
        phi = phi_ref + dphi
        if phi < phi0 - 1e-12:
            raise InputError(
                f"delta_phis: phi_c + {dphi:g} is below the jammed packing's phi {phi0:.9g}"
            )
        result, saddles, substeps = advance(current, p_prev, phi, 0, index)
        current = result.packing
        obs = measure(current, model)
        moduli = linear_response(current, model)
        n_live = obs.n - obs.n_rattlers
        events = []
        if is_unjammed(obs, result.gtol, rtol):
            events.append("unjammed")
        if obs.pressure < p_prev and p_prev > 0.0 and "unjammed" not in events:
            events.append("pressure drop")
        if saddles:
            events.append("saddle left")
        if moduli.shear < 0.0:
            events.append("unstable to shear")
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
            saddles=saddles,
            substeps=substeps,
            events=tuple(events),
            iterations=result.iterations,
            evaluations=result.evaluations,
            seconds=time.perf_counter() - t0,
            packing=current,
        )
        p_prev = obs.pressure


def is_unjammed(obs: Observables, gtol: float, rtol: float = RTOL) -> bool:
    """Whether a packing measured as ``obs`` and relaxed to ``max_i |grad_i| <= gtol`` (``rtol``
    of its starting forces, floored) bears no load: no pressure, every particle a rattler, or a
    mean contact force within ``min(UNJAMMED_FORCE, UNJAMMED_DROP / rtol) x gtol``."""
    factor = min(UNJAMMED_FORCE, UNJAMMED_DROP / rtol)
    return not (
        obs.pressure > 0.0 and obs.n_rattlers < obs.n and obs.mean_contact_force > factor * gtol
    )


def fitted_value(column: str, value: float, events: Collection[str]) -> float:
    """The value of a compression step's ``column`` (a :meth:`CompressionStep.row` key) that the
    scaling fits use: an unjammed step's pressure counts as zero, whatever its round-off contacts
    leave (measured: 6e-15 with one contact of N = 48 on an AMD EPYC, exactly 0 on an Intel Xeon
    for the same step), so that only jammed steps enter a fit of ``p``."""
    return 0.0 if column == "pressure" and "unjammed" in events else value


def pooled_fit(
    rows: Iterable[Mapping[str, Any]], column: str, lower: float = FIT_LOWER
) -> PowerLaw:
    """``column`` against ``delta_phi`` fitted over ``rows`` (:meth:`CompressionStep.row`
    dicts, of any number of compressions pooled), each value as :func:`fitted_value` takes it,
    from ``lower`` up; raises :class:`~athermal.errors.InputError` with fewer than 3 points."""
    rows = list(rows)
    values = [
        fitted_value(column, float(row[column]), str(row["events"]).split(";")) for row in rows
    ]
    return fit_power_law([float(row["delta_phi"]) for row in rows], values, lower=lower)


@dataclass(frozen=True)
class ScalingExponents:
    """Power laws fitted to a compression: ``p``, ``G`` and ``z - z_iso`` against the
    protocol's ``Delta phi``; ``None`` where fewer than 3 usable points fell in the window.

    ``phi_c`` is the protocol's jamming point, the one the fits use. ``phi_c_fitted`` is a
    diagnostic: the jamming point of ``p = a (phi - phi_c)^b`` with ``phi_c`` free (NaN with
    fewer than 4 points); a value far from ``phi_c`` says the start was not at its jamming
    point. ``events`` counts the steps with each event (:data:`EVENTS`).
    """

    pressure: PowerLaw | None
    shear_modulus: PowerLaw | None
    z_excess: PowerLaw | None
    phi_c: float
    phi_c_fitted: float
    events: dict[str, int]


def scaling_exponents(
    steps: Sequence[CompressionStep],
    *,
    lower: float = FIT_LOWER,
    upper: float = np.inf,
) -> ScalingExponents:
    """Fit the three power laws to ``steps`` against their ``Delta phi`` within
    ``[lower, upper]``.

    Each fit uses the steps with a positive value in the window (a step unstable to shear has
    ``G < 0``; an unjammed one counts no pressure, its round-off contacts aside, and has
    ``z - z_iso < 0``); the fit records how many points and which ``Delta phi`` range it used.
    """
    dphi = np.array([s.delta_phi for s in steps])
    phi_c = float(steps[0].phi - steps[0].delta_phi) if steps else np.nan

    def fit(values: list[float]) -> PowerLaw | None:
        try:
            return fit_power_law(dphi, values, lower=lower, upper=upper)
        except InputError:
            return None

    pressures = [fitted_value("pressure", s.pressure, s.events) for s in steps]
    try:
        phi_c_fitted = fit_jamming_point([s.phi for s in steps], pressures)[0]
    except InputError:
        phi_c_fitted = np.nan
    return ScalingExponents(
        pressure=fit(pressures),
        shear_modulus=fit([s.shear_modulus for s in steps]),
        z_excess=fit([s.z_excess for s in steps]),
        phi_c=phi_c,
        phi_c_fitted=float(phi_c_fitted),
        events={name: sum(name in s.events for s in steps) for name in EVENTS},
    )
