"""The paper's finite-strain moduli: small quasi-static strain steps, each relaxed, and a fit.

"For each relaxed over-jammed configuration, we exert small shear strains from 1e-6 to 1e-5
quasi-statically, in 10 steps" (seed, section 4.2): the slope of the shear stress gives ``G``
and the minimizer's iterations per step are the paper's iteration experiment. The bulk modulus is
measured the same way under isotropic strain of the cell at fixed radii. Both agree with
:func:`~athermal.analysis.moduli.linear_response` (the fit removes the curvature's first order).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validate import choice, float_array
from ..analysis.moduli import nonaffine_displacement
from ..analysis.observables import pressure, shear_stress, stress
from ..errors import InputError
from ..model.cell import isotropic, simple_shear
from ..model.contact import ContactModel, Contacts, find_contacts
from ..model.objective import MAX_STEP_FACTOR, Objective
from ..model.packing import Packing
from ..relaxation import RTOL, Minimizer, Relaxer, force_tolerance

DEFAULT_STRAINS = np.linspace(1e-6, 1e-5, 10)
"""The paper's strains ``(10,)``: 1e-6 to 1e-5 in 10 quasi-static steps (read-only)."""
DEFAULT_STRAINS.setflags(write=False)
FIT_DEGREE = 3
"""Degree of the polynomial whose slope at zero strain is the modulus: a straight line's slope is
the chord's over the strains, which the stress's curvature biases; the cubic is the lowest degree
whose bias stays within ~2 of its own standard errors (``docs/decisions.md``, "Finite-strain
moduli")."""
StepStart = Literal["linear", "affine"]
STEP_STARTS: tuple[str, ...] = ("linear", "affine")
FINITE_STRAIN_MINIMIZER = Minimizer("newton")
"""Default minimizer of the finite-strain steps: truncated Newton (:mod:`athermal.minimize.newton`),
which near jamming takes tens of iterations per step where the L-BFGS family and FIRE take
thousands. A step still unconverged after :data:`~athermal.relaxation.NEWTON_PATIENCE`
iterations goes on with P-L-BFGS. Measurements: ``docs/decisions.md``, section "Finite-strain
moduli", ``FINITE_STRAIN_MINIMIZER``."""


@dataclass(frozen=True, eq=False)
class FiniteStrain:
    """A modulus fitted to quasi-static finite-strain steps.

    Attributes
    ----------
    modulus : ``G = d(-sigma_01)/d gamma`` (shear) or ``B = -(1/d) dp/de`` (bulk) at zero
        strain: the slope there of the least-squares cubic through the start and every step
        (scaled by ``-1/d`` for bulk).
    stderr : standard error of ``modulus`` from the fit residuals.
    strains : ``(k,)`` total strain after each step.
    stresses : ``(k,)`` shear stress ``-sigma_01`` (shear) or pressure (bulk) after each
        relaxation.
    iterations : ``(k,)`` minimizer iterations of each relaxation (the paper's iteration count).
    contacts : ``(k,)`` number of contacts after each relaxation.
    stress_initial : the stress of the input packing (strain 0).
    contacts_initial : number of contacts of the input packing.
    packing : the relaxed configuration at the last strain.
    """

    modulus: float
    stderr: float
    strains: NDArray[np.float64]
    stresses: NDArray[np.float64]
    iterations: NDArray[np.int64]
    contacts: NDArray[np.int64]
    stress_initial: float
    contacts_initial: int
    packing: Packing


def finite_strain_shear(
    packing: Packing,
    model: ContactModel,
    strains: ArrayLike = DEFAULT_STRAINS,
    *,
    minimizer: Minimizer | None = None,
    rtol: float = RTOL,
    start: StepStart = "linear",
) -> FiniteStrain:
    """Shear modulus ``G = d(-sigma_01)/d gamma`` from quasi-static simple shear ``x += gamma y``.

    Each step deforms the previous relaxed configuration by the simple shear increment that
    reaches the next strain (``Packing.deform``) and relaxes it on a fresh :class:`Objective`;
    ``G`` is the slope at ``gamma = 0`` of the least-squares cubic through the input (relaxed
    first, as every step) and every step (:data:`FIT_DEGREE`).

    Parameters
    ----------
    packing : a relaxed configuration (the fit assumes it is at a minimum).
    model : contact law.
    strains : ``(k,)`` total shear strains, ``k >= 2`` (a cubic from ``k = 3``), of one sign,
        strictly increasing in magnitude (default: the paper's 1e-6 to 1e-5 in 10 steps).
    minimizer : how each step is relaxed (default :data:`FINITE_STRAIN_MINIMIZER`, truncated
        Newton); its iteration limit is fatal (:class:`~athermal.errors.ConvergenceError`).
    rtol : tolerance relative to the mean contact force at the start of each relaxation,
        floored at round-off (:func:`~athermal.relaxation.round_off_floor`).
    start : where each relaxation starts: ``"affine"``, the deformed previous configuration
        (the paper's), or ``"linear"``, that moved by the linear-response displacement
        (:func:`~athermal.analysis.moduli.nonaffine_displacement`, one sparse solve with the
        previous minimum's Hessian) unless it moves a particle more than the minimizers' step cap.
        Near jamming the paper's step of 1e-6 opens a quarter of the contacts of a packing at
        ``Delta phi = 1e-7`` and the relaxation has to close them again; the linear start keeps
        them (``benchmarks/results/protocols/newton_diagnostics_n*.md``).
    """
    gammas = _check_strains(strains, lower=-np.inf)
    dim = packing.dim
    return _quasi_static(
        packing,
        model,
        gammas,
        lambda old, new: simple_shear(new - old, dim),
        lambda contacts, p: shear_stress(stress(contacts, p.cell)),
        1.0,
        minimizer or FINITE_STRAIN_MINIMIZER,
        rtol,
        start,
    )


def finite_strain_bulk(
    packing: Packing,
    model: ContactModel,
    strains: ArrayLike = -DEFAULT_STRAINS,
    *,
    minimizer: Minimizer | None = None,
    rtol: float = RTOL,
    start: StepStart = "linear",
) -> FiniteStrain:
    """Bulk modulus ``B = -(1/d) dp/de`` from quasi-static isotropic strain at fixed radii.

    Strain ``e`` is the cell map ``D = (1 + e) I`` (``e < 0`` compresses); each step applies
    ``(1 + e_new) / (1 + e_old) I`` to the previous relaxed configuration and relaxes it. ``B`` is
    ``-1/d`` times the slope at ``e = 0`` of the least-squares cubic of the pressure through the
    input and every step (:data:`FIT_DEGREE`): ``-V dp/dV``.

    Parameters
    ----------
    packing : a relaxed configuration (the fit assumes it is at a minimum).
    model : contact law.
    strains : ``(k,)`` total strains, ``k >= 2`` (a cubic from ``k = 3``), each > -1, of one
        sign, strictly increasing in magnitude (default: compression by 1e-6 to 1e-5 in 10
        steps).
    minimizer, rtol, start : as in :func:`finite_strain_shear`.
    """
    strain = _check_strains(strains, lower=-1.0)
    dim = packing.dim
    return _quasi_static(
        packing,
        model,
        strain,
        lambda old, new: isotropic((1.0 + new) / (1.0 + old), dim),
        lambda contacts, p: pressure(stress(contacts, p.cell)),
        -1.0 / dim,
        minimizer or FINITE_STRAIN_MINIMIZER,
        rtol,
        start,
    )


def _check_strains(strains: ArrayLike, lower: float) -> NDArray[np.float64]:
    """``strains`` as ``(k,)`` float64: k >= 2, finite, > ``lower``, one sign, increasing size."""
    values = float_array(strains, "strains", (None,))
    if values.size < 2:
        raise InputError(f"strains: need at least 2 for a fit with an error, got {values.size}")
    if np.any(values <= lower):
        raise InputError(f"strains: every strain must be > {lower}, got min {values.min()}")
    if np.any(values == 0.0) or not (np.all(values > 0.0) or np.all(values < 0.0)):
        raise InputError("strains: must be nonzero and all of one sign")
    if np.any(np.diff(np.abs(values)) <= 0.0):
        raise InputError("strains: magnitudes must be strictly increasing")
    return values


def _quasi_static(
    packing: Packing,
    model: ContactModel,
    strains: NDArray[np.float64],
    increment: Callable[[float, float], NDArray[np.float64]],
    observe: Callable[[Contacts, Packing], float],
    scale: float,
    minimizer: Minimizer,
    rtol: float,
    start: StepStart,
) -> FiniteStrain:
    """Step through ``strains``: deform by ``increment(old, new)``, relax, ``observe``; fit."""
    choice(start, "start", STEP_STARTS)
    # the strain-0 point relaxed as every step is: a start left at a looser tolerance would
    # release its residual forces in the first step, an offset the fit reads as strain response
    objective = Objective(packing, model)
    packing = (
        Relaxer(objective, minimizer)
        .relax(objective.x0, gtol=force_tolerance(packing, model, rtol), what="the start")
        .packing
    )
    contacts = find_contacts(packing, model)
    first = observe(contacts, packing)
    first_contacts = int(contacts.i.size)
    stresses = np.empty(strains.size)
    iterations = np.empty(strains.size, dtype=np.int64)
    counts = np.empty(strains.size, dtype=np.int64)
    current, old = packing, 0.0
    for step, new in enumerate(strains):
        deformation = increment(old, float(new))
        deformed = current.deform(deformation)
        if start == "linear":
            deformed = _linear_start(current, deformed, deformation, model)
        objective = Objective(deformed, model)
        gtol = force_tolerance(deformed, model, rtol)
        result = Relaxer(objective, minimizer).relax(
            objective.x0, gtol=gtol, what=f"finite strain step {step} (strain {new:g})"
        )
        current, old = result.packing, float(new)
        contacts = find_contacts(current, model)
        stresses[step] = observe(contacts, current)
        iterations[step] = result.iterations
        counts[step] = contacts.i.size
    slope, stderr = _fit_tangent(
        np.concatenate([[0.0], strains]), np.concatenate([[first], stresses])
    )
    return FiniteStrain(
        modulus=scale * slope,
        stderr=abs(scale) * stderr,
        strains=strains,
        stresses=stresses,
        iterations=iterations,
        contacts=counts,
        stress_initial=first,
        contacts_initial=first_contacts,
        packing=current,
    )


def _linear_start(
    relaxed: Packing, deformed: Packing, deformation: NDArray[np.float64], model: ContactModel
) -> Packing:
    """``deformed`` (= ``relaxed`` deformed affinely) moved by the linear-response displacement of
    ``deformation``; ``deformed`` itself when that displacement is not finite or moves a particle
    more than the minimizers' step cap (``MAX_STEP_FACTOR`` mean radii: the linear response is
    then no guide, as at an instability).

    Neither the energy nor the largest force tells a good prediction from a bad one: the affine
    step opens contacts and lowers both. Measurements (contacts kept, Newton iterations from
    either start): ``docs/decisions.md``, section "Finite-strain moduli", "The linear start".
    """
    d1 = deformation - np.eye(relaxed.dim)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a poor solve is caught below
        u = nonaffine_displacement(relaxed, model, d1)
    longest = float(np.sqrt(np.max(np.einsum("ij,ij->i", u, u)))) if u.size else 0.0
    if not np.isfinite(longest) or longest > MAX_STEP_FACTOR * float(np.mean(relaxed.radii)):
        return deformed
    return deformed.with_positions(deformed.positions + u)


def _fit_tangent(x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[float, float]:
    """The slope at ``x = 0`` of the least-squares polynomial through ``(n,)`` points, n >= 3,
    and its standard error: of degree :data:`FIT_DEGREE`, or ``n - 2`` where fewer points leave
    no residual to estimate the error from."""
    degree = min(FIT_DEGREE, x.size - 2)
    scale = float(np.max(np.abs(x)))
    t = x / scale  # the normal equations in O(1) numbers
    design = np.stack([t**k for k in range(degree + 1)], axis=1)
    gram = np.linalg.inv(design.T @ design)
    coef = gram @ (design.T @ y)
    resid = y - design @ coef
    variance = float(resid @ resid) / (x.size - degree - 1)
    return float(coef[1]) / scale, float(np.sqrt(variance * gram[1, 1])) / scale
