"""The engine seam: a third engine, defined here alone (scipy's L-BFGS-B over the objective),
registered by name, runs ``relax`` and ``jam`` end to end, on the command line too; what it has
not is refused by its capabilities before any work."""

import json

import numpy as np
import pytest
import scipy.optimize

from athermal import ContactModel, engines, jam, random_packing, relax
from athermal.errors import InputError
from athermal.minimize import Status
from athermal.minimize.result import Tracker
from athermal.relaxation import Minimizer, Relaxer


class ScipySession:
    """scipy's L-BFGS-B (m = 10) on one objective, stopped by the objective's own norm, and a
    plain FIRE in numpy: where scipy's line search gives up (energy differences at round-off,
    near a minimum) the relaxer hands over to FIRE, which needs none."""

    def __init__(self, objective):
        self.objective = objective

    @property
    def n_rebuilds(self):
        return self.objective.n_rebuilds

    def minimize(self, method, x, *, gtol, etol, maxiter, precon=None):
        assert precon is None
        tracker = Tracker.start(self.objective, f"{method} (scipy)", None, gtol, maxiter, etol)
        energy, grad = self.objective(x)
        if tracker.record(energy, grad):
            return tracker.finish(x, Status.CONVERGED, "converged")
        x, stopped = (self._lbfgs if method == "lbfgs" else self._fire)(x, grad, tracker)
        if stopped:
            return tracker.finish(x, Status.CONVERGED, "converged")
        if tracker.iterations >= maxiter:
            return tracker.finish(x, Status.ITERATION_LIMIT, "iteration limit")
        return tracker.finish(x, Status.LINE_SEARCH_FAILED, "scipy's line search stopped")

    def _lbfgs(self, x, grad, tracker):
        last = {"x": x.copy()}

        def fun(point):
            energy, grad = self.objective(point)
            last.update(x=point.copy(), energy=energy, grad=grad)
            return energy, grad

        def callback(intermediate_result):
            if not np.array_equal(intermediate_result.x, last["x"]):
                fun(intermediate_result.x)
            if tracker.record(last["energy"], last["grad"]):
                last["stopped"] = True
            if last.get("stopped") or tracker.iterations >= tracker.maxiter:
                raise StopIteration

        options = {"maxcor": 10, "maxiter": tracker.maxiter, "ftol": 0.0, "gtol": 0.0}
        scipy.optimize.minimize(
            fun, x, jac=True, method="L-BFGS-B", callback=callback, options=options
        )
        return last["x"], last.get("stopped", False)

    def _fire(self, x, grad, tracker):
        """FIRE (Bitzek et al. 2006), unit masses, semi-implicit Euler."""
        dt_max = 1.0 / np.sqrt(self.objective.curvature_bound(x))
        dt, mix, positive = 0.5 * dt_max, 0.1, 0
        v = np.zeros_like(x)
        while tracker.iterations < tracker.maxiter:
            force = -grad
            if force @ v > 0.0:
                v = (1 - mix) * v + mix * np.linalg.norm(v) / np.linalg.norm(force) * force
                positive += 1
                if positive > 5:
                    dt, mix = min(1.1 * dt, dt_max), 0.99 * mix
            else:
                x, v, dt, mix, positive = x - 0.5 * dt * v, 0.0 * v, 0.5 * dt, 0.1, 0
            v = v + dt * force
            x = x + dt * v
            energy, grad = self.objective(x)
            if tracker.record(energy, grad):
                return x, True
        return x, False


class ScipyEngine(engines.Engine):
    name = "scipy"
    label = "scipy and numpy"
    capabilities = engines.Capabilities(methods=("lbfgs", "fire"))

    def bind(self, objective, precon, *, A, solver):
        return ScipySession(objective)


@pytest.fixture
def scipy_engine():
    engines.register("scipy", ScipyEngine)
    yield Minimizer("lbfgs", backend="scipy")
    engines.unregister("scipy")


def test_a_third_engine_relaxes_a_packing(scipy_engine):
    """From a small perturbation of a minimum both engines reach that minimum."""
    model = ContactModel(2.0)
    minimum = relax(random_packing(64, 0.88, seed=1), model).packing
    shake = np.random.default_rng(3).uniform(-1e-4, 1e-4, minimum.positions.shape)
    start = minimum.with_positions(minimum.positions + shake * minimum.radii.mean())
    result = relax(start, model, scipy_engine)
    assert result.converged and result.max_gradient <= result.gtol
    # scipy's line search stops at round-off near the minimum: the relaxer hands over to FIRE
    assert result.method == "lbfgs (scipy)+fire" and "FIRE after" in result.message
    assert scipy_engine.label == "lbfgs/scipy" and scipy_engine.name == "L-BFGS (scipy)"
    ours = relax(start, model, Minimizer("lbfgs"))
    assert result.energy == pytest.approx(ours.energy, rel=1e-6)


def test_a_third_engine_jams_a_packing_that_passes_the_checks(scipy_engine):
    result = jam(random_packing(32, 0.8, seed=2), ContactModel(2.0), minimizer=scipy_engine)
    assert result.check.passed
    assert 0.78 < result.phi_c < 0.88


def test_a_third_engine_on_the_command_line(scipy_engine, tmp_path, capsys):
    from athermal.cli import main

    out = tmp_path / "j.gsd"
    argv = ["jam", "--n", "32", "--seed", "2", "-o", str(out), "--json", "--quiet"]
    assert main([*argv, "--backend", "scipy", "--method", "lbfgs", "--precon", "none"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["checks_passed"] and report["method"] == "lbfgs/scipy"


def test_what_the_third_engine_has_not_is_refused_by_its_capabilities(scipy_engine, tmp_path):
    with pytest.raises(
        InputError, match="backend scipy: scipy and numpy runs lbfgs, fire with precon none; got cg"
    ):
        Minimizer("cg", backend="scipy")
    with pytest.raises(InputError, match="got lbfgs with exp"):
        Minimizer("plbfgs", backend="scipy")
    with pytest.raises(InputError, match="no walls yet; relax packings between walls with "):
        engines.check("scipy", walls=True)
    with pytest.raises(InputError, match="runs no batches; run them with --backend jax"):
        engines.check("scipy", batch=True)
    with pytest.raises(InputError, match="--deterministic: only with --backend jax"):
        engines.check("scipy", deterministic=True)
    frozen = np.zeros(64, dtype=bool)
    frozen[:4] = True
    from athermal.model.objective import Objective

    objective = Objective(random_packing(64, 0.88, seed=1), ContactModel(2.0), frozen=frozen)
    with pytest.raises(InputError, match="holds no particle fixed"):
        Relaxer(objective, scipy_engine)


def test_the_registry_refuses_an_unknown_or_a_second_engine_of_one_name(scipy_engine):
    with pytest.raises(InputError, match="backend: 'hoomd' is not one of 'numba', 'jax', 'scipy'"):
        Minimizer(backend="hoomd")
    with pytest.raises(InputError, match="registered already"):
        engines.register("scipy", ScipyEngine)
    with pytest.raises(InputError, match="the default engine stays"):
        engines.unregister("numba")


class LbfgsOnly(ScipyEngine):
    name = "scipy-lbfgs"
    capabilities = engines.Capabilities(methods=("lbfgs",))


def test_an_engine_without_fire_gets_no_hand_over_to_it(scipy_engine):
    """The relaxer hands a failed line search to FIRE only on an engine that runs FIRE."""
    from athermal.model.objective import Objective

    engines.register("scipy-lbfgs", LbfgsOnly)
    try:
        objective = Objective(random_packing(64, 0.88, seed=1), ContactModel(2.0))
        alone = Relaxer(objective, Minimizer(backend="scipy-lbfgs")).attempt(objective.x0, gtol=0.0)
        assert alone.status is Status.LINE_SEARCH_FAILED and alone.method == "lbfgs (scipy)"
        both = Relaxer(objective, scipy_engine).attempt(objective.x0, gtol=0.0, maxiter=2000)
        assert both.method == "lbfgs (scipy)+fire"
    finally:
        engines.unregister("scipy-lbfgs")
