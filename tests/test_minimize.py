import importlib

import numpy as np
import pytest

from athermal.errors import InputError
from athermal.minimize import Function, Hooks, Status
from athermal.minimize._step import advance
from athermal.minimize.cg import cg
from athermal.minimize.lbfgs import lbfgs
from athermal.minimize.newton import newton
from athermal.model.cell import Cell
from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.model.packing import Packing, random_packing
from athermal.relaxation import minimize_objective


def two_component(fun, x0):
    """A smooth test function on two-component blocks, each move capped at 1 per iteration
    (only the relative round-off of the line search)."""
    return Function(fun, np.size(x0), Hooks(block=2, max_step=1.0))


def quadratic(x):
    h = np.arange(1.0, x.size + 1.0)
    return 0.5 * float(h @ (x - 1.0) ** 2), h * (x - 1.0)


def unit_quadratic(x):
    return 0.5 * float((x - 1.0) @ (x - 1.0)), x - 1.0


def rosenbrock(x):
    a, b = x[:-1], x[1:]
    f = float(np.sum(100.0 * (b - a * a) ** 2 + (1.0 - a) ** 2))
    g = np.zeros_like(x)
    g[:-1] = -400.0 * a * (b - a * a) - 2.0 * (1.0 - a)
    g[1:] += 200.0 * (b - a * a)
    return f, g


class Identity:
    name, n_builds, n_solves = "identity", 0, 0

    def compiled_solver(self):
        return None

    def update(self, x):
        pass

    def solve(self, g):
        return g.copy()

    def dot(self, v):
        return v.copy()


@pytest.mark.parametrize("method", ["lbfgs", "cg-fr", "cg-pr+"])
@pytest.mark.parametrize(("fun", "limit"), [(quadratic, 300), (rosenbrock, 3000)])
def test_methods_reach_the_known_minimum(method, fun, limit):
    start = np.full(10, -1.2)
    obj = two_component(fun, start)
    if method == "lbfgs":
        res = lbfgs(obj, start, gtol=1e-9, maxiter=limit)
    else:
        res = cg(obj, start, gtol=1e-9, maxiter=limit * 3, variant=method[3:])
    assert res.converged, res.message
    np.testing.assert_allclose(res.x, 1.0, atol=1e-7)
    assert res.max_gradient <= 1e-9
    assert res.history_energy.size == res.iterations + 1


def test_lbfgs_with_identity_preconditioner_equals_plain_lbfgs_when_b0_is_identity():
    """On a function with unit Hessian the paper's scaling s.y / y.y is exactly 1, so the two
    runs take the same steps, to round-off: their arithmetic runs through different code (one
    CI run, the second pass on the native CPU, ended 1 ulp apart in 3 of 12 coordinates; the
    cause of that one run was not found, so bits are not asserted)."""
    start = np.linspace(-2.0, 3.0, 12)
    plain = lbfgs(two_component(unit_quadratic, start), start, gtol=1e-12)
    pre = lbfgs(two_component(unit_quadratic, start), start, gtol=1e-12, precon=Identity())
    assert plain.iterations == pre.iterations
    eps = np.finfo(np.float64).eps
    np.testing.assert_allclose(plain.x, pre.x, rtol=0.0, atol=8 * eps)
    scale = abs(plain.history_energy[0])
    np.testing.assert_allclose(
        plain.history_energy, pre.history_energy, rtol=64 * eps, atol=64 * eps * scale
    )


def overlapped(seed=1, n=128, phi=0.88):
    return random_packing(n, phi, seed=seed)


# Iteration counts measured on these seeded problems; they may only go down.
PINNED = {"lbfgs": 585, "cg": 675, "fire": 1140}


@pytest.mark.parametrize("method", ["lbfgs", "cg", "fire"])
def test_small_packings_relax_to_a_tight_tolerance(method):
    obj = Objective(overlapped(), ContactModel(2.0))
    e0, _ = obj(obj.x0)
    res = minimize_objective(obj, method, rtol=1e-9)
    assert res.converged, res.message
    assert res.max_gradient <= res.gtol
    assert res.energy < e0
    assert res.iterations <= PINNED[method]
    # the returned packing is in the caller's order and at the final state
    again = Objective(res.packing, ContactModel(2.0))
    e_final, g_final = again(again.x0)
    assert e_final == pytest.approx(res.energy, rel=1e-10)
    assert again.max_gradient(g_final) == pytest.approx(res.max_gradient, rel=1e-6)


def test_hertzian_packing_and_three_dimensions():
    for packing, model in [
        (overlapped(seed=2), ContactModel(2.5)),
        (random_packing(96, 0.7, dim=3, seed=3), ContactModel(2.0)),
    ]:
        res = minimize_objective(Objective(packing, model), "lbfgs", rtol=1e-9)
        assert res.converged, res.message


def test_unjammed_packing_ends_with_zero_energy():
    obj = Objective(random_packing(128, 0.5, seed=4), ContactModel(2.0))
    res = minimize_objective(obj, "lbfgs", rtol=1e-9)
    assert res.converged and res.energy == 0.0
    done = minimize_objective(Objective(res.packing, ContactModel(2.0)), "lbfgs", gtol=1e-12)
    assert done.converged and done.iterations == 0 and done.evaluations == 1


@pytest.mark.parametrize("method", ["lbfgs", "cg", "fire"])
def test_energy_tolerance_ends_the_run_at_the_first_iterate_below_it(method):
    obj = Objective(random_packing(128, 0.5, seed=4), ContactModel(2.0))
    res = minimize_objective(obj, method, gtol=0.0, etol=1e-12)
    assert res.converged and res.energy <= 1e-12
    assert np.all(res.history_energy[:-1] > 1e-12)
    with pytest.raises(InputError, match="etol"):
        minimize_objective(obj, method, gtol=0.0, etol=-1.0)


def test_non_convergence_is_reported_not_raised():
    obj = Objective(overlapped(), ContactModel(2.0))
    res = minimize_objective(obj, "lbfgs", rtol=1e-12, maxiter=3)
    assert not res.converged and "limit" in res.message and res.iterations == 3


def test_runs_are_reproducible():
    a = minimize_objective(Objective(overlapped(), ContactModel(2.0)), "lbfgs", rtol=1e-9)
    b = minimize_objective(Objective(overlapped(), ContactModel(2.0)), "lbfgs", rtol=1e-9)
    np.testing.assert_array_equal(a.x, b.x)
    assert a.iterations == b.iterations


def test_option_errors_name_the_choices():
    obj = Objective(overlapped(), ContactModel(2.0))
    with pytest.raises(InputError, match="'lbfgs'"):
        minimize_objective(obj, "bfgs", rtol=1e-9)
    with pytest.raises(InputError, match="precon"):
        minimize_objective(obj, "lbfgs", precon="jacobi", rtol=1e-9)
    with pytest.raises(InputError, match="exactly one"):
        minimize_objective(obj, "lbfgs")


def test_two_disks_relax_to_touching():
    p = Packing(np.array([[0.0, 0.0], [0.15, 0.0]]), np.array([0.1, 0.1]), Cell.box([1.0, 1.0]))
    res = minimize_objective(Objective(p, ContactModel(2.0)), "lbfgs", gtol=1e-14)
    assert res.converged
    sep = p.cell.minimum_image(res.packing.positions[0] - res.packing.positions[1])
    assert np.linalg.norm(sep) >= 0.2 - 1e-12


@pytest.mark.parametrize("seed", [1, 2])
def test_preconditioners_cut_iterations_on_a_compressed_relaxed_packing(seed):
    """The paper's Case 1 in small: a relaxed packing with radii grown by 5e-5."""
    relaxed = minimize_objective(
        Objective(random_packing(256, 0.86, seed=seed), ContactModel(2.0)), "lbfgs", rtol=1e-12
    ).packing
    start = relaxed.scale_radii(1.0 + 5e-5)
    iterations = {
        pre: minimize_objective(Objective(start, ContactModel(2.0)), "lbfgs", precon=pre, rtol=1e-9)
        for pre in ("none", "exp", "contact")
    }
    assert all(res.converged for res in iterations.values())
    plain = iterations["none"].iterations
    assert iterations["exp"].iterations < plain
    assert iterations["contact"].iterations < plain
    # measured (none / exp / contact) 369 / 222 / 128 (seed 1) and 345 / 251 / 127 (seed 2),
    # with 1.03-1.07 evaluations per iteration; exp on seed 1 is 243 on an Intel Xeon and 278
    # with numba compiling for a generic x86-64 (other rounding, another trajectory)
    assert iterations["exp"].iterations <= 300 and iterations["contact"].iterations <= 150
    for pre in ("exp", "contact"):  # the scaled H0 = gamma P^-1: the unit step is accepted
        assert iterations[pre].evaluations <= 1.1 * iterations[pre].iterations
    assert iterations["exp"].precon_builds >= 1
    # "auto" factors the Exp matrix incompletely (IC(0)) and keeps the gain: measured 267 and
    # 247 iterations against the exact factor's 243 and 251 (Intel Xeon)
    direct = minimize_objective(
        Objective(start, ContactModel(2.0)), "lbfgs", precon="exp", solver="direct", rtol=1e-9
    )
    assert direct.converged and direct.iterations <= 300
    assert iterations["exp"].iterations <= 1.3 * direct.iterations


def test_status_says_why_a_run_stopped():
    obj = Objective(overlapped(), ContactModel(2.0))
    assert minimize_objective(obj, "lbfgs", rtol=1e-9).status is Status.CONVERGED
    limited = minimize_objective(obj, "cg", rtol=1e-12, maxiter=3)
    assert limited.status is Status.ITERATION_LIMIT and not limited.converged
    assert minimize_objective(obj, "fire", rtol=1e-12, maxiter=3).status is Status.ITERATION_LIMIT


def test_explicit_start_is_where_the_run_begins_and_x0_is_left_alone():
    obj = Objective(overlapped(), ContactModel(2.0))
    first = minimize_objective(obj, "lbfgs", rtol=1e-6)
    before = obj.x0.copy()
    again = minimize_objective(obj, "lbfgs", x0=first.x, gtol=first.gtol)
    assert again.iterations == 0 and again.evaluations <= 1
    np.testing.assert_array_equal(obj.x0, before)
    with pytest.raises(InputError, match="x0"):
        minimize_objective(obj, "lbfgs", x0=first.x[:-1], rtol=1e-9)


def test_step_limit_caps_the_largest_particle_move():
    obj = Objective(overlapped(), ContactModel(2.0))
    direction = np.zeros(obj.n_dof)
    direction[4:6] = [3.0, 4.0]  # particle 2 moves 5 per unit step
    assert obj.hooks.step_limit(direction) == pytest.approx(obj.max_step / 5.0)
    assert obj.max_step == pytest.approx(0.1 * obj.radii.mean())
    assert obj.hooks.step_limit(np.zeros(obj.n_dof)) == np.inf


def two_loop_reference(grad, pairs, precon_solve):
    """Nocedal & Wright Algorithm 7.4 with H0 = gamma P^-1, gamma = s.y / y.P^-1 y (newest)."""
    q, alphas = grad.copy(), []
    for s, y in reversed(pairs):
        a = (s @ q) / (s @ y)
        alphas.append(a)
        q -= a * y
    s, y = pairs[-1]
    r = (s @ y) / (y @ precon_solve(y)) * precon_solve(q)
    for (s, y), a in zip(pairs, reversed(alphas), strict=True):
        r += (a - (y @ r) / (s @ y)) * s
    return -r


def test_compiled_compact_form_matches_the_textbook_two_loop_recursion():
    from athermal.minimize._memory import Memory

    rng = np.random.default_rng(5)
    n, diag = 40, np.linspace(1.0, 5.0, 40)
    solve = lambda v: v / diag  # noqa: E731  # a diagonal P
    memory = Memory(4, n, Identity())
    pairs = []
    for _ in range(6):  # more pairs than the memory: the ring drops the oldest
        s = rng.standard_normal(n)
        y = diag * s + 0.1 * rng.standard_normal(n)
        zero = np.zeros(n)  # a step from 0 to s with gradients 0 -> y
        memory.store(zero, s, zero, y, zero, solve(y))
        pairs = [*pairs[-3:], (s, y)]
    grad = rng.standard_normal(n)
    np.testing.assert_allclose(
        memory.direction(grad, solve(grad)), two_loop_reference(grad, pairs, solve), rtol=1e-12
    )


class Rebuilding:
    """A diagonal P whose entries change at every 5th update (a rebuild)."""

    name = "rebuilding"

    def __init__(self, n):
        self.n_builds, self.n_solves, self.updates, self.diag = 0, 0, 0, np.ones(n)

    def compiled_solver(self):
        return None

    def update(self, x):
        if self.updates % 5 == 0:
            self.n_builds += 1
            self.diag = np.linspace(0.5, 2.0, x.size) * (1.0 + 0.3 * (self.n_builds % 3))
        self.updates += 1

    def solve(self, g):
        return g / self.diag

    def dot(self, v):
        return v * self.diag


def test_pairs_are_refreshed_when_the_preconditioner_is_rebuilt():
    from athermal.minimize._memory import Memory

    start = np.linspace(-2.0, 3.0, 40)
    res = lbfgs(two_component(quadratic, start), start, gtol=1e-10, precon=Rebuilding(40))
    assert res.converged and res.precon_builds > 3
    memory, pre = Memory(3, 40, Rebuilding(40)), Rebuilding(40)
    rng = np.random.default_rng(2)
    for _ in range(3):
        s = rng.standard_normal(40)
        zero = np.zeros(40)
        memory.store(zero, s, zero, 2.0 * s, zero, 2.0 * s)  # a stale P^-1 y = y
    pre.update(start)
    memory.refresh(pre)
    for slot in memory.slots:
        np.testing.assert_allclose(memory.py[slot], pre.solve(memory.y[slot]), rtol=1e-15)
        ypy = memory.y[slot] @ memory.py[slot]
        assert memory.gamma[slot] == pytest.approx((memory.s[slot] @ memory.y[slot]) / ypy)
    pairs = [(memory.s[slot], memory.y[slot]) for slot in memory.slots]
    grad = rng.standard_normal(40)
    np.testing.assert_allclose(
        memory.direction(grad, pre.solve(grad)),
        two_loop_reference(grad, pairs, pre.solve),
        rtol=1e-12,
    )


class PythonOnly:
    """An objective without its compiled energy: the minimizers' generic (Python) search."""

    def __init__(self, objective):
        self._objective = objective

    def __getattr__(self, name):
        return getattr(self._objective, name)

    def compiled_search(self):
        return None

    def __call__(self, x):
        return self._objective(x)


@pytest.mark.parametrize(("alpha", "dim"), [(2.0, 2), (2.5, 2), (2.0, 3)])
@pytest.mark.parametrize("scale", [1e-3, 1.0, 30.0])
def test_compiled_line_search_takes_the_python_search_s_step(alpha, dim, scale):
    """The same search from the same point, compiled and in Python: the same trial steps and
    result up to the round-off of the energy sum; ``scale`` 30 sends the trial points beyond
    the Verlet skin, so the compiled search hands them to the objective, which rebuilds."""
    packing = random_packing(96, 0.88 if dim == 2 else 0.7, dim=dim, seed=7)
    model = ContactModel(alpha)
    compiled, plain = Objective(packing, model), Objective(packing, model)
    x = compiled.x0
    energy, grad = compiled(x)
    direction = -scale * grad / compiled.max_gradient(grad) * compiled.max_step
    rebuilds = compiled.n_rebuilds
    fast = advance(compiled, x, energy, grad, direction, 1.0, 0.9)
    slow = advance(PythonOnly(plain), x, *plain(x), direction, 1.0, 0.9)
    assert fast[0].ok and slow[0].ok
    assert fast[0].step == slow[0].step
    assert fast[0].evaluations == slow[0].evaluations
    assert compiled.n_evaluations == plain.n_evaluations
    np.testing.assert_array_equal(fast[1], slow[1])
    assert fast[2] == pytest.approx(slow[2], rel=1e-13)
    np.testing.assert_allclose(fast[3], slow[3], rtol=0.0, atol=1e-13 * np.abs(slow[3]).max())
    if scale == 30.0:
        assert compiled.n_rebuilds > rebuilds  # a trial point left the skin
    # the accepted point is the objective's cached evaluation
    evaluations = compiled.n_evaluations
    again = compiled(fast[1])
    assert compiled.n_evaluations == evaluations
    assert again[0] == fast[2]
    np.testing.assert_array_equal(again[1], fast[3])
    assert compiled.count_contacts(fast[1]) == Objective(packing, model).count_contacts(fast[1])


def test_a_compiled_search_out_of_reach_leaves_the_last_point_it_evaluated():
    """A search that extrapolates beyond the Verlet list's reach stops at the first trial point
    out of reach, after evaluations, with ``trial`` and its gradient those of the last point it
    evaluated (the one the objective takes back as its cached evaluation)."""
    from athermal.minimize import _wolfe
    from athermal.minimize.linesearch import C1, EPS
    from athermal.model.objective import energy_search

    objective = Objective(random_packing(96, 0.88, seed=7), ContactModel(2.0))
    x = objective.x0
    energy, grad = objective(x)
    arguments = objective.search_arguments(x)
    reach = float(np.sqrt(arguments[-1]))
    direction = -0.2 * reach * grad / objective.max_gradient(grad)  # a first step in reach
    state = np.empty(_wolfe.STATE_SIZE)
    code = _wolfe.begin(state, energy, grad @ direction, 1.0, C1, 0.9, np.inf, EPS, 0.0, 30)
    trial, trial_grad = np.empty_like(x), np.empty_like(x)
    code, evaluations, last, _, stale = energy_search(
        state, code, x, direction, trial, trial_grad, arguments
    )
    assert stale and evaluations >= 1 and code == _wolfe.GO_ON
    moves = (state[_wolfe.TRIAL] * direction).reshape(-1, 2)
    assert np.linalg.norm(moves, axis=1).max() > reach  # the trial point it stopped at
    fresh = Objective(random_packing(96, 0.88, seed=7), ContactModel(2.0))
    again = fresh(trial)
    assert again[0] == last
    np.testing.assert_array_equal(again[1], trial_grad)


@pytest.mark.parametrize("method", ["lbfgs", "cg", "newton"])
def test_minimizers_converge_alike_through_either_search(method):
    """Whole relaxations: the compiled and the Python search end at the same minimum."""
    model = ContactModel(2.0)
    out = []
    for wrap in (lambda obj: obj, PythonOnly):
        obj = Objective(overlapped(seed=3), model)
        run = {"lbfgs": lbfgs, "cg": cg, "newton": newton}[method]
        res = run(wrap(obj), obj.x0, gtol=1e-12)
        assert res.converged, res.message
        out.append(res)
    assert out[0].energy == pytest.approx(out[1].energy, rel=1e-9)
    assert abs(out[0].iterations - out[1].iterations) <= 0.2 * out[1].iterations


@pytest.mark.parametrize("method", ["lbfgs", "fr", "pr+"])
@pytest.mark.parametrize("precon", ["none", "exp"])
def test_compiled_iterations_hand_over_and_match_the_python_loop(method, precon, monkeypatch):
    """L-BFGS and CG (both variants) with whole iterations compiled against the Python loop
    (both searching in compiled code), on a relaxation whose Verlet list and Exp
    preconditioner are rebuilt along the way and whose compiled history fills up every 7
    iterates: the same iterations and minimum bit for bit (both form every product by the same
    compiled functions, and CG hands its slope ``g.p`` on instead of forming it again), every
    iterate in the history, and each point handed back to the objective as the last one
    evaluated has that energy and gradient."""
    from athermal.engines.precon import ExpPreconditioner

    compiled_module = importlib.import_module("athermal.minimize._compiled")

    model = ContactModel(2.0)
    monkeypatch.setattr(compiled_module, "HISTORY", 7)
    handed = []
    took = Objective.took
    fresh = Objective(overlapped(seed=4, phi=0.92), model)  # the same internal order

    def checked(self, x, energy, grad, contacts, evaluations):
        fresh_energy, fresh_grad = fresh(x.copy())
        handed.append(energy == pytest.approx(fresh_energy, rel=1e-12, abs=0.0))
        handed[-1] &= np.allclose(grad, fresh_grad, rtol=0.0, atol=1e-14)  # forces ~0.1
        took(self, x, energy, grad, contacts, evaluations)

    monkeypatch.setattr(Objective, "took", checked)
    out = []
    for compiled in (True, False):
        if not compiled:
            monkeypatch.setattr(
                compiled_module.CompiledLoop, "possible", staticmethod(lambda p, q: False)
            )
        obj = Objective(overlapped(seed=4, phi=0.92), model)
        pre = ExpPreconditioner(obj, solver="ic0") if precon == "exp" else None
        if method == "lbfgs":
            res = lbfgs(obj, obj.x0, gtol=1e-11, precon=pre)
        else:
            res = cg(obj, obj.x0, gtol=1e-11, precon=pre, variant=method)
        assert res.converged, res.message
        assert obj.n_rebuilds > 1
        if pre is not None:
            assert pre.n_builds > 1 and pre.n_solves >= res.iterations
        assert res.history_energy.size == res.iterations + 1
        history = res.history_energy  # non-increasing up to round-off
        assert np.all(np.diff(history) <= 1e-12 * history[:-1])
        assert res.max_gradient == res.history_max_gradient[-1] <= 1e-11
        energy, grad = obj(res.x)
        assert energy == res.energy and obj.max_gradient(grad) == res.max_gradient
        out.append(res)
    assert len(handed) > 20 and all(handed)
    assert out[0].iterations == out[1].iterations and out[0].energy == out[1].energy


@pytest.mark.parametrize("method", [lbfgs, cg])
def test_compiled_iterations_stop_at_the_iteration_limit(method):
    obj = Objective(overlapped(seed=4, phi=0.92), ContactModel(2.0))
    res = method(obj, obj.x0, gtol=1e-14, maxiter=23)
    assert res.status is Status.ITERATION_LIMIT and res.iterations == 23
    assert res.history_energy.size == 24


@pytest.mark.parametrize("method", ["lbfgs", "cg", "fire", "newton"])
def test_the_library_minimizes_a_plain_function(method):
    """Issue 36: the 100-dimensional Rosenbrock function, a plain callable, to gtol = 1e-10
    through the public call (FIRE given a bound on the Hessian's largest eigenvalue, 1802 at
    the minimum; Newton the Hessian)."""
    from scipy.optimize import rosen, rosen_der, rosen_hess

    from athermal.minimize import minimize as library

    result = library(
        lambda x: (rosen(x), rosen_der(x)),
        np.zeros(100),
        method=method,
        gtol=1e-10,
        hess=rosen_hess if method == "newton" else None,
        options={"curvature": 2500.0} if method == "fire" else None,
    )
    assert result.success and result.status is Status.CONVERGED, result.message
    assert np.abs(rosen_der(result.x)).max() <= 1e-10
    np.testing.assert_allclose(result.x, 1.0, atol=1e-8)
    assert result.fun == rosen(result.x) and result.nit == result.iterations
    np.testing.assert_array_equal(result.jac, rosen_der(result.x))
    assert result.nfev >= result.nit


def test_the_library_refuses_what_it_cannot_use():
    from athermal.minimize import minimize as library

    quadratic_ = lambda x: (0.5 * float(x @ x), x.copy())  # noqa: E731
    with pytest.raises(InputError, match="x0 is the start vector"):
        library(Objective(overlapped(), ContactModel(2.0)), "lbfgs")
    with pytest.raises(InputError, match="curvature"):
        library(quadratic_, np.ones(4), method="fire")
    with pytest.raises(InputError, match="hess"):
        library(quadratic_, np.ones(4), method="newton")
    with pytest.raises(InputError, match="block"):
        library(quadratic_, np.ones(5), hooks=Hooks(block=2))
    with pytest.raises(InputError, match="'lbfgs'"):
        library(quadratic_, np.ones(4), method="plbfgs")
    with pytest.raises(InputError, match="hess"):
        library(quadratic_, np.ones(4), method="lbfgs", hess=lambda x: np.eye(4))
    with pytest.raises(InputError, match="options"):
        library(quadratic_, np.ones(4), method="cg", options={"dt_max": 1.0})


def test_a_function_below_zero_is_minimized_not_stopped_at_zero():
    """The library's energy stop is off by default: a function that goes negative runs on to
    its gradient tolerance (the physics passes etol = 0 for a contact energy)."""
    from scipy.optimize import rosen, rosen_der

    from athermal.minimize import Problem
    from athermal.minimize import minimize as library

    result = library(lambda x: (rosen(x) - 0.5, rosen_der(x)), np.zeros(10), gtol=1e-10)
    assert result.success and result.max_gradient <= 1e-10
    assert result.fun == pytest.approx(-0.5, abs=1e-15)
    # telling a Problem from a plain callable builds nothing (no Verlet list, no compile)
    obj = Objective(overlapped(), ContactModel(2.0))
    assert isinstance(obj, Problem) and obj.n_rebuilds == 0


def test_only_the_exp_factor_is_solved_in_compiled_code():
    """An incomplete factor of the contact preconditioner (an N d system) is solved from
    Python; the Exp one (N rows, d columns) in the compiled loops."""
    from athermal.engines.precon import ContactPreconditioner, ExpPreconditioner

    obj = Objective(overlapped(), ContactModel(2.0))
    for kind, compiled in ((ContactPreconditioner, False), (ExpPreconditioner, True)):
        pre = kind(obj, solver="ic0")
        pre.update(obj.x0)
        assert (pre.compiled_solver() is not None) is compiled


def test_athermal_minimize_is_the_minimizer_package_and_refuses_an_objective():
    """The deprecated top-level function that shadowed the package is gone: ``athermal.minimize``
    is the package, whose ``minimize`` names the replacement for an objective."""
    import athermal
    import athermal.minimize as library

    assert athermal.minimize is library and callable(library.minimize)
    with pytest.raises(InputError, match="minimize_objective"):
        library.minimize(Objective(overlapped(), ContactModel(2.0)), "lbfgs")
