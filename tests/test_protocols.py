import dataclasses
import itertools

import numpy as np
import pytest

from athermal.cell import pure_shear
from athermal.contact import ContactModel
from athermal.errors import InputError
from athermal.moduli import linear_response
from athermal.observables import measure
from athermal.packing import random_packing
from athermal.protocols import (
    Minimizer,
    compression_steps,
    isostatic_z,
    jam,
    jamming_steps,
    log_spaced,
    scaling_exponents,
    shear_steps,
)
from athermal.protocols._relax import energy_scale


@pytest.fixture(scope="module")
def jammed_256():
    return jam(random_packing(256, 0.8, seed=2), ContactModel(2.0), epsilon=1e-6)


def test_jamming_follows_the_seed_algorithm_and_ends_on_a_narrow_bracket():
    steps = list(jamming_steps(random_packing(64, 0.8, seed=1), ContactModel(2.0), epsilon=1e-5))
    assert steps[0].phase == "start" and not steps[0].jammed
    increments = [s for s in steps if s.phase == "increment"]
    np.testing.assert_allclose(np.diff([s.phi for s in increments]), 1e-3, rtol=1e-9)
    assert [s.jammed for s in increments] == [False] * (len(increments) - 1) + [True]
    bisection = [s for s in steps if s.phase == "bisection"]
    widths = [s.bracket for s in bisection]
    np.testing.assert_allclose(np.array(widths[1:]) / widths[:-1], 0.5, rtol=1e-9)
    last = steps[-1]
    assert last.bracket <= 1e-5 < 2 * last.bracket
    for s in bisection:  # every trial sits in the middle of the previous bracket
        assert s.phi_low <= s.phi <= s.phi_high
    assert all(s.energy > 0 and s.pressure > 0 for s in steps if s.jammed)


def test_jammed_threshold_separates_states_by_energy_not_round_off():
    """Unjammed steps end with E/N at most the stated threshold (epsilon / 10 d)^alpha in
    units of k <r>^alpha and jammed ones above it; the threshold is more than 1e12 times the
    round-off of an overlap energy, (eps_mach L / <r>)^2 in the same units."""
    model = ContactModel(2.0)
    steps = list(jamming_steps(random_packing(64, 0.8, seed=1), model, epsilon=1e-5))
    threshold = (1e-5 / 20.0) ** 2
    for s in steps:
        per_particle = s.energy / (64 * energy_scale(s.packing.radii, model))
        assert (per_particle > threshold) == s.jammed
    roundoff = (np.finfo(float).eps / steps[0].packing.radii.mean()) ** 2
    assert threshold > 1e12 * roundoff


def test_jam_returns_a_jammed_packing_near_isostaticity(jammed_256):
    result = jammed_256
    obs = result.observables
    assert 0.80 < result.phi_c < 0.86
    assert result.packing.phi == pytest.approx(result.phi_c, rel=1e-12)
    assert obs.energy > 0.0 and obs.pressure > 0.0
    n_live = obs.n - obs.n_rattlers
    assert abs(obs.z - isostatic_z(n_live, 2)) < 0.1
    assert result.iterations == sum(s.iterations for s in result.history)


def test_a_jammed_start_is_refused_and_bad_parameters_are_named():
    with pytest.raises(InputError, match="phi_init"):
        next(jamming_steps(random_packing(64, 0.9, seed=1), ContactModel(2.0)))
    with pytest.raises(InputError, match="dphi"):
        next(jamming_steps(random_packing(64, 0.8, seed=1), ContactModel(2.0), dphi=-1e-3))
    with pytest.raises(InputError, match="method"):
        Minimizer("bfgs")  # type: ignore[arg-type]


def test_jamming_is_reproducible():
    a = jam(random_packing(48, 0.8, seed=4), ContactModel(2.0), epsilon=1e-4)
    b = jam(random_packing(48, 0.8, seed=4), ContactModel(2.0), epsilon=1e-4)
    assert a.phi_c == b.phi_c and a.iterations == b.iterations
    np.testing.assert_array_equal(a.packing.positions, b.packing.positions)


@pytest.mark.slow
def test_compression_scaling_exponents_small(jammed_256):
    """Small form of the seed's scaling check (N = 256, one seed): p ~ Dphi^1, z - z_iso ~
    Dphi^0.5 over 1e-6 ... 1e-1 (G, noisier at this size, has its own looser bound)."""
    steps = list(
        compression_steps(
            jammed_256.packing, ContactModel(2.0), delta_phis=log_spaced(1e-6, 1e-1, 2)
        )
    )
    fits = scaling_exponents(steps, lower=1e-6)
    assert fits.pressure is not None and abs(fits.pressure.exponent - 1.0) < 0.1
    z_fit = scaling_exponents(steps, lower=1e-4).z_excess
    assert z_fit is not None and abs(z_fit.exponent - 0.5) < 0.15
    g_fit = scaling_exponents(steps, lower=1e-4).shear_modulus
    assert g_fit is not None and 0.2 < g_fit.exponent < 0.9
    assert all(s.z_excess >= -1e-12 for s in steps)


def test_bulk_modulus_is_phi_dp_dphi_along_the_protocol():
    """B reported by the compression (linear response + (alpha - d) p / d) equals a central
    difference of p along radius growth, for alpha = 2.5 where the correction is not zero."""
    model = ContactModel(2.5)
    start = random_packing(128, 0.9, seed=3)
    deltas = np.array([1e-3, 1e-3 + 2e-7, 1e-3 + 4e-7])
    steps = list(compression_steps(start, model, phi_c=0.899, delta_phis=deltas, rtol=1e-12))
    assert steps[0].contacts == steps[2].contacts
    dp = (steps[2].pressure - steps[0].pressure) / (steps[2].phi - steps[0].phi)
    assert steps[1].bulk_modulus == pytest.approx(steps[1].phi * dp, rel=1e-4)
    cell_only = linear_response(steps[1].packing, model).bulk
    assert abs(steps[1].bulk_modulus - cell_only) > 1e-3 * cell_only


def test_compression_rejects_bad_ranges():
    packing = random_packing(64, 0.9, seed=1)
    with pytest.raises(InputError, match="delta_phis"):
        next(compression_steps(packing, ContactModel(), delta_phis=[1e-3, 1e-4]))
    with pytest.raises(InputError, match="phi_c"):
        next(compression_steps(packing, ContactModel(), phi_c=0.95))
    assert log_spaced(1e-7, 1e-1, 4).size == 25


def test_simple_shear_first_step_follows_the_linear_response_modulus():
    model = ContactModel(2.0)
    start = random_packing(128, 0.88, seed=1)
    steps = list(shear_steps(start, model, mode="simple", strain=2e-6, step=1e-6, rtol=1e-12))
    assert [s.strain for s in steps] == [0.0, 1e-6, 2e-6]
    g = linear_response(steps[0].packing, model).shear
    slope = (steps[1].tau - steps[0].tau) / 1e-6
    assert slope == pytest.approx(g, rel=2e-3)
    assert not any(s.plastic for s in steps)


def test_pure_shear_reaches_the_final_strain_exactly_and_flags_stress_drops():
    model = ContactModel(2.0)
    start = random_packing(128, 0.86, seed=2)
    steps = list(shear_steps(start, model, mode="pure", strain=0.005, step=0.002))
    assert [s.strain for s in steps] == pytest.approx([0.0, 0.002, 0.004, 0.005])
    expected = start.cell.deform(pure_shear(0.005)).h
    np.testing.assert_allclose(steps[-1].packing.cell.h, expected, rtol=1e-12)
    for before, after in itertools.pairwise(steps):
        drop = before.tau - after.tau
        assert after.stress_drop == pytest.approx(drop)
        assert after.plastic == (drop > 1e-6 * abs(after.observables.pressure))
    obs = measure(steps[-1].packing, model)
    assert obs.stress_dev == pytest.approx(steps[-1].observables.stress_dev)
    with pytest.raises(InputError, match="step"):
        next(shear_steps(start, model, strain=1e-3, step=1e-2))


def test_relaxer_finishes_with_fire_when_the_line_search_gives_up(monkeypatch):
    """A line-search failure near the minimum is handed to FIRE; counts add up, the message
    says so, and a plain non-convergence still raises."""
    from athermal.errors import ConvergenceError
    from athermal.objective import Objective
    from athermal.protocols import _relax

    packing, model = random_packing(64, 0.9, seed=1), ContactModel(2.0)
    real = _relax.minimize
    calls = []

    def failing_lbfgs(objective, method, **kw):
        calls.append(method)
        if method == "lbfgs":
            first = real(objective, method, **{**kw, "maxiter": 5})
            return dataclasses.replace(first, converged=False, message="line search failed: x")
        return real(objective, method, **kw)

    monkeypatch.setattr(_relax, "minimize", failing_lbfgs)
    relaxer = _relax.Relaxer(Objective(packing, model), Minimizer("lbfgs"))
    result = relaxer.relax(relaxer.objective.x0, gtol=1e-12)
    assert calls == ["lbfgs", "fire"] and result.converged and result.max_gradient <= 1e-12
    assert result.method == "lbfgs+fire" and "FIRE after" in result.message
    assert result.iterations == result.history_energy.size - 1 > 5

    monkeypatch.setattr(_relax, "minimize", real)
    with pytest.raises(ConvergenceError, match="did not converge"):
        _relax.Relaxer(Objective(packing, model), Minimizer("lbfgs", maxiter=3)).relax(
            relaxer.objective.x0, gtol=1e-14
        )


def _same_steps(a, b):
    assert [s.index for s in a] == [s.index for s in b]
    assert [s.iterations for s in a] == [s.iterations for s in b]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.packing.positions, y.packing.positions)


def test_jamming_resumed_after_any_step_is_bit_identical():
    start, model = random_packing(48, 0.8, seed=4), ContactModel(2.0)
    full = list(jamming_steps(start, model, epsilon=1e-4))
    assert full[-1].phase == "final"
    for cut in (1, len(full) // 2, len(full) - 2, len(full) - 1):
        rest = list(jamming_steps(start, model, epsilon=1e-4, resume=full[:cut]))
        _same_steps(full[cut:], rest)
    assert list(jamming_steps(start, model, epsilon=1e-4, resume=full)) == []
    with pytest.raises(InputError, match="resume"):
        next(jamming_steps(start, model, epsilon=1e-4, resume=full[1:]))


def test_compression_resumed_is_bit_identical(jammed_256):
    model, deltas = ContactModel(2.0), log_spaced(1e-5, 1e-2, 1)
    full = list(compression_steps(jammed_256.packing, model, delta_phis=deltas))
    rest = list(compression_steps(jammed_256.packing, model, delta_phis=deltas, resume=full[:2]))
    _same_steps(full[2:], rest)
    assert [s.index for s in rest] == [2, 3]


def test_shear_resumed_is_bit_identical():
    start, model = random_packing(96, 0.87, seed=5), ContactModel(2.0)
    full = list(shear_steps(start, model, mode="simple", strain=4e-3, step=1e-3))
    rest = list(shear_steps(start, model, mode="simple", strain=4e-3, step=1e-3, resume=full[:3]))
    _same_steps(full[3:], rest)
    assert [s.plastic for s in rest] == [s.plastic for s in full[3:]]


def test_a_refuted_jammed_verdict_reopens_the_bracket_and_resumes_identically():
    """With a deliberately loose trial tolerance some trials stop, E above the threshold, on
    their way to unjamming; the tight final relaxation refutes them, the refuted state becomes
    the new bottom of an open bracket and the protocol still ends on a verified jammed state."""
    start, model, lbfgs = random_packing(64, 0.8, seed=0), ContactModel(2.0), Minimizer("lbfgs")
    steps = list(jamming_steps(start, model, epsilon=1e-5, rtol=0.1, minimizer=lbfgs))
    finals = [s for s in steps if s.phase == "final"]
    assert len(finals) >= 2 and not finals[0].jammed and finals[-1].jammed
    assert steps[-1] is finals[-1] and steps[-1].bracket <= 1e-5
    refuted = steps.index(finals[0])
    after = steps[refuted + 1]
    assert after.phase == "increment" and after.phi == pytest.approx(finals[0].phi + 1e-3)
    done = steps[: refuted + 1]
    rest = list(jamming_steps(start, model, epsilon=1e-5, rtol=0.1, minimizer=lbfgs, resume=done))
    _same_steps(steps[refuted + 1 :], rest)
