"""FIRE 2.0: the fast inertial relaxation engine, optionally preconditioned.

Damped dynamics of unit masses integrated by semi-implicit Euler, with the velocity steered toward
the force and the time step adapted to how long the motion has been going downhill (Bitzek et
al., Phys. Rev. Lett. 97, 170201 (2006)), in the corrected form of Guénolé et al., "Assessment
and optimization of the fast inertial relaxation engine (FIRE) for energy minimization in
atomistic simulations and its implementation in LAMMPS", Comput. Mater. Sci. 175, 109584 (2020),
Algorithm 2, with its "initial delay" and "half step back" options on. One step is::

    P = F . v
    if P > 0:   n_pos += 1;  if n_pos > n_delay: dt = min(f_inc dt, dt_max), a = f_alpha a
    else:       n_pos = 0
                if not (first n_delay steps): dt = f_dec dt (unless below dt_min), a = alpha_start
                x = x - dt v / 2;  v = 0
    v = v + dt F
    v = (1 - a) v + a |v| F / |F|
    x = x + dt v                      (dt v capped at max_step per particle)
    F = -grad E(x)                    (the one evaluation of the step)

Preconditioned variant (``precon`` given): the dynamics are ``P dv/dt = F`` (``P`` is the mass
matrix), i.e. ``F`` is replaced by ``F_p = -P^-1 grad E`` in the velocity update and in the
mixing (Euclidean norms). The uphill test keeps the true power ``F . v = -dE/dt``, which is the
rate of energy change whatever the metric, so a reset happens exactly when the motion climbs.
``precon.update(x)`` is called at every iterate before its solve.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .._validate import positive_scalar
from ..contact import find_contacts
from ..errors import InputError
from ..objective import Objective
from .result import MinimizeResult, Preconditioner, Tracker

#: Default largest time step, in units of ``1 / sqrt(lambda_G)`` (see :func:`curvature_bound`).
DT_MAX_FACTOR = 1.6
#: Default first time step, as a fraction of the largest (FIRE 2.0: dt_max = 10 dt).
DT_START_FRACTION = 0.1
#: Default smallest time step, as a multiple of the first one (FIRE 2.0: 0.02).
DT_MIN_FACTOR = 0.02
#: Default largest time step with a preconditioner (``P^-1 H`` has eigenvalues of order one).
DT_MAX_PRECON = 1.0
#: Default cap on one particle's displacement per step, as a multiple of the mean radius.
MAX_STEP_FACTOR = 0.1


def curvature_bound(objective: Objective, x: NDArray[np.float64]) -> float:
    """Gershgorin bound ``lambda_G >= lambda_max(H)`` on the Hessian of the contact energy at ``x``.

    A contact's Hessian block ``K_ij = c [(alpha - 1 + delta/l) n n^T - (delta/l) I]`` with
    ``c = k delta^(alpha-2)`` has norm ``(alpha - 1) c``, and row ``i`` of ``H`` holds
    ``H_ii = sum_j K_ij`` and ``H_ij = -K_ij``, so
    ``lambda_max <= lambda_G = 2 max_i sum_j (alpha - 1) k_ij delta_ij^(alpha - 2)``
    (``2 k z_max`` for Hooke contacts). Units ``k`` x length^(alpha-2), i.e. 1 / time^2 for unit
    masses. Without contacts it falls back to a particle with 6 (2D) or 12 (3D) contacts of
    overlap ``delta`` = the mean radius.
    """
    model = objective.model
    contacts = find_contacts(objective.packing(x, internal=True), model, objective.neighbor_list(x))
    alpha = float(model.alpha)
    if contacts.i.size == 0:
        z_ref = 6.0 if objective.dim == 2 else 12.0
        r_mean = float(np.mean(objective.radii))
        return 2.0 * z_ref * (alpha - 1.0) * float(np.max(model.kmat)) * r_mean ** (alpha - 2.0)
    stiff = (alpha - 1.0) * contacts.stiffness * contacts.overlap ** (alpha - 2.0)
    per_particle = np.bincount(contacts.i, stiff, objective.n)
    per_particle += np.bincount(contacts.j, stiff, objective.n)
    return 2.0 * float(per_particle.max())


def default_timesteps(
    objective: Objective,
    precon: Preconditioner | None,
    dt: float | None,
    dt_max: float | None,
    dt_min: float | None,
) -> tuple[float, float, float]:
    """``(dt, dt_max, dt_min)`` with the defaults filled in (see :func:`fire`), validated."""
    if dt_max is None:
        if precon is not None:
            dt_max = DT_MAX_PRECON
        else:
            dt_max = DT_MAX_FACTOR / np.sqrt(curvature_bound(objective, objective.x0))
        if dt is not None:
            dt_max = max(dt_max, positive_scalar(dt, "dt"))
    dt_max = positive_scalar(dt_max, "dt_max")
    dt = DT_START_FRACTION * dt_max if dt is None else positive_scalar(dt, "dt")
    dt_min = DT_MIN_FACTOR * dt if dt_min is None else positive_scalar(dt_min, "dt_min")
    if not dt_min <= dt <= dt_max:
        raise InputError(f"dt: need dt_min <= dt <= dt_max, got {dt_min!r}, {dt!r}, {dt_max!r}")
    return float(dt), float(dt_max), float(dt_min)


def fire(
    objective: Objective,
    *,
    gtol: float | None = None,
    rtol: float | None = None,
    maxiter: int = 100_000,
    precon: Preconditioner | None = None,
    dt: float | None = None,
    dt_max: float | None = None,
    dt_min: float | None = None,
    n_delay: int = 20,
    f_inc: float = 1.1,
    f_dec: float = 0.5,
    alpha_start: float = 0.25,
    f_alpha: float = 0.99,
    max_step: float | None = None,
) -> MinimizeResult:
    """Minimize ``objective`` from ``objective.x0`` by FIRE 2.0 (see the module docstring).

    Parameters
    ----------
    objective : energy and gradient of a flat ``(N d,)`` vector; unit masses.
    gtol : absolute tolerance on ``max_i |grad_i E|`` (force units ``k`` x length^(alpha-1)).
    rtol : tolerance relative to the mean contact force at ``x0``; give exactly one of the two.
        The run also stops, converged, when the energy is exactly zero (no overlaps).
    maxiter : the most steps (one energy+gradient evaluation each).
    precon : preconditioner; the dynamics then follow ``F_p = -P^-1 grad E``.
    dt_max : largest time step (time units ``sqrt(m / k)``, m = 1). Default
        ``1.6 / sqrt(lambda_G)`` with ``lambda_G`` the Gershgorin bound on the Hessian at ``x0``
        (:func:`curvature_bound`; ``2 k z_max`` for Hooke contacts, so about 0.4 for a 2D
        packing with ``k = 1``): semi-implicit Euler is stable for ``dt < 2 / sqrt(lambda_max)``,
        and FIRE ran fastest with ``dt_max`` near ``1 / sqrt(lambda_max)`` (``lambda_G`` is
        2-3.5 ``lambda_max`` in the packings measured) but stalled above
        ~``1.3 / sqrt(lambda_max)``.
        With a preconditioner the default is 1.0 (``P^-1 H`` has eigenvalues of order one).
        When only ``dt`` is given the default is raised to at least ``dt``.
    dt : first time step; default ``dt_max / 10`` (the FIRE 2.0 ratio).
    dt_min : the time step is not shrunk below it; default ``0.02 dt`` (FIRE 2.0).
    n_delay : steps downhill before the time step may grow (also the initial delay during which
        an uphill step does not shrink it).
    f_inc, f_dec : growth (> 1) and shrink (< 1) factors of the time step.
    alpha_start, f_alpha : initial mixing parameter and its decay factor per step downhill.
    max_step : largest displacement of one particle in one step (length units); default
        ``0.1 x`` the mean radius. A step that would move a particle further is scaled down,
        velocity included.

    Returns
    -------
    MinimizeResult with ``method="fire"``; ``converged=False`` and a message when ``maxiter``
    steps did not reach the tolerance or the energy became non-finite.

    Examples
    --------
    >>> from athermal import ContactModel, random_packing
    >>> from athermal.objective import Objective
    >>> obj = Objective(random_packing(64, 0.88, seed=1), ContactModel(2.0))
    >>> result = fire(obj, rtol=1e-8)
    >>> result.converged, result.evaluations == result.iterations + 1
    (True, True)
    """
    tracker = Tracker.start(objective, "fire", precon, gtol, rtol, maxiter)
    dt, dt_max, dt_min = default_timesteps(objective, precon, dt, dt_max, dt_min)
    if max_step is None:
        max_step = MAX_STEP_FACTOR * float(np.mean(objective.radii))
    max_step = positive_scalar(max_step, "max_step")
    if int(n_delay) != n_delay or n_delay < 0:
        raise InputError(f"n_delay: must be an integer >= 0, got {n_delay!r}")
    if not (np.isfinite(f_inc) and f_inc >= 1.0):
        raise InputError(f"f_inc: must be a finite number >= 1, got {f_inc!r}")
    if not 0.0 < f_dec < 1.0:
        raise InputError(f"f_dec: must be in (0, 1), got {f_dec!r}")
    if not 0.0 <= alpha_start <= 1.0:
        raise InputError(f"alpha_start: must be in [0, 1], got {alpha_start!r}")
    if not 0.0 < f_alpha <= 1.0:
        raise InputError(f"f_alpha: must be in (0, 1], got {f_alpha!r}")

    n, dim = objective.n, objective.dim
    x = np.array(objective.x0, dtype=np.float64, copy=True)
    energy, grad = objective(x)
    if tracker.record(energy, grad):
        return tracker.finish(x, True, "converged at the start")
    v = np.zeros_like(x)
    alpha = float(alpha_start)
    n_positive = 0
    max_step_sq = max_step * max_step

    for step in range(1, tracker.maxiter + 1):
        if not (np.isfinite(energy) and np.all(np.isfinite(grad))):
            return tracker.finish(x, False, "stopped: the energy or gradient is not finite")
        x_recorded = x
        force = -grad
        if precon is not None:
            precon.update(x)
            direction = -precon.solve(grad)
        else:
            direction = force

        if float(force @ v) > 0.0:
            n_positive += 1
            if n_positive > n_delay:
                dt = min(dt * f_inc, dt_max)
                alpha *= f_alpha
        else:
            n_positive = 0
            if step >= n_delay:
                if dt * f_dec >= dt_min:
                    dt *= f_dec
                alpha = float(alpha_start)
            x = x - 0.5 * dt * v
            v[:] = 0.0

        # semi-implicit Euler: velocity first (with the FIRE mixing), then positions
        v += dt * direction
        d_norm = float(np.sqrt(direction @ direction))
        if d_norm > 0.0:
            v_norm = float(np.sqrt(v @ v))
            v *= 1.0 - alpha
            v += (alpha * v_norm / d_norm) * direction
        largest_sq = float(np.max(np.einsum("ij,ij->i", s := v.reshape(n, dim), s))) * dt * dt
        if not np.isfinite(largest_sq):
            return tracker.finish(
                x_recorded,
                False,
                "stopped: non-finite step (is the preconditioner positive definite?)",
            )
        if largest_sq > max_step_sq:
            v *= max_step / np.sqrt(largest_sq)
        x = x + dt * v

        energy, grad = objective(x)
        if tracker.record(energy, grad):
            return tracker.finish(x, True, f"converged after {step} steps")

    return tracker.finish(x, False, f"iteration limit reached ({tracker.maxiter} steps)")
