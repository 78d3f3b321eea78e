import dataclasses
import itertools

import numpy as np
import pytest

from athermal.analysis.moduli import linear_response
from athermal.analysis.observables import measure
from athermal.errors import ConvergenceError, InputError
from athermal.minimize import Status
from athermal.model.cell import pure_shear
from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.model.packing import random_packing
from athermal.protocols import (
    JammingStep,
    Minimizer,
    check_jammed,
    compression_steps,
    isostatic_z,
    jam,
    jamming_steps,
    log_spaced,
    scaling_exponents,
    shear_steps,
)
from athermal.protocols.compress import UNJAMMED_FORCE, is_unjammed, pooled_fit
from athermal.protocols.jamming import JammingCheck, _next_trial, isostatic_allowance
from athermal.relaxation import energy_scale, force_tolerance, minimize_objective


@pytest.fixture(scope="module")
def jammed_256():
    return jam(random_packing(256, 0.8, seed=2), ContactModel(2.0), epsilon=1e-6)


def test_jamming_grows_by_dphi_then_ends_one_epsilon_above_its_own_unjammed_state():
    """The paper's growth, then a bracket that ends with the jammed packing relaxed from the
    unjammed configuration at phi_low grown by at most epsilon (final -> its trial -> phi_low)."""
    steps = list(jamming_steps(random_packing(64, 0.8, seed=1), ContactModel(2.0), epsilon=1e-5))
    assert steps[0].phase == "start" and not steps[0].jammed
    growth = []
    for s in steps[1:]:
        growth.append(s)
        if s.jammed:
            break
    assert all(s.phase == "increment" for s in growth)
    np.testing.assert_allclose(np.diff([s.phi for s in growth]), 1e-3, rtol=1e-9)
    for before, s in itertools.pairwise(steps):
        assert s.origin < s.index
        if s.phase == "bisection":  # inside the bracket, or the check at its top
            assert before.phi_low < s.phi <= before.phi_high
    final = steps[-1]
    assert final.phase == "final" and final.jammed and 0 < final.bracket <= 1e-5
    trial = steps[final.origin]
    assert trial.jammed and trial.phi == final.phi
    grown_from = steps[trial.origin]
    assert not grown_from.jammed and grown_from.phi == final.phi_low
    assert all(s.energy > 0 and s.pressure > 0 for s in steps if s.jammed)


@pytest.mark.parametrize("protocol", ["seed", "ohern"])
def test_a_smaller_epsilon_refines_the_bracket_of_a_larger_one(protocol):
    """The verdicts do not depend on epsilon: runs from one start follow the same trials, bit
    for bit, until the coarser bracket is closed, and the finer phi_c lies inside it (unless the
    coarser run's last check reopened its bracket, which it did not here)."""
    model, nested = ContactModel(2.0), 0
    for seed in (3, 4, 5):
        start = random_packing(64, 0.8, seed=seed)
        coarse = list(jamming_steps(start, model, epsilon=1e-4, protocol=protocol))
        fine = list(jamming_steps(start, model, epsilon=1e-7, protocol=protocol))
        closed = next(k for k, s in enumerate(coarse) if s.bracket <= 1e-4)
        for a, b in zip(coarse[: closed + 1], fine[: closed + 1], strict=True):
            assert (a.phase, a.phi, a.origin, a.jammed, a.energy) == (
                b.phase,
                b.phi,
                b.origin,
                b.jammed,
                b.energy,
            )
        assert fine[-1].bracket <= 1e-7
        if all(np.isfinite(s.phi_high) for s in coarse[closed:]):  # the bracket never reopened
            assert coarse[-1].phi_low <= fine[-1].phi_low < fine[-1].phi <= coarse[-1].phi
            nested += 1
    assert nested >= 2


def test_a_jammed_trial_balances_its_forces_to_its_own_mean_contact_force():
    """The verdict's force rule: every jammed trial is relaxed to rtol (1e-6) of its own mean
    contact force (or the round-off floor), not of the forces it started from."""
    from athermal.protocols.jamming import TRIAL_RTOL

    model = ContactModel(2.0)
    steps = list(jamming_steps(random_packing(64, 0.8, seed=2), model, epsilon=1e-6))
    trials = [s for s in steps if s.jammed and s.phase != "final"]
    assert trials
    for s in trials:
        objective = Objective(s.packing, model)
        gradient = objective(objective.x0)[1].reshape(-1, 2)
        largest = float(np.sqrt((gradient**2).sum(axis=1)).max())
        assert largest <= force_tolerance(s.packing, model, TRIAL_RTOL) * (1 + 1e-9)


def test_epsilon_below_the_verdicts_resolution_is_refused():
    with pytest.raises(InputError, match="epsilon"):
        next(jamming_steps(random_packing(64, 0.8, seed=3), ContactModel(2.0), epsilon=1e-10))
    with pytest.raises(InputError, match="protocol"):
        next(jamming_steps(random_packing(64, 0.8, seed=3), ContactModel(2.0), protocol="x"))


def _step(index, phase, origin, phi, jammed, low, high):
    return JammingStep(
        index, phase, origin, phi, jammed, 0.0, 0.0, 0, 0, 0, 0, 0.0, low, high, None
    )


@pytest.mark.parametrize("protocol", ["seed", "ohern"])
def test_next_trial_follows_the_scheme(protocol):
    """The plan is a function of the history: growth by dphi, bisection (from the last unjammed
    state for ``seed``, from the last state for ``ohern``), a check of the unjammed state at
    phi_high, the final, and the reopened growth by RESTART epsilon doubling up to dphi."""
    inf, eps = np.inf, 1e-6

    def plan(h):
        return _next_trial(h, 1e-3, eps, protocol)

    h = [_step(0, "start", -1, 0.8, False, 0.8, inf)]
    assert plan(h) == ("increment", pytest.approx(0.801), 0)
    h.append(_step(1, "increment", 0, 0.801, True, 0.8, 0.801))
    # the first bisection trial grows the start (seed) or decompresses the jammed state (ohern)
    assert plan(h) == ("bisection", pytest.approx(0.8005), 0 if protocol == "seed" else 1)
    # a bracket of 1e-6 whose jammed top came from step 1, not from the unjammed bottom
    low = 0.801 - 0.9 * eps
    h.append(_step(2, "bisection", 1, low, False, low, 0.801))
    assert plan(h) == ("bisection", 0.801, 2)
    h.append(_step(3, "bisection", 2, 0.801, True, low, 0.801))
    assert plan(h) == ("final", 0.801, 3)
    h.append(_step(4, "final", 3, 0.801, True, low, 0.801))
    assert plan(h) is None
    # the check at the top unjams instead: the bracket reopens and growth restarts small
    h[3:] = [_step(3, "bisection", 2, 0.801, False, 0.801, inf)]
    assert plan(h) == ("increment", pytest.approx(0.801 + 4 * eps), 3)
    h.append(_step(4, "increment", 3, 0.801 + 4 * eps, False, 0.801 + 4 * eps, inf))
    assert plan(h) == ("increment", pytest.approx(0.801 + 12 * eps), 4)
    # a jammed trial leaves the paper's C_ref where it was
    h = [
        _step(0, "start", -1, 0.8, False, 0.8, inf),
        _step(1, "increment", 0, 0.801, True, 0.8, 0.801),
        _step(2, "bisection", 0, 0.8005, True, 0.8, 0.8005),
    ]
    assert plan(h) == ("bisection", pytest.approx(0.80025), 0 if protocol == "seed" else 2)


def test_jam_checks_its_packing_as_a_referee_would(jammed_256):
    """Decompressed by 3 epsilon it unjams; isostatic; overlaps of a packing ~epsilon above
    jamming; a minimum; and the pressure of one about epsilon above it (p / eps measured
    0.19-0.21 at N = 128-1024, alpha = 2)."""
    check = jammed_256.check
    assert check.passed, check.problems()
    assert check.unjams and check.decompressed_energy <= (1e-6 / 20) ** 2
    assert 0 <= check.excess_contacts <= check.allowed_excess < 6 and check.stable
    assert 0.0 < check.overlap_dphi < 1e-6
    assert 0.0 < jammed_256.observables.pressure < 1e-6
    assert jammed_256.phi_c - jammed_256.phi_low <= 1e-6


def test_check_jammed_flags_a_packing_far_above_jamming():
    model = ContactModel(2.0)
    far = minimize_objective(
        Objective(random_packing(128, 0.86, seed=3), model), rtol=1e-10
    ).packing
    check = check_jammed(far, model, epsilon=1e-6)
    assert not check.unjams and check.overlap_dphi > 1e-3
    assert any("decompressed" in p for p in check.problems())


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
    assert 0.0 <= obs.z - isostatic_z(n_live, 2) <= 8 / n_live
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
    """Small form of the paper's scaling check (N = 256): p ~ Dphi^1 for one packing; z - z_iso
    ~ Dphi^0.5 and G ~ Dphi^0.5 pooled over three packings (all their points in one fit, as the
    seed's figures average realizations), each fit over the points its rules take
    (:func:`~athermal.protocols.compress.fit_points`: at N = 256 z - z_iso counts 10 contacts
    from Delta phi ~ 1e-3 up, and G is fitted from Delta phi N^2 >= 1).
    """
    model = ContactModel(2.0)
    deltas = log_spaced(1e-6, 1e-1, 2)
    steps = list(compression_steps(jammed_256.packing, model, delta_phis=deltas))
    fits = scaling_exponents(steps, lower=1e-6)
    assert fits.pressure is not None and abs(fits.pressure.exponent - 1.0) < 0.1
    # never hypostatic in its basin; a packing this small and this near jamming may rearrange
    # into a looser one on the way (seed 2 does at Delta phi = 1e-3, unstable to shear from the
    # start): the step says so, and the fits stop there
    for s in steps:
        assert s.z_excess >= -1e-12 or "unjammed" in s.events
        assert ("unjammed" in s.events) == (s.pressure < 1e-12)
    if fits.left_basin is not None:
        assert fits.pressure.x_max < fits.left_basin
    compressions = [[s.row() for s in steps]]
    for seed in (3, 4):
        packing = jam(random_packing(256, 0.8, seed=seed), model, epsilon=1e-6).packing
        compressions.append([s.row() for s in compression_steps(packing, model, delta_phis=deltas)])
    z_fit = pooled_fit(compressions, "z_excess")
    assert abs(z_fit.exponent - 0.5) < 0.15 and z_fit.x_min >= 3e-4, z_fit
    g_fit = pooled_fit(compressions, "shear_modulus")
    assert 0.2 < g_fit.exponent < 0.9 and g_fit.x_min >= 1.0 / 256**2, g_fit


def test_bulk_modulus_is_phi_dp_dphi_along_the_protocol():
    """B reported by the compression (linear response + (alpha - d) p / d) equals a central
    difference of p along radius growth, for alpha = 2.5 where the correction is not zero."""
    model = ContactModel(2.5)
    start = random_packing(128, 0.9, seed=3)
    deltas = np.array([1e-3, 1e-3 + 2e-7, 1e-3 + 4e-7])
    with pytest.warns(UserWarning, match="above its jamming point"):  # unrelaxed, on purpose
        steps = list(
            compression_steps(
                start, model, phi_c=0.899, delta_phis=deltas, rtol=1e-12, from_unjammed=True
            )
        )
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
    from athermal import relaxation
    from athermal.engines import numba
    from athermal.errors import ConvergenceError
    from athermal.model.objective import Objective

    packing, model = random_packing(64, 0.9, seed=1), ContactModel(2.0)
    real = numba.run
    calls = []

    def failing_lbfgs(objective, method, x, precon, **kw):
        calls.append(method)
        if method == "lbfgs":
            first = real(objective, method, x, precon, **{**kw, "maxiter": 5})
            return dataclasses.replace(
                first, converged=False, status=Status.LINE_SEARCH_FAILED, message="x"
            )
        return real(objective, method, x, precon, **kw)

    monkeypatch.setattr(numba, "run", failing_lbfgs)
    relaxer = relaxation.Relaxer(Objective(packing, model), Minimizer("lbfgs"))
    result = relaxer.relax(relaxer.objective.x0, gtol=1e-12)
    assert calls == ["lbfgs", "fire"] and result.converged and result.max_gradient <= 1e-12
    assert result.method == "lbfgs+fire" and "FIRE after" in result.message
    assert result.iterations == result.history_energy.size - 1 > 5

    monkeypatch.setattr(numba, "run", real)
    with pytest.raises(ConvergenceError, match="did not converge"):
        relaxation.Relaxer(Objective(packing, model), Minimizer("lbfgs", maxiter=3)).relax(
            relaxer.objective.x0, gtol=1e-14
        )


def test_a_newton_relaxation_that_crawls_goes_on_with_plbfgs(monkeypatch):
    """Past NEWTON_PATIENCE iterations Newton-CG hands over to P-L-BFGS; counts add up, the
    message says so; within it, or with maxiter at or below it, Newton alone."""
    from athermal import relaxation

    packing, model = random_packing(64, 0.9, seed=1), ContactModel(2.0)
    alone = relaxation.Relaxer(Objective(packing, model), Minimizer("newton"))
    plain = alone.relax(alone.objective.x0, gtol=1e-12)
    assert plain.method == "newton" and plain.converged and plain.iterations > 3

    monkeypatch.setattr(relaxation, "NEWTON_PATIENCE", 3)
    relaxer = relaxation.Relaxer(Objective(packing, model), Minimizer("newton"))
    result = relaxer.relax(relaxer.objective.x0, gtol=1e-12)
    assert result.converged and result.max_gradient <= 1e-12
    assert result.method == "newton+lbfgs" and "P-L-BFGS after" in result.message
    assert result.iterations == result.history_energy.size - 1 > 3
    assert result.linear_iterations >= 3 and result.precon_builds >= 2  # Newton's, then Exp's
    # another minimum than Newton's alone (a random start has many), reached downhill
    assert result.energy < relaxer.objective(relaxer.objective.x0)[0]
    with pytest.raises(ConvergenceError, match="did not converge"):
        relaxation.Relaxer(Objective(packing, model), Minimizer("newton", maxiter=3)).relax(
            relaxer.objective.x0, gtol=1e-12
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


def test_a_refuted_jammed_verdict_reopens_the_bracket_and_resumes_identically(monkeypatch):
    """A final relaxation that unjams (here forced at the first final's phi) makes its state the
    bottom of an open bracket; growth restarts from it by 4 epsilon and the protocol still ends
    on a verified jammed state; a run resumed after the refutation is bit-identical."""
    from athermal.protocols import jamming

    start, model, eps = random_packing(64, 0.8, seed=0), ContactModel(2.0), 1e-5
    first_final = list(jamming_steps(start, model, epsilon=eps))[-1].phi
    real = jamming._Trials.relax

    def refuting(self, phi, origin, tight, what):
        out = real(self, phi, origin, tight, what)
        return dataclasses.replace(out, jammed=False) if tight and phi == first_final else out

    monkeypatch.setattr(jamming._Trials, "relax", refuting)
    steps = list(jamming_steps(start, model, epsilon=eps))
    finals = [s for s in steps if s.phase == "final"]
    assert len(finals) >= 2 and not finals[0].jammed and finals[-1].jammed
    assert steps[-1] is finals[-1] and steps[-1].bracket <= eps
    refuted = steps.index(finals[0])
    assert np.isinf(finals[0].phi_high) and finals[0].phi_low == first_final
    after = steps[refuted + 1]
    assert after.phase == "increment" and after.phi == pytest.approx(first_final + 4 * eps)
    rest = list(jamming_steps(start, model, epsilon=eps, resume=steps[: refuted + 1]))
    _same_steps(steps[refuted + 1 :], rest)


def test_the_final_relaxation_balances_forces_relative_to_the_packings_own(jammed_256):
    """max_i |grad_i| <= 1e-10 x the mean contact force, or the round-off floor when larger."""
    from athermal.model.contact import find_contacts
    from athermal.relaxation import round_off_floor

    packing, model = jammed_256.packing, ContactModel(2.0)
    obs = measure(packing, model)
    floor = round_off_floor(find_contacts(packing, model), packing.cell)
    assert obs.max_gradient <= max(1e-10 * obs.mean_contact_force, floor)
    assert floor < 1e-6 * obs.mean_contact_force  # a packing 1e-6 above jamming: still relative


@pytest.mark.parametrize("alpha", [2.0, 2.5])
def test_round_off_floor_is_reachable_and_follows_the_contact_stiffness(alpha):
    """eps (L kappa_max + f_max) x 10: reachable by L-BFGS (it stalls at 0.25-0.6 of the
    unscaled estimate), and for Hertzian contacts near jamming far below a floor fixed in units
    of k <r>^(alpha-1) (the old 1e-13 k <r>^(alpha-1) was ~1e-3 of the mean force there)."""
    from athermal.model.contact import find_contacts
    from athermal.relaxation import round_off_floor

    model = ContactModel(alpha)
    near = jam(random_packing(64, 0.8, seed=5), model, epsilon=1e-6).packing
    contacts = find_contacts(near, model)
    floor = round_off_floor(contacts, near.cell)
    kappa = (alpha - 1.0) * contacts.overlap ** (alpha - 2.0)
    eps = np.finfo(float).eps
    assert floor == pytest.approx(10 * eps * (kappa.max() + contacts.force_magnitude.max()))
    result = minimize_objective(Objective(near, model), "lbfgs", gtol=floor, maxiter=20_000)
    assert result.converged and result.max_gradient <= floor
    if alpha > 2.0:
        assert floor < 1e-2 * 1e-13 * np.mean(near.radii) ** (alpha - 1.0)


def test_compression_refuses_an_unjammed_start():
    model = ContactModel(2.0)
    loose = minimize_objective(Objective(random_packing(64, 0.6, seed=1), model), rtol=1e-9).packing
    with pytest.raises(InputError, match="not jammed"):
        next(compression_steps(loose, model))


def test_a_packing_whose_forces_are_within_its_tolerance_bears_no_load(jammed_256):
    """Unjammed: no pressure, no rigid backbone, or contact forces no larger than the residual
    its relaxation's tolerance allows (a p = 1.5e-12 left by a compression step that rearranged
    an N = 1024 packing into a looser one counted as jammed before)."""
    model = ContactModel(2.0)
    packing = jammed_256.packing
    obs = measure(packing, model)
    gtol = force_tolerance(packing, model, 1e-9)
    assert obs.pressure > 0.0 and obs.n_rattlers < obs.n
    assert not is_unjammed(obs, gtol)
    assert is_unjammed(obs, obs.mean_contact_force / UNJAMMED_FORCE)
    assert not is_unjammed(obs, 0.5 * obs.mean_contact_force / UNJAMMED_FORCE)
    assert is_unjammed(dataclasses.replace(obs, pressure=0.0), gtol)
    assert is_unjammed(dataclasses.replace(obs, n_rattlers=obs.n), gtol)
    # relaxed to 1e-3 of its forces: jammed, unless those forces had fallen from a 1e6 x larger
    # start (rtol = 1e-9)
    loose = 1e-3 * obs.mean_contact_force
    assert not is_unjammed(obs, loose, rtol=1e-3)
    assert is_unjammed(obs, loose, rtol=1e-9)


def test_iteration_counts_leave_a_state_the_compression_unjammed_out(jammed_256, monkeypatch):
    """Such a state is not Delta phi above jamming: it is not sheared and counts NaN."""
    from athermal.studies import experiments

    real = experiments.compression_steps

    def second_unjammed(*args, **kwargs):
        for k, state in enumerate(real(*args, **kwargs)):
            yield dataclasses.replace(state, events=("unjammed",)) if k == 1 else state

    monkeypatch.setattr(experiments, "compression_steps", second_unjammed)
    spec = experiments.IterationSpec(
        delta_phis=(1e-4, 1e-3, 1e-2), methods=(Minimizer("lbfgs"),), strains=(1e-6, 2e-6)
    )
    counts = experiments.iteration_counts(
        jammed_256.packing, ContactModel(2.0), jammed_256.phi_c, spec
    )
    name = spec.methods[0].name
    assert np.isnan(counts.iterations[name][1]) and np.isnan(counts.seconds[name][1])
    assert counts.iterations[name][0] > 0 and counts.iterations[name][2] > 0
    assert len(counts.delta_phi) == 3


def test_compression_reports_its_events_and_pressure_rises_between_them(jammed_256):
    """Every drop of p is an event, never silent; between events p rises; G < 0 is flagged."""
    model = ContactModel(2.0)
    steps = list(compression_steps(jammed_256.packing, model, delta_phis=log_spaced(1e-6, 1e-2, 2)))
    previous = jammed_256.observables.pressure
    for s in steps:
        if s.pressure < previous and "unjammed" not in s.events:
            assert "pressure drop" in s.events
        assert ("unstable to shear" in s.events) == (s.shear_modulus < 0.0)
        assert s.substeps >= 1 and s.saddles >= 0
        previous = s.pressure
    assert steps[-1].pressure > 1e3 * steps[0].pressure


def test_jam_warns_when_its_packing_fails_a_check(monkeypatch):
    from athermal.protocols import jamming

    real = jamming.check_jammed

    def failing(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), unjams=False, decompressed_energy=1e-9)

    monkeypatch.setattr(jamming, "check_jammed", failing)
    with pytest.warns(UserWarning, match="still jammed when decompressed"):
        result = jam(random_packing(48, 0.8, seed=4), ContactModel(2.0), epsilon=1e-4)
    assert not result.check.passed


def test_the_isostatic_allowance_grows_with_the_contacts_an_overlap_implies():
    """N' (z - z_iso) / 2 ~ N' 3.5 sqrt(Delta phi) / 2 in 2D on average: ~5 extra contacts at
    N = 4096 and 5e-7 above jamming, 1 at N = 1024; single packings scatter by about the mean, so
    twice it is accepted (on top of a slack of 4); a packing with more is hyperstatic."""
    assert isostatic_allowance(1000, 2, 0.0) == 4
    assert isostatic_allowance(1000, 2, 5e-7) == pytest.approx(4 + 2 * 1000 * 3.5 * 5e-7**0.5 / 2)
    assert isostatic_allowance(4000, 2, 5e-7) > isostatic_allowance(1000, 2, 5e-7) + 3.5
    assert isostatic_allowance(1000, 3, 5e-7) > isostatic_allowance(1000, 2, 5e-7)
    check = JammingCheck(1e-6, 0.0, True, 8, isostatic_allowance(4000, 2, 5e-7), 5e-7, 1e-6, True)
    assert check.passed
    crowded = JammingCheck(1e-6, 0.0, True, 8, isostatic_allowance(1000, 2, 5e-7), 5e-7, 1e-6, True)
    assert crowded.problems() == ["N_c - N_iso = 8 (isostatic at this overlap: 0 ... 6.5)"]
