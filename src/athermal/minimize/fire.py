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
                if step >= n_delay (steps count from 1; the initial delay):
                    dt = f_dec dt unless that is below dt_min;  a = alpha_start
                x = x - dt v / 2;  v = 0      (half step back, with the new dt)
    v = v + dt F
    v = (1 - a) v + a |v| F / |F|
    x = x + dt v                      (dt v capped at max_step per block)
    F = -grad E(x)                    (the one evaluation of the step)

Preconditioned variant (``precon`` given): the dynamics are ``P dv/dt = F`` (``P`` is the mass
matrix), i.e. ``F`` is replaced by ``F_p = -P^-1 grad E`` in the velocity update and in the
mixing, with Euclidean norms. The uphill test keeps the true power ``F . v = -dE/dt``, the
rate of energy change whatever the metric, so a reset happens exactly when the motion climbs.
``precon.update(x)`` is called at every iterate before its solve. (A preconditioned FIRE came with
the Exp preconditioner of Packwood et al., J. Chem. Phys. 144, 164109 (2016); the choices above are
ours, in the FIRE 2.0 form.)

The loop runs in Python: compiled loops with the energy kernel inside were no faster per step.
Measurements (this, the norms of the preconditioned variant, :data:`DT_MAX_PRECON`):
``docs/decisions.md``, section "FIRE".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .._jit import _jit
from .._portable import vdot
from .._validate import positive_scalar
from ..errors import InputError
from .result import MinimizeResult, Preconditioner, Problem, Status, Tracker

#: Default largest time step, in units of ``1 / sqrt(curvature)``, ``curvature`` an upper bound
#: on the Hessian's largest eigenvalue (the physics: a Gershgorin bound).
DT_MAX_FACTOR = 1.6
#: Default first time step, as a fraction of the largest (FIRE 2.0: dt_max = 10 dt).
DT_START_FRACTION = 0.1
#: Default smallest time step, as a multiple of the first one (FIRE 2.0: 0.02).
DT_MIN_FACTOR = 0.02
#: Default largest time step with a preconditioner (time units ``sqrt(m / k)``): larger ones
#: stalled FIRE with the Exp and contact preconditioners (``docs/decisions.md``, section "FIRE").
DT_MAX_PRECON = 0.25
#: FIRE 2.0's defaults (Guénolé et al. 2020): the delay, the time step's growth and shrink
#: factors, the first mixing parameter and its decay per step downhill.
N_DELAY, F_INC, F_DEC, ALPHA_START, F_ALPHA = 20, 1.1, 0.5, 0.25, 0.99


def default_timesteps(
    precon: Preconditioner | None,
    dt: float | None,
    dt_max: float | None,
    dt_min: float | None,
    curvature: float | None = None,
) -> tuple[float, float, float]:
    """``(dt, dt_max, dt_min)`` with the defaults filled in (see :func:`fire`), validated.

    The default ``dt_max`` without a preconditioner is ``DT_MAX_FACTOR / sqrt(curvature)``."""
    if dt_max is None:
        if precon is not None:
            dt_max = DT_MAX_PRECON
        else:
            if curvature is None:
                raise InputError(
                    "dt_max: give FIRE's largest time step, or curvature (a bound on the "
                    "Hessian's largest eigenvalue) to derive it"
                )
            dt_max = DT_MAX_FACTOR / np.sqrt(positive_scalar(curvature, "curvature"))
        if dt is not None:
            dt_max = max(dt_max, positive_scalar(dt, "dt"))
    dt_max = positive_scalar(dt_max, "dt_max")
    dt = DT_START_FRACTION * dt_max if dt is None else positive_scalar(dt, "dt")
    dt_min = DT_MIN_FACTOR * dt if dt_min is None else positive_scalar(dt_min, "dt_min")
    if not dt_min <= dt <= dt_max:
        raise InputError(f"dt: need dt_min <= dt <= dt_max, got {dt_min!r}, {dt!r}, {dt_max!r}")
    return float(dt), float(dt_max), float(dt_min)


@_jit
def _move(
    x: NDArray[np.float64],
    v: NDArray[np.float64],
    slope: NDArray[np.float64],
    dt: float,
    alpha: float,
    max_step: float,
    dim: int,
) -> tuple[NDArray[np.float64], bool]:
    """One semi-implicit Euler step with the FIRE mixing, in three passes over the arrays.

    ``v += -dt slope``; ``v = (1 - alpha) v + alpha |v| (-slope) / |slope|``; ``v`` scaled so
    that no block of ``dim`` coordinates moves further than ``max_step``; returns ``(x + dt v,
    finite)``, with ``finite`` False (and ``x`` unchanged) when ``slope`` or ``v`` holds a NaN
    or infinity.
    ``v`` is updated in place.
    """
    m = x.size
    vv = 0.0
    ss = 0.0
    for p in range(m):
        v[p] -= dt * slope[p]
        vv += v[p] * v[p]
        ss += slope[p] * slope[p]
    if not (np.isfinite(vv) and np.isfinite(ss)):
        return x.copy(), False
    keep, toward = 1.0, 0.0
    if ss > 0.0:
        keep, toward = 1.0 - alpha, -alpha * np.sqrt(vv) / np.sqrt(ss)
    largest = 0.0
    for i in range(m // dim):
        norm_sq = 0.0
        for a in range(dim):
            k = i * dim + a
            w = keep * v[k] + toward * slope[k]
            v[k] = w
            norm_sq += w * w
        if norm_sq > largest:
            largest = norm_sq
    length = dt * np.sqrt(largest)
    if not np.isfinite(length):
        return x.copy(), False
    scale = max_step / length if length > max_step else 1.0
    out = np.empty_like(x)
    for p in range(m):
        v[p] *= scale
        out[p] = x[p] + dt * v[p]
    return out, True


def fire(
    problem: Problem,
    x0: NDArray[np.float64],
    *,
    gtol: float,
    maxiter: int = 100_000,
    etol: float = -np.inf,
    precon: Preconditioner | None = None,
    dt: float | None = None,
    dt_max: float | None = None,
    dt_min: float | None = None,
    n_delay: int = N_DELAY,
    f_inc: float = F_INC,
    f_dec: float = F_DEC,
    alpha_start: float = ALPHA_START,
    f_alpha: float = F_ALPHA,
    max_step: float | None = None,
    curvature: float | None = None,
) -> MinimizeResult:
    """Minimize ``problem`` from ``x0`` ``(n_dof,)`` by FIRE 2.0 (see the module docstring).

    Parameters
    ----------
    problem : energy and gradient of a flat vector; unit masses.
    x0 : the start.
    gtol : absolute tolerance on the largest block of the gradient
        (:meth:`~.hooks.Hooks.max_gradient`).
        The run also stops, converged, when the energy is ``<= etol``.
    etol : energy tolerance (absolute; default ``-inf``: no such stop).
    maxiter : the most steps (one energy+gradient evaluation each).
    precon : preconditioner; the dynamics then follow ``F_p = -P^-1 grad E``.
    dt_max : largest time step (time units, unit masses). Default ``1.6 / sqrt(curvature)``
        (``DT_MAX_FACTOR``): semi-implicit Euler is stable for ``dt < 2 / sqrt(lambda_max)``,
        and FIRE ran fastest with ``dt_max`` near ``1 / sqrt(lambda_max)`` but stalled above
        ~``1.3 / sqrt(lambda_max)`` (a packing's Gershgorin bound is 2-3.5 ``lambda_max``).
        With a preconditioner the default is 0.25 (``DT_MAX_PRECON``, measured).
        When only ``dt`` is given the default is raised to at least ``dt``.
    dt : first time step; default ``dt_max / 10`` (the FIRE 2.0 ratio).
    dt_min : the time step is not shrunk below it; default ``0.02 dt`` (FIRE 2.0).
    n_delay : steps downhill before the time step may grow; also the initial delay: on steps
        1 to ``n_delay - 1`` an uphill step does not shrink it (nor reset the mixing).
    f_inc, f_dec : growth (> 1) and shrink (< 1) factors of the time step.
    alpha_start, f_alpha : initial mixing parameter and its decay factor per step downhill.
    max_step : largest Euclidean move of one block of ``x`` in one step; default the
        problem's :attr:`~.hooks.Hooks.max_step`. A step that would move a block further is
        scaled down, velocity included.
    curvature : an upper bound on the Hessian's largest eigenvalue at ``x0``, for the default
        ``dt_max`` (the physics passes a Gershgorin bound: ``2 k z_max`` for Hooke contacts).

    Returns
    -------
    MinimizeResult with ``method="fire"``; status ``ITERATION_LIMIT`` when ``maxiter`` steps did
    not reach the tolerance, ``NOT_FINITE`` when the energy or a step became non-finite.

    Examples
    --------
    >>> import numpy as np
    >>> from athermal.minimize.function import Function
    >>> quadratic = Function(lambda x: (0.5 * x @ x, x.copy()), 3)
    >>> result = fire(quadratic, np.ones(3), gtol=1e-8, curvature=1.0)
    >>> result.converged, result.evaluations == result.iterations + 1
    (True, True)
    """
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
    if max_step is not None:
        max_step = positive_scalar(max_step, "max_step")
    tracker = Tracker.start(problem, "fire", precon, gtol, maxiter, etol)
    dt, dt_max, dt_min = default_timesteps(precon, dt, dt_max, dt_min, curvature)
    if max_step is None:
        max_step = problem.hooks.max_step
    dim = problem.hooks.block
    x = np.array(x0, dtype=np.float64, copy=True)
    energy, grad = problem(x)
    if tracker.record(energy, grad):
        return tracker.finish(x, Status.CONVERGED, "converged at the start")
    v = np.zeros_like(x)
    alpha = float(alpha_start)
    n_positive = 0

    for step in range(1, tracker.maxiter + 1):
        if not np.isfinite(energy):
            return tracker.finish(x, Status.NOT_FINITE, "stopped: the energy is not finite")
        x_recorded = x
        if precon is not None:
            precon.update(x)
            slope = precon.solve(grad)  # P^-1 grad: the direction is -slope
        else:
            slope = grad

        if vdot(grad, v) < 0.0:  # power F . v > 0: downhill
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

        x, finite = _move(x, v, slope, dt, alpha, max_step, dim)
        if not finite:
            hint = " (is the preconditioner positive definite?)" if precon is not None else ""
            return tracker.finish(
                x_recorded, Status.NOT_FINITE, f"stopped: non-finite gradient or step{hint}"
            )

        energy, grad = problem(x)
        if tracker.record(energy, grad):
            return tracker.finish(x, Status.CONVERGED, f"converged after {step} steps")

    return tracker.finish(
        x, Status.ITERATION_LIMIT, f"iteration limit reached ({tracker.maxiter} steps)"
    )
