"""Quasi-static compression above jamming: the paper's scaling-law experiment (section 4.2).

From a jammed packing at ``phi_c`` the radii are grown to ``phi_c + Delta phi`` for log-spaced
``Delta phi`` (1e-7 ... 1e-1 by default), each state relaxed from the previous one. Every step
reports pressure, energy, contacts, z with rattlers removed and its distance ``z - z_iso`` from
the isostatic value of the non-rattlers, and the bulk and shear moduli by exact linear response
(:func:`~athermal.analysis.moduli.linear_response`); :func:`scaling_exponents` fits the power laws
``p ~ Delta phi^(alpha-1)``, ``G ~ Delta phi^(alpha-3/2)``, ``z - z_iso ~ Delta phi^(1/2)``.

The bulk modulus reported is the paper's ``B = phi dp/dphi`` along this protocol (radii growing in
a fixed cell). Growing the radii is cell compression followed by a uniform rescaling of lengths,
under which stresses scale as ``length^(alpha-d)``, so ``B = B_cell + (alpha - d) p / d`` with
``B_cell = -V dp/dV`` the fixed-radii modulus of the linear response.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal, get_args

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._records import Value, as_row
from .._validate import float_array
from ..analysis.fitting import PowerLaw, fit_jamming_point, fit_power_law
from ..analysis.moduli import linear_response
from ..analysis.observables import Observables, isostatic_contacts, measure
from ..errors import InputError
from ..model.contact import ContactModel, find_contacts
from ..model.objective import Objective
from ..model.packing import Packing
from ..relaxation import RTOL, Minimizer, Relaxation, Relaxer, force_tolerance
from .jamming import EPSILON, overlap_distance

Event = Literal["unjammed", "pressure drop", "saddle left", "unstable to shear"]
EVENTS: tuple[Event, ...] = get_args(Event)
"""What a compression step reports when it happens (``CompressionStep.events``): no load borne
(:func:`is_unjammed`); a pressure below the previous step's; a saddle left along its negative
mode (:meth:`~athermal.relaxation.Relaxer.relax_to_minimum`); a minimum with a negative
linear-response shear modulus, unstable to shear at fixed cell (Dagois-Bohy et al., PRL 109,
095703 (2012): physical near jamming, where ``p N^2`` is small)."""
MAX_SPLITS = 4
"""A compression step whose pressure drops (or that unjams) is redone in halves, down to
``2^MAX_SPLITS`` substeps: a one-shot relaxation can jump out of a stable basin. A drop that
persists at the finest substep is an instability of the packing (reported). Measurements:
``docs/decisions.md``, section "Protocol constants"."""
UNJAMMED_FORCE = 1e3
"""A relaxed step counts as unjammed when its mean contact force is at most this many times the
force tolerance it was relaxed to: such forces are the residual the minimizer may leave, not a
load (the case that set it: ``docs/decisions.md``, section "Protocol constants")."""
UNJAMMED_DROP = 1e-3
"""With a loose ``rtol`` a jammed step's forces are only ``~1 / rtol`` times its tolerance, so the
factor :data:`UNJAMMED_FORCE` is capped at ``UNJAMMED_DROP / rtol``: an unjammed step's forces
must also have fallen this far below those it started from (``rtol`` = 1e-3: to the tolerance
itself)."""
FIT_LOWER = EPSILON
"""Smallest ``Delta phi`` fitted by default: the jamming protocol's default ``epsilon``, below
which ``Delta phi`` is not known to better than itself."""
RESOLVED_CONTACTS = 10
"""``z - z_iso`` is fitted only where the non-rattlers have at least this many contacts beyond
isostatic, ``N' (z - z_iso) / 2``: below, it counts a handful of contacts and its exponent is set
by their discreteness (``docs/jamming.md``)."""
FINITE_SIZE = 1.0
"""``p`` and ``G`` are fitted only where ``Delta phi N^2`` is at least this: closer to jamming a
packing of N particles leaves the scaling regime of the large system (Goodrich, Liu & Nagel,
PRL 109, 095704 (2012): the crossover at ``p N^2 ~ 1`` for harmonic disks, ``p ~ Delta phi``)."""
FIT_LAWS = ("pressure", "shear_modulus", "z_excess")
"""The columns :func:`scaling_exponents` fits against ``Delta phi``."""
FAR_ABOVE = 10.0
""":func:`compression_steps` refuses a start whose overlaps (:func:`overlap_distance`) put it
more than this many times ``max(phi - phi_c, first Delta phi)`` above its jamming point."""


def log_spaced(start: float = 1e-7, stop: float = 1e-1, per_decade: int = 4) -> NDArray[np.float64]:
    """``Delta phi`` values from ``start`` to ``stop``, ``per_decade`` per decade (both ends)."""
    count = log_count(start, stop, per_decade)
    return np.logspace(np.log10(start), np.log10(stop), count)


def log_count(start: float, stop: float, per_decade: int) -> int:
    """How many values :func:`log_spaced` gives; :class:`InputError` for a range or a density
    it cannot take."""
    if not 0.0 < start < stop:
        raise InputError(
            f"dphi_min: must lie in (0, {stop:g}), below the largest Delta phi, got {start:g}"
        )
    if int(per_decade) != per_decade or per_decade < 1:
        raise InputError(f"per_decade: must be an integer >= 1, got {per_decade!r}")
    return round(float(np.log10(stop / start)) * per_decade) + 1


def excess_z(obs: Observables, periodic: int) -> float:
    """``2 (C' - N_iso) / N'``: the contacts beyond isostatic per non-rattler, doubled, with
    ``N_iso = d N' - t + 1`` (``t = periodic`` axes); ``z - z_iso`` in a periodic cell, and
    with walls too (each wall contact counts one in ``z``, as in ``C'``); ``-2 d`` when every
    particle is a rattler."""
    n_live = obs.n - obs.n_rattlers
    if not n_live:
        return -2.0 * obs.dim
    return 2.0 * (obs.contacts_nonrattler - isostatic_contacts(n_live, obs.dim, periodic)) / n_live


def isostatic_z(n_live: int, dim: int) -> float:
    """Isostatic coordination of ``n_live`` non-rattlers in a periodic cell:
    ``2 N_c / N'`` with ``N_c = d (N' - 1) + 1`` contacts (tends to ``2 d``)."""
    return 2.0 * isostatic_contacts(n_live, dim) / n_live if n_live >= 1 else 0.0


@dataclass(frozen=True, eq=False)
class CompressionStep:
    """One relaxed state of the compression (units: ``k`` and the cell's lengths).

    ``bulk_modulus`` is ``phi dp/dphi`` along the protocol, ``shear_modulus`` the simple-shear
    ``G`` (between walls normal to x or y the pure-shear one,
    :func:`~athermal.analysis.moduli.linear_response`), both by linear response (negative for a
    minimum unstable to shear: the event ``unstable to shear``, and no modulus in the fits);
    ``z_excess`` :func:`excess_z`; ``events`` what happened
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
    events: tuple[Event, ...]
    iterations: int
    evaluations: int
    seconds: float
    packing: Packing

    def row(self) -> dict[str, Value]:
        """The step's numbers, for tables and checkpoints.

        No packing; the packing's ``n`` follows ``index``."""
        return as_row(self, after={"index": {"n": self.packing.n}})


def compression_steps(
    jammed: Packing,
    model: ContactModel,
    *,
    phi_c: float | None = None,
    delta_phis: ArrayLike | None = None,
    minimizer: Minimizer | None = None,
    rtol: float = RTOL,
    resume: Sequence[CompressionStep] = (),
    from_unjammed: bool = False,
) -> Iterator[CompressionStep]:
    """Compress ``jammed`` quasi-statically, yielding each relaxed step.

    Parameters
    ----------
    jammed : a packing at its jamming point (e.g. :func:`~athermal.protocols.jam`'s), the first
        start; refused (:class:`~athermal.errors.InputError`) when it has no energy, pressure
        or rigid backbone (every particle a rattler), or when its overlaps put it far above
        ``phi_c`` (:data:`FAR_ABOVE`: a random placement, or a relaxed packing far above the
        jamming point it names), unless ``from_unjammed``. Its forces need not balance: a
        packing jammed with one contact law may be compressed with another (the paper's alpha =
        2.5 from the same jamming point), and the first step relaxes it.
    model : contact law.
    phi_c : jamming fraction ``Delta phi`` is measured from; default ``jammed.phi``.
    delta_phis : increasing ``Delta phi > 0`` ``(k,)``; default :func:`log_spaced`.
    minimizer : how each step is relaxed (default L-BFGS).
    rtol : tolerance relative to the mean contact force at each step's start, floored at
        round-off (:func:`~athermal.relaxation.round_off_floor`). Every step is checked to
        be a local minimum; a saddle is left along its negative mode (``saddles``, ``events``).
    resume : the steps already done by an interrupted run with the same arguments; the run
        continues after the last one. Each step builds its objective from the previous step's
        packing alone, so the continued run matches an uninterrupted one bit for bit.
    from_unjammed : compress a start that is not a packing at its jamming point all the same,
        with a ``UserWarning`` that names what is wrong with it.
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
    problem = _not_at_jamming(jammed, model, start, phi_ref, float(targets[0]))
    if problem and not from_unjammed:
        raise InputError(
            f"jammed: the start packing is not jammed: {problem}; jam it first (athermal jam), "
            "or compress it all the same with from_unjammed (--from-unjammed)"
        )
    if problem:
        warnings.warn(
            f"compression: the start packing is not jammed: {problem}; Delta phi is not "
            "measured from its own jamming point",
            UserWarning,
            stacklevel=2,
        )
    config = minimizer or Minimizer()
    phi0 = jammed.phi

    def advance(
        packing: Packing, p_start: float, phi: float, depth: int, index: int
    ) -> tuple[Relaxation, int, int]:
        """Grow ``packing`` (pressure ``p_start``) to ``phi`` and relax; on a pressure drop or
        unjamming of a jammed start, redo it in two halves (to depth :data:`MAX_SPLITS`).
        Returns the last relaxation (iterations and evaluations summed over the substeps), the
        saddles left and the number of substeps."""
        grown = Packing(packing.positions, jammed.radii_at(phi), jammed.cell)
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
        events: list[Event] = []
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
            z_excess=excess_z(obs, jammed.cell.periodic_axes),
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


def _not_at_jamming(
    packing: Packing, model: ContactModel, obs: Observables, phi_c: float, first: float
) -> str:
    """What makes ``packing`` (measured as ``obs``) no packing at its jamming point ``phi_c``,
    for a compression whose first step is ``first``; empty when nothing does."""
    if not (obs.energy > 0.0 and obs.pressure > 0.0 and obs.n_rattlers < obs.n):
        return (
            f"E = {obs.energy:.3e}, p = {obs.pressure:.3e}, {obs.n_rattlers} of {obs.n} "
            "particles rattlers (no rigid backbone)"
        )
    above = overlap_distance(find_contacts(packing, model), packing)
    if above > FAR_ABOVE * max(packing.phi - phi_c, first):
        return (
            f"its overlaps are those of a packing ~{above:.1e} above its jamming point, but "
            f"phi - phi_c = {packing.phi - phi_c:.1e}"
        )
    return ""


def is_unjammed(obs: Observables, gtol: float, rtol: float = RTOL) -> bool:
    """Whether a packing measured as ``obs`` and relaxed to ``max_i |grad_i| <= gtol`` (``rtol``
    of its starting forces, floored) bears no load: no pressure, every particle a rattler, or a
    mean contact force within ``min(UNJAMMED_FORCE, UNJAMMED_DROP / rtol) x gtol``."""
    factor = min(UNJAMMED_FORCE, UNJAMMED_DROP / rtol)
    return not (
        obs.pressure > 0.0 and obs.n_rattlers < obs.n and obs.mean_contact_force > factor * gtol
    )


def left_out(row: Mapping[str, Any], column: str, lower: float, upper: float) -> str | None:
    """Why a compression step (its :meth:`CompressionStep.row`) is no point of the fit of
    ``column`` (one of :data:`FIT_LAWS`) over ``[lower, upper]``, or None when it is one.

    Left out: a ``Delta phi`` outside the window; an unjammed step (whatever pressure its
    round-off contacts leave); a negative ``G`` (unstable to shear); ``z - z_iso`` of fewer than
    :data:`RESOLVED_CONTACTS` contacts; ``p`` and ``G`` with ``Delta phi N^2`` below
    :data:`FINITE_SIZE`; a value that is not positive. A step with a pressure drop stays: the
    packing rearranged but bears its load, and its ``Delta phi`` is still measured from the
    jamming point it came from (the event says so).
    """
    if "n" not in row:
        raise InputError(
            "rows: a compression step without its particle count 'n' (written before the fits "
            "had finite-size rules): add the packing's N to each row"
        )
    dphi, value = float(row["delta_phi"]), float(row[column])
    events = str(row["events"]).split(";")
    if not lower <= dphi <= upper:
        return "outside the fitted range"
    if "unjammed" in events:
        return "unjammed"
    if column == "shear_modulus" and value < 0.0:
        return "unstable to shear (G < 0)"
    live = int(row["n"]) - int(row["n_rattlers"])
    if column == "z_excess" and live * value / 2.0 < RESOLVED_CONTACTS - 0.5:
        return f"fewer than {RESOLVED_CONTACTS} contacts beyond isostatic"
    if column != "z_excess" and dphi * int(row["n"]) ** 2 < FINITE_SIZE:
        return f"finite size (Delta phi N^2 < {FINITE_SIZE:g})"
    if not value > 0.0:
        return "not positive"
    return None


def fit_reasons(
    rows: Sequence[Mapping[str, Any]], column: str, lower: float = FIT_LOWER, upper: float = np.inf
) -> list[str | None]:
    """For each of one compression's ``rows`` (in order), why the fit of ``column`` leaves it
    out (:func:`left_out`), or None when it is a point of the fit. The steps after the first
    unjammed one are left out too: the packing has left the basin of the jamming point
    ``Delta phi`` is measured from."""
    reasons: list[str | None] = []
    left_basin = False
    for row in rows:
        reasons.append(
            "after the packing left its basin"
            if left_basin
            else left_out(row, column, lower, upper)
        )
        left_basin = left_basin or "unjammed" in str(row["events"]).split(";")
    return reasons


def fit_points(
    rows: Sequence[Mapping[str, Any]], column: str, lower: float = FIT_LOWER, upper: float = np.inf
) -> tuple[list[float], list[float], dict[str, int]]:
    """The points ``(Delta phi, value)`` of one compression's ``rows`` that the fit of
    ``column`` uses, and how many steps it left out for each reason (:func:`fit_reasons`)."""
    xs: list[float] = []
    ys: list[float] = []
    dropped: dict[str, int] = {}
    for row, reason in zip(rows, fit_reasons(rows, column, lower, upper), strict=True):
        if reason is None:
            xs.append(float(row["delta_phi"]))
            ys.append(float(row[column]))
        else:
            dropped[reason] = dropped.get(reason, 0) + 1
    return xs, ys, dropped


def pooled_fit(
    compressions: Iterable[Sequence[Mapping[str, Any]]], column: str, lower: float = FIT_LOWER
) -> PowerLaw:
    """``column`` against ``delta_phi`` fitted over the points of any number of compressions
    (each a sequence of :meth:`CompressionStep.row` dicts, in order), each taken as
    :func:`fit_points` takes it, from ``lower`` up; raises :class:`~athermal.errors.InputError`
    with fewer than 3 points."""
    xs: list[float] = []
    ys: list[float] = []
    for rows in compressions:
        x, y, _ = fit_points(rows, column, lower)
        xs += x
        ys += y
    return fit_power_law(xs, ys)


@dataclass(frozen=True)
class ScalingExponents:
    """Power laws fitted to a compression: ``p``, ``G`` and ``z - z_iso`` against the
    protocol's ``Delta phi``; ``None`` where fewer than 3 usable points fell in the window.

    ``phi_c`` is the protocol's jamming point, the one the fits use. ``phi_c_fitted`` is a
    diagnostic: the jamming point of ``p = a (phi - phi_c)^b`` with ``phi_c`` free, over the
    points of the fit of ``p`` (NaN with fewer than 4); a value far from ``phi_c`` says the start
    was not at its jamming point. ``events`` counts the steps with each event (:data:`EVENTS`);
    ``left_out`` says, for each law of :data:`FIT_LAWS`, how many steps were no point of its fit
    and why (:func:`fit_points`); ``left_basin`` is the ``Delta phi`` of the first unjammed step
    (None when the packing stayed jammed), after which no step is fitted.
    """

    pressure: PowerLaw | None
    shear_modulus: PowerLaw | None
    z_excess: PowerLaw | None
    phi_c: float
    phi_c_fitted: float
    events: dict[str, int]
    left_out: dict[str, dict[str, int]]
    left_basin: float | None


def scaling_exponents(
    steps: Sequence[CompressionStep],
    *,
    lower: float = FIT_LOWER,
    upper: float = np.inf,
) -> ScalingExponents:
    """Fit the three power laws to ``steps`` against their ``Delta phi`` within
    ``[lower, upper]``, each over the points :func:`fit_points` takes; each fit records how many
    points and which ``Delta phi`` range it used, and ``left_out`` the steps it did not use.
    """
    rows = [s.row() for s in steps]
    phi_c = float(steps[0].phi - steps[0].delta_phi) if steps else np.nan
    fits: dict[str, PowerLaw | None] = {}
    dropped: dict[str, dict[str, int]] = {}
    for column in FIT_LAWS:
        xs, ys, dropped[column] = fit_points(rows, column, lower, upper)
        try:
            fits[column] = fit_power_law(xs, ys)
        except InputError:
            fits[column] = None
        if column == "pressure":
            try:
                phi_c_fitted = fit_jamming_point([phi_c + x for x in xs], ys)[0]
            except InputError:
                phi_c_fitted = np.nan
    unjammed = [s.delta_phi for s in steps if "unjammed" in s.events]
    return ScalingExponents(
        pressure=fits["pressure"],
        shear_modulus=fits["shear_modulus"],
        z_excess=fits["z_excess"],
        phi_c=phi_c,
        phi_c_fitted=float(phi_c_fitted),
        events={name: sum(name in s.events for s in steps) for name in EVENTS},
        left_out=dropped,
        left_basin=unjammed[0] if unjammed else None,
    )
