"""FIRE 2.0 (athermal.minimize.fire): steps worked by hand, fake objectives, a small packing."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from athermal import ContactModel, InputError, find_contacts, random_packing
from athermal.minimize import Hooks, MinimizeResult
from athermal.minimize.fire import default_timesteps, fire
from athermal.model.objective import Objective

Function = Callable[[NDArray[np.float64]], tuple[float, NDArray[np.float64]]]


class FakeObjective:
    """The interface of :class:`~athermal.model.objective.Objective` around a plain function.

    Records every point it evaluates; caches the last one like the real objective.
    """

    def __init__(self, x0: NDArray[np.float64], dim: int, function: Function) -> None:
        self.x0 = np.asarray(x0, dtype=np.float64)
        self.dim = dim
        self.n = self.x0.size // dim
        self.n_dof = self.x0.size
        self.max_step = 0.1  # FIRE's default cap: an Objective's is 0.1 x the mean radius
        self.function = function
        self.hooks = Hooks(block=dim, max_step=self.max_step)
        self.n_evaluations = 0
        self.points: list[NDArray[np.float64]] = []
        self._last: tuple[NDArray[np.float64], tuple[float, NDArray[np.float64]]] | None = None

    def compiled_search(self) -> None:
        return None  # evaluated from Python

    def __call__(self, x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        if self._last is not None and np.array_equal(x, self._last[0]):
            return self._last[1]
        self.n_evaluations += 1
        self.points.append(x.copy())
        value = self.function(x)
        self._last = (x.copy(), value)
        return value


def quadratic(stiffness: NDArray[np.float64], center: NDArray[np.float64]) -> Function:
    """``E = sum_i a_i (x_i - c_i)^2 / 2``."""

    def function(x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        dx = x - center
        return 0.5 * float(dx @ (stiffness * dx)), stiffness * dx

    return function


def rosenbrock(x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """Chained Rosenbrock ``sum_i 100 (x_{i+1} - x_i^2)^2 + (1 - x_i)^2``; minimum 0 at all ones."""
    a = x[1:] - x[:-1] ** 2
    b = 1.0 - x[:-1]
    grad = np.zeros_like(x)
    grad[:-1] += -400.0 * a * x[:-1] - 2.0 * b
    grad[1:] += 200.0 * a
    return float(np.sum(100.0 * a * a + b * b)), grad


class DiagonalPrecon:
    """``P = diag(p)``; counts its updates."""

    name = "diagonal"

    def __init__(self, diagonal: NDArray[np.float64]) -> None:
        self.diagonal = diagonal
        self.n_builds = 0
        self.n_solves = 0
        self.n_updates = 0

    def compiled_solver(self) -> None:
        return None

    def update(self, x: NDArray[np.float64]) -> None:
        self.n_updates += 1

    def solve(self, g: NDArray[np.float64]) -> NDArray[np.float64]:
        return g / self.diagonal

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        return v * self.diagonal


def packing_objective(phi: float = 0.88, stiffness: float = 1.0) -> Objective:
    return Objective(random_packing(64, phi, seed=1), ContactModel(2.0, stiffness))


# --- the algorithm, step by step ------------------------------------------------------------


def test_first_steps_by_hand_downhill() -> None:
    # one particle in 1D, E = a x^2 / 2, small dt: both steps go downhill
    a, x0, dt, alpha = 2.0, 1.0, 0.1, 0.25
    obj = FakeObjective(np.array([x0]), 1, quadratic(np.array([a]), np.zeros(1)))
    fire(obj, obj.x0, gtol=1e-300, maxiter=2, dt=dt, dt_max=1.0, alpha_start=alpha, max_step=10.0)
    # step 1: v = 0 so P = 0 (uphill branch, inside the initial delay: dt and alpha kept)
    v1 = dt * (-a * x0)  # mixing toward F leaves a velocity parallel to F unchanged
    x1 = x0 + dt * v1
    # step 2: P = F(x1) v1 > 0, n_positive = 1 <= n_delay: dt and alpha kept
    f1 = -a * x1
    v2 = v1 + dt * f1
    v2 = (1 - alpha) * v2 + alpha * abs(v2) * np.sign(f1)
    x2 = x1 + dt * v2
    np.testing.assert_allclose(np.ravel(obj.points), [x0, x1, x2], rtol=1e-15)


def test_uphill_step_shrinks_dt_and_steps_half_back() -> None:
    # a dt so large that step 1 overshoots the minimum; the initial delay covers step 1 only
    a, x0, dt = 3.0, 1.0, 1.0
    obj = FakeObjective(np.array([x0]), 1, quadratic(np.array([a]), np.zeros(1)))
    fire(
        obj, obj.x0, gtol=1e-300, maxiter=2, dt=dt, dt_max=1.0, n_delay=2, f_dec=0.5, max_step=10.0
    )
    v1 = dt * (-a * x0)
    x1 = x0 + dt * v1  # = -2: overshoot, so F(x1) v1 < 0
    assert (-a * x1) * v1 < 0
    dt2 = 0.5 * dt
    x_back = x1 - 0.5 * dt2 * v1  # half step back with the shrunk dt, then v = 0
    x2 = x_back + dt2 * (dt2 * (-a * x1))  # restart from rest with the force at x1
    np.testing.assert_allclose(np.ravel(obj.points), [x0, x1, x2], rtol=1e-15)


def test_dt_min_is_a_floor() -> None:
    a, x0 = 3.0, 1.0
    obj = FakeObjective(np.array([x0]), 1, quadratic(np.array([a]), np.zeros(1)))
    # dt * f_dec < dt_min: dt is kept at 1 on the uphill step
    fire(
        obj,
        obj.x0,
        gtol=1e-300,
        maxiter=2,
        dt=1.0,
        dt_max=1.0,
        dt_min=0.9,
        n_delay=2,
        max_step=10.0,
    )
    x1 = x0 - a * x0
    x2 = x1 - 0.5 * (-a * x0) + (-a * x1)
    np.testing.assert_allclose(np.ravel(obj.points), [x0, x1, x2], rtol=1e-15)


def test_max_step_caps_every_displacement() -> None:
    stiffness = np.full(40, 1e4)
    obj = FakeObjective(np.full(40, 5.0), 2, quadratic(stiffness, np.zeros(40)))
    max_step = 0.05
    result = fire(obj, obj.x0, gtol=1e-8, dt=0.001, dt_max=0.01, max_step=max_step, maxiter=2000)
    assert result.converged
    steps = np.diff(np.array(obj.points), axis=0).reshape(len(obj.points) - 1, obj.n, 2)
    largest = np.sqrt((steps**2).sum(axis=2)).max(axis=1)
    # dt v is capped at max_step; a half step back (0.5 dt_new v_old, at most max_step / 4)
    # may come before it
    assert largest.max() <= 1.25 * max_step * (1 + 1e-12)
    assert largest[0] == pytest.approx(max_step, rel=1e-12)  # the first step hits the cap


def reference_fire(
    function: Function,
    x0: NDArray[np.float64],
    p: NDArray[np.float64],
    steps: int,
    dt: float,
    dt_max: float,
    dt_min: float,
    n_delay: int,
    f_inc: float,
    f_dec: float,
    alpha_start: float,
    f_alpha: float,
) -> list[NDArray[np.float64]]:
    """Guénolé et al. (2020) Algorithm 2 line by line, preconditioned by ``diag(p)``.

    Returns every evaluated point. No displacement cap (tests give a large ``max_step``).
    """
    x, v, alpha = x0.copy(), np.zeros_like(x0), alpha_start
    n_pos = 0
    points = [x.copy()]
    for i in range(1, steps + 1):
        force = -function(points[-1])[1]
        if float(np.dot(force, v)) > 0:
            n_pos += 1
            if n_pos > n_delay:
                dt, alpha = min(dt * f_inc, dt_max), alpha * f_alpha
        else:
            n_pos = 0
            if not i < n_delay:
                if dt * f_dec >= dt_min:
                    dt *= f_dec
                alpha = alpha_start
            x = x - 0.5 * dt * v
            v = np.zeros_like(v)
        f_p = force / p
        v = v + dt * f_p
        v = (1 - alpha) * v + alpha * np.linalg.norm(v) * f_p / np.linalg.norm(f_p)
        x = x + dt * v
        points.append(x.copy())
    return points


@pytest.mark.parametrize("preconditioned", [False, True])
def test_matches_the_published_algorithm(preconditioned: bool) -> None:
    # a coupled 2-particle quadratic in 2D, steps long enough to see dt grow, alpha decay, dt
    # shrink on uphill steps (dt_max above the stability limit) and the dt_min floor
    rng = np.random.default_rng(7)
    m = rng.standard_normal((4, 4))
    hess = m @ m.T + 0.1 * np.eye(4)
    center = rng.standard_normal(4)

    def function(x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        g = hess @ (x - center)
        return 0.5 * float((x - center) @ g), g

    p = np.array([1.0, 3.0, 0.5, 2.0]) if preconditioned else np.ones(4)
    options: dict[str, Any] = {
        "dt": 0.05, "dt_max": 1.5, "dt_min": 0.01, "n_delay": 3, "f_inc": 1.2, "f_dec": 0.5,
        "alpha_start": 0.3, "f_alpha": 0.9,
    }  # fmt: skip
    obj = FakeObjective(rng.standard_normal(4), 2, function)
    precon = DiagonalPrecon(p) if preconditioned else None
    fire(obj, obj.x0, gtol=1e-300, maxiter=120, precon=precon, max_step=1e6, **options)
    expected = reference_fire(function, obj.x0, p, 120, **options)
    np.testing.assert_allclose(np.array(obj.points), np.array(expected), rtol=1e-9, atol=1e-12)


# --- reaching minima ------------------------------------------------------------------------


def test_convex_quadratic() -> None:
    rng = np.random.default_rng(3)
    stiffness = np.logspace(-3, 0, 200)
    center = rng.standard_normal(200)
    obj = FakeObjective(rng.standard_normal(200), 2, quadratic(stiffness, center))
    result = fire(obj, obj.x0, gtol=1e-10, dt=0.1, dt_max=1.0)
    assert result.converged
    assert result.max_gradient <= 1e-10
    np.testing.assert_allclose(result.x, center, atol=1e-10 / 1e-3 * 1.01)
    assert result.evaluations == result.iterations + 1


def test_preconditioned_quadratic_is_faster_and_updates_every_step() -> None:
    rng = np.random.default_rng(4)
    stiffness = np.logspace(-4, 0, 200)
    x0 = rng.standard_normal(200)
    plain = fire(
        FakeObjective(x0, 2, quadratic(stiffness, np.zeros(200))), x0, gtol=1e-8, dt=0.1, dt_max=1.0
    )
    precon = DiagonalPrecon(stiffness + 1e-3)
    result = fire(
        FakeObjective(x0, 2, quadratic(stiffness, np.zeros(200))), x0, gtol=1e-8, precon=precon
    )
    assert result.converged and plain.converged
    assert result.precon == "diagonal"
    assert precon.n_updates == result.iterations
    assert result.iterations < plain.iterations / 3


def test_non_convex_rosenbrock() -> None:
    obj = FakeObjective(np.tile([-1.2, 1.0], 10), 2, rosenbrock)
    result = fire(obj, obj.x0, gtol=1e-8, dt=2e-3, dt_max=2e-2, max_step=0.1)
    assert result.converged
    np.testing.assert_allclose(result.x, 1.0, atol=1e-7)
    assert result.energy < 1e-14


# --- packings -------------------------------------------------------------------------------


def relax_fire(obj: Objective, maxiter: int = 100_000) -> MinimizeResult:
    """FIRE on ``obj`` to 1e-8 of the mean contact force, with its default time steps."""
    return fire(
        obj,
        obj.x0,
        gtol=obj.tolerance(None, 1e-8),
        maxiter=maxiter,
        curvature=obj.curvature_bound(obj.x0),
    )


def test_relaxes_overlapped_packing() -> None:
    obj = packing_objective()
    f0 = obj.mean_contact_force(obj.x0)
    result = relax_fire(obj)
    assert result.converged, result.message
    assert result.method == "fire" and result.precon == "none"
    assert result.gtol == pytest.approx(1e-8 * f0, rel=1e-15)
    assert result.max_gradient <= result.gtol
    assert obj.max_gradient(obj(result.x)[1]) <= result.gtol
    energies = result.history_energy
    assert energies[-1] < 1e-2 * energies[0]
    # overall descent: no iterate more than a whisker below where it ends (a local minimum)
    assert energies.min() >= energies[-1] * (1 - 1e-6)
    assert energies.size == result.history_max_gradient.size == result.iterations + 1
    # one evaluation per step, plus the start
    assert result.evaluations == result.iterations + 1 == obj.n_evaluations
    # measured 626 (default dt_max = 1.6 / sqrt(16) = 0.4 here); pinned from above
    assert result.iterations <= 690


def test_unjammed_packing_reaches_zero_energy_quickly() -> None:
    obj = packing_objective(phi=0.5)
    result = relax_fire(obj)
    assert result.converged
    assert result.energy == 0.0 or result.max_gradient <= result.gtol
    assert result.iterations <= 115  # measured 103


def test_iteration_limit_is_reported_not_raised() -> None:
    obj = packing_objective()
    result = relax_fire(obj, maxiter=5)
    assert not result.converged
    assert "iteration limit" in result.message
    assert result.iterations == 5
    assert result.history_energy.size == result.history_max_gradient.size == 6
    assert result.evaluations == 6


def test_maxiter_zero_evaluates_once() -> None:
    obj = packing_objective()
    result = relax_fire(obj, maxiter=0)
    assert not result.converged and result.iterations == 0 and result.evaluations == 1
    np.testing.assert_array_equal(result.x, obj.x0)


def test_deterministic() -> None:
    first = relax_fire(packing_objective())
    second = relax_fire(packing_objective())
    assert first.iterations == second.iterations
    np.testing.assert_array_equal(first.x, second.x)
    np.testing.assert_array_equal(first.history_energy, second.history_energy)


def test_stiffer_contacts_same_path_in_rescaled_time() -> None:
    # E -> 4 E halves the default time step: the same iterates, energies x 4
    soft = relax_fire(packing_objective())
    stiff = relax_fire(packing_objective(stiffness=4.0))
    assert stiff.iterations == soft.iterations
    np.testing.assert_allclose(stiff.x, soft.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(stiff.history_energy, 4.0 * soft.history_energy, rtol=1e-9)


# --- defaults and inputs --------------------------------------------------------------------


def test_curvature_bound_is_twice_largest_contact_count_for_hooke() -> None:
    obj = packing_objective(stiffness=2.5)
    contacts = find_contacts(obj.packing(obj.x0, internal=True), obj.model)
    z = np.bincount(contacts.i, minlength=obj.n) + np.bincount(contacts.j, minlength=obj.n)
    assert obj.curvature_bound(obj.x0) == pytest.approx(2.0 * 2.5 * z.max(), rel=1e-12)


def test_curvature_bound_bounds_the_hessian() -> None:
    from scipy.linalg import eigvalsh

    from athermal import hessian

    for alpha in (2.0, 2.5):
        obj = Objective(random_packing(64, 0.88, seed=2), ContactModel(alpha))
        contacts = find_contacts(obj.packing(obj.x0, internal=True), obj.model)
        largest = eigvalsh(hessian(contacts, obj.n).toarray())[-1]
        assert largest <= obj.curvature_bound(obj.x0)


def test_default_timesteps() -> None:
    obj = packing_objective()
    bound = obj.curvature_bound(obj.x0)
    dt, dt_max, dt_min = default_timesteps(None, None, None, None, bound)
    assert dt_max == pytest.approx(1.6 / np.sqrt(obj.curvature_bound(obj.x0)))
    assert dt == pytest.approx(0.1 * dt_max) and dt_min == pytest.approx(0.02 * dt)
    precon = DiagonalPrecon(np.ones(obj.n_dof))
    assert default_timesteps(precon, None, None, None, bound) == pytest.approx((0.025, 0.25, 5e-4))
    # a large dt alone raises the default dt_max to it
    assert default_timesteps(None, 2.0, None, None, bound)[:2] == (2.0, 2.0)
    with pytest.raises(InputError, match="curvature"):  # nothing to derive dt_max from
        default_timesteps(None, None, None, None, None)


@pytest.mark.parametrize(
    "options",
    [
        {"gtol": -1.0},  # both/neither of gtol and rtol: Objective.tolerance (test_minimize)
        {"gtol": float("nan")},
        {"gtol": 1e-8, "dt": 0.5, "dt_max": 0.1},
        {"gtol": 1e-8, "dt": -0.1},
        {"gtol": 1e-8, "f_dec": 1.0},
        {"gtol": 1e-8, "f_inc": 0.9},
        {"gtol": 1e-8, "alpha_start": 1.5},
        {"gtol": 1e-8, "f_alpha": 0.0},
        {"gtol": 1e-8, "n_delay": -1},
        {"gtol": 1e-8, "max_step": 0.0},
        {"gtol": 1e-8, "maxiter": -1},
    ],
)
def test_bad_options_are_rejected(options: dict[str, Any]) -> None:
    with pytest.raises(InputError):
        obj = packing_objective()
        fire(obj, obj.x0, curvature=obj.curvature_bound(obj.x0), **options)


def test_non_finite_step_stops_cleanly() -> None:
    obj = FakeObjective(np.ones(4), 2, quadratic(np.ones(4), np.zeros(4)))
    broken = DiagonalPrecon(np.zeros(4))  # P^-1 g = inf
    with np.errstate(divide="ignore", invalid="ignore"):
        result = fire(obj, obj.x0, gtol=1e-8, precon=broken, dt=0.1)
    assert not result.converged
    assert "non-finite" in result.message
    assert np.all(np.isfinite(result.x)) and result.iterations == 0
