"""Certified jamming points: the force balance a certificate states holds when recomputed
independently (decimal at 60 digits), and what cannot be certified is refused."""

import json
from dataclasses import replace
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

import athermal as at
import athermal.certify as certify_package
import athermal.certify.bisection as bisection
import athermal.cli.analysis as analysis
from athermal._portable import root
from athermal.analysis.observables import rattlers
from athermal.certify import (
    GAP_REACH,
    TARGET,
    _same_network,
    certify,
    contact_network,
    toward_jamming,
)
from athermal.certify.bisection import (
    MARCH_BITS,
    START_EPSILON,
    _KeptFactor,
    _landing,
    _trial,
    bisect_jamming_point,
    float64_epsilon,
)
from athermal.certify.extended import NearPairs
from athermal.cli import main
from athermal.errors import ConvergenceError, InputError
from athermal.model.neighbors import build_neighbor_list
from athermal.protocols import RESOLUTION
from decimal_reference import decimal_sums

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module", params=[(2, 2.0, 64), (2, 2.5, 64), (3, 2.0, 48)])
def jammed(request):
    dim, alpha, n = request.param
    model = at.ContactModel(alpha)
    start = at.random_packing(n, 0.8 if dim == 2 else 0.6, dim=dim, seed=4)
    return at.jam(start, model).packing, model


def decimal_force_balance(packing, lo, model):
    """``max_i |F_i|`` and the mean contact force, by decimal arithmetic from ``hi + lo``."""
    nlist = build_neighbor_list(packing.positions, packing.radii, packing.cell, skin=0.0)
    first, second = nlist.first.astype(np.int64), nlist.second.astype(np.int64)
    images = np.ascontiguousarray(nlist.images[nlist.code])
    k = np.full(first.size, model.stiffness)
    overlaps, grad, _, _ = decimal_sums(
        packing.positions, lo, packing.radii, packing.cell.h, first, second, images, k, model.alpha
    )
    forces = [Decimal(model.stiffness) * o ** Decimal(model.alpha - 1) for o in overlaps if o > 0]
    largest = max(sum(g * g for g in row).sqrt() for row in grad)
    return largest, sum(forces) / len(forces)


def test_a_certified_packing_balances_its_forces_to_1e_20_of_the_mean_force(jammed):
    packing, model = jammed
    done = certify(packing, model)
    cert = done.certificate
    assert cert.converged and cert.relative_force_balance <= TARGET
    assert cert.start_force_balance > 1e-10 * cert.mean_force  # float64's floor, far above
    # independently, from the certified hi + lo
    largest, mean_force = decimal_force_balance(done.packing, done.position_lo, model)
    assert largest <= Decimal(TARGET) * mean_force
    assert float(mean_force) == pytest.approx(cert.mean_force, rel=1e-12)
    assert 1 <= cert.iterations <= 4
    # a jammed packing: isostatic up to a few contacts, stable, with gaps and forces resolved
    assert 0 <= cert.excess_contacts <= 4
    assert cert.lowest_eigenvalue > 0.0
    assert 0.0 < cert.smallest_force < cert.mean_force
    assert cert.smallest_gap > 0.0
    assert cert.pressure == pytest.approx(at.measure(packing, model).pressure, rel=1e-6)
    # the same packing: the refinement moves the particles by a small part of an overlap (more
    # than float64's resolution of positions: the residual forces act along soft modes)
    moved = np.abs(done.packing.positions - packing.positions).max()
    overlap = (cert.mean_force / model.stiffness) ** (1.0 / (model.alpha - 1.0))
    assert moved < 1e-2 * overlap


def test_certifying_a_certified_packing_changes_nothing(jammed):
    packing, model = jammed
    done = certify(packing, model)
    again = certify(done.packing, model, done.position_lo)
    assert again.certificate.iterations == 0
    np.testing.assert_array_equal(again.packing.positions, done.packing.positions)
    np.testing.assert_array_equal(again.position_lo, done.position_lo)


def test_certify_on_the_machines_blas_reaches_the_same_certificate(jammed):
    """``portable=False`` (CHOLMOD on cvxopt's BLAS) refines to the same state as cholespy's
    factor does, within the round-off of the double-double positions, and certifies it alike."""
    packing, model = jammed
    portable, fast = certify(packing, model), certify(packing, model, portable=False)
    a, b = portable.certificate, fast.certificate
    assert b.converged and b.contacts == a.contacts and b.n_rattlers == a.n_rattlers
    assert b.relative_force_balance <= TARGET
    exact = (portable.packing.positions - fast.packing.positions) + (
        portable.position_lo - fast.position_lo
    )
    assert np.abs(exact).max() <= 1e-20 * float(packing.radii.mean())
    assert b.lowest_eigenvalue == pytest.approx(a.lowest_eigenvalue, rel=1e-6)


def test_the_certified_state_is_read_back_exactly(jammed, tmp_path):
    packing, model = jammed
    done = certify(packing, model)
    at.write_gsd(
        tmp_path / "c.gsd",
        done.packing,
        model=model,
        observables=done.certificate.log(),
        position_lo=done.position_lo,
    )
    frame = at.read_gsd(tmp_path / "c.gsd")
    np.testing.assert_array_equal(frame.packing.positions, done.packing.positions)
    np.testing.assert_array_equal(frame.position_lo, done.position_lo)
    assert float(frame.log["certificate_relative_force_balance"][()]) == (
        done.certificate.relative_force_balance
    )
    assert "position_lo" not in frame.log


def test_an_unjammed_packing_is_refused():
    packing = at.random_packing(64, 0.5, seed=1)
    with pytest.raises(InputError, match="not jammed"):
        certify(packing, at.ContactModel(2.0))


def test_a_packing_off_its_minimum_is_refused(jammed):
    packing, model = jammed
    shaken = packing.with_positions(
        packing.positions
        + 1e-13 * np.random.default_rng(1).standard_normal(packing.positions.shape)
    )
    with pytest.raises(InputError, match="not relaxed"):
        certify(shaken, model)


def test_another_contact_exponent_is_refused(jammed):
    packing, _ = jammed
    with pytest.raises(InputError, match="alpha"):
        certify(packing, at.ContactModel(2.2))


def test_the_command_certifies_a_file_and_jam_certifies_its_packing(tmp_path, capsys):
    jam = ["jam", "--n", "64", "--seed", "2", "--picture", "none", "--json", "--certify"]
    assert main([*jam, "-o", str(tmp_path / "j.gsd")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["certificate"]["converged"] and out["certificate"]["relative_force_balance"] < 1e-20
    frame = at.read_gsd(tmp_path / "j.gsd")
    assert frame.position_lo is not None and "certificate_force_balance" in frame.log
    assert main(["certify", str(tmp_path / "j.gsd"), "-o", str(tmp_path / "c.gsd"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["iterations"] == 0 and out["converged"] and out["bits"] == "portable"
    fast = ["certify", str(tmp_path / "j.gsd"), "-o", str(tmp_path / "f.gsd"), "--fast", "--json"]
    assert main(fast) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["converged"] and out["bits"].startswith("this machine's")
    assert main(["jam", "--n", "64", "-o", str(tmp_path / "p.gsd"), "--certify", "--pressure",
                 "1e-3"]) == 2  # fmt: skip
    assert "drop --pressure or --certify" in capsys.readouterr().err


def test_the_command_refuses_an_unjammed_file_and_writes_nothing(tmp_path, capsys):
    at.write_gsd(tmp_path / "r.gsd", at.random_packing(64, 0.5, seed=1), model=at.ContactModel())
    assert main(["certify", str(tmp_path / "r.gsd"), "-o", str(tmp_path / "c.gsd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not jammed" in err
    assert not (tmp_path / "c.gsd").exists()


def test_positions_in_any_memory_order_are_certified(jammed):
    packing, model = jammed
    fortran = at.Packing(np.asfortranarray(packing.positions), packing.radii, packing.cell)
    assert certify(fortran, model).certificate.converged


def test_a_rattler_that_touches_its_cage_is_moved_out(jammed):
    packing, model = jammed
    contacts = at.find_contacts(packing, model)
    rattler = np.flatnonzero(rattlers(contacts, packing.n, packing.dim))
    if not rattler.size:
        pytest.skip("no rattler in this packing")
    r = int(rattler[0])
    pairs = NearPairs(packing, model, GAP_REACH)
    near = np.flatnonzero((pairs.first == r) | (pairs.second == r))
    sep = pairs.separations(packing.positions)[near]
    gap = (
        np.linalg.norm(sep, axis=1)
        - (packing.radii[pairs.first] + packing.radii[pairs.second])[near]
    )
    k = int(np.argmin(gap))  # the nearest neighbour: push the rattler into it by 1e-14
    toward = -sep[k] / np.linalg.norm(sep[k]) * (1 if pairs.first[near[k]] == r else -1)
    positions = packing.positions.copy()
    positions[r] += (gap[k] + 1e-14) * toward
    done = certify(packing.with_positions(positions), model)
    assert done.certificate.converged
    overlap = pairs.sums(done.packing.positions, done.position_lo).overlap[0]
    assert not np.any(overlap[near] > 0.0)  # out of every overlap


def test_a_network_that_changes_is_named():
    pairs = type("Pairs", (), {"first": np.array([3, 5]), "second": np.array([4, 9])})()
    with pytest.raises(InputError, match="contact 5-9 formed"):
        _same_network(pairs, np.array([True, False]), np.array([True, True]))
    with pytest.raises(InputError, match="contact 3-4 broke"):
        _same_network(pairs, np.array([True, False]), np.array([False, False]))


def test_a_refinement_cut_short_is_written_and_exits_3(jammed, tmp_path, capsys, monkeypatch):
    packing, model = jammed
    at.write_gsd(tmp_path / "j.gsd", packing, model=model)
    monkeypatch.setattr(analysis, "certify", lambda *a, **k: certify(*a, **k, max_iterations=1))
    code = main(["certify", str(tmp_path / "j.gsd"), "-o", str(tmp_path / "c.gsd")])
    assert code == 3 and "not certified" in capsys.readouterr().err
    frame = at.read_gsd(tmp_path / "c.gsd")
    assert frame.log["certificate_converged"][()] == 0.0
    assert frame.log["certificate_iterations"][()] == 1.0


def test_an_exponent_without_double_double_powers_is_refused_at_the_door(tmp_path, capsys):
    code = main(["jam", "--n", "64", "--certify", "--alpha", "2.2", "-o", str(tmp_path / "j.gsd")])
    assert code == 2 and "--alpha" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def bisected():
    model = at.ContactModel(2.0)
    jammed = at.jam(at.random_packing(128, 0.8, seed=5), model)
    return jammed, bisect_jamming_point(jammed.packing, model, 1e-12), model


def test_the_jamming_point_is_bracketed_to_1e_12_inside_float64_s_bracket(bisected):
    jammed, point, model = bisected
    assert 0.0 < point.phi_high - point.phi_low <= 1e-12
    assert jammed.phi_low <= point.phi_low < point.phi_high <= jammed.phi_c
    cert = point.jammed.certificate
    assert point.jammed.packing.phi == point.phi_high and cert.converged
    # at ~1e-12 above its jamming point: pressure ~1e-13, still isostatic and stable, every
    # force balanced to double-double's floor (checked in decimal, independently)
    assert 0.0 < cert.pressure < 1e-11 and cert.excess_contacts >= 0
    assert cert.lowest_eigenvalue > 0.0
    largest, _ = decimal_force_balance(point.jammed.packing, point.jammed.position_lo, model)
    assert largest < Decimal("1e-29")


def test_below_the_bracket_the_network_holds_only_in_tension(bisected):
    _, point, model = bisected
    packing = point.jammed.packing
    pairs = NearPairs(packing, model, GAP_REACH)
    hi, lo = packing.positions.copy(), point.jammed.position_lo.copy()
    sums = pairs.sums(hi, lo)
    _, rattler = contact_network(pairs, hi, sums)
    bonds = ~(rattler[pairs.first] | rattler[pairs.second]) & (sums.overlap[0] > 0.0)
    radii = packing.radii * (point.phi_low / point.phi_high) ** 0.5
    stiffness = pairs.stiffness.copy()
    verdict, _, _, _ = _trial(
        pairs, stiffness, hi, lo, radii, bonds, rattler, _KeptFactor(packing, model)
    )
    assert verdict is False


def stored(name):
    """A packing of ``tests/data/jammed_<name>.npz`` and its float64 bracket."""
    data = np.load(DATA / f"jammed_{name}.npz")
    packing = at.Packing(data["positions"], data["radii"], at.Cell(data["h"]))
    return packing, float(data["phi_low"]), float(data["phi_high"])


def test_the_linear_response_finds_the_jamming_point():
    """The certificate's jamming point by linear response lies inside the certified bracket;
    from the float64 packing ~6e-7 above it (stored: N = 256, no contact changes on the way),
    it misses by a second-order term only (measured: 2e-5 of that distance)."""
    packing, _, _ = stored("n256_seed2")
    model = at.ContactModel(2.0)
    point = bisect_jamming_point(packing, model, 1e-12)
    assert point.contacts_shed == point.contacts_formed == point.rearrangements == 0
    bound = point.jammed.certificate
    assert point.phi_low <= bound.linear_phi_c <= point.phi_high
    assert bound.linearity < 1e-6  # ~1e-12 above it the overlaps vanish together
    start = certify(packing, model).certificate
    above = packing.phi - point.phi_high
    assert start.linearity > bound.linearity
    assert abs(start.linear_phi_c - point.phi_high) < 1e-3 * above


def test_a_first_newton_step_along_a_soft_mode_does_not_stop_the_refinement():
    """A stored packing (N = 4096) whose network has a soft mode: the first Newton step moves
    it by ~3e-9 and only halves the largest force; the steps after it converge."""
    packing, _, _ = stored("n4096_seed23")
    cert = certify(packing, at.ContactModel(2.0)).certificate
    assert cert.converged and cert.relative_force_balance <= TARGET and cert.iterations >= 3


def test_the_rates_of_the_linear_response_are_those_of_relaxed_expansions():
    """Each pair's distance grows with an isotropic expansion of the cell at the rate
    ``toward_jamming`` gives: central differences of packings expanded by +-1e-6 and relaxed
    (a packing 1e-3 above jamming, where float64 resolves the change)."""
    model = at.ContactModel(2.0)
    jammed = at.jam(at.random_packing(64, 0.8, seed=1), model).packing
    start = at.Packing(jammed.positions, jammed.radii * 1.001, jammed.cell)
    packing = at.relax(start, model, rtol=1e-11).packing
    pairs = NearPairs(packing, model, GAP_REACH)
    hi = packing.positions.copy()
    sums = pairs.sums(hi, np.zeros_like(hi))
    contacts, rattler = contact_network(pairs, hi, sums)
    overlap = sums.overlap[0] + sums.overlap[1]
    live = ~(rattler[pairs.first] | rattler[pairs.second])
    _, rate, _ = toward_jamming(pairs, hi, overlap, contacts, rattler, live)
    step, lengths = 1e-6, []
    for sign in (1.0, -1.0):
        expanded = packing.deform((1.0 + sign * step) * np.eye(2))
        moved = at.relax(expanded, model, rtol=1e-11).packing
        sep = moved.positions[pairs.first] - moved.positions[pairs.second]
        lengths.append(np.linalg.norm(sep + pairs.images @ moved.cell.h.T, axis=1))
    differences = (lengths[0] - lengths[1]) / (2.0 * step)
    # rates of order one; the relaxations' tolerance (1e-11 of the mean force) leaves ~1e-6
    np.testing.assert_allclose(rate[live], differences[live], rtol=1e-4, atol=2e-5)
    assert np.ptp(rate[live] / np.linalg.norm(pairs.separations(hi), axis=1)[live]) > 0.1


def test_the_linear_response_of_a_compressed_crystal_is_exact():
    """A triangular crystal of equal disks jams at pi / (2 sqrt 3); compressed, every contact
    overlaps alike and the expansion back to it is affine (no relaxation: this checks the
    affine part and the packing fraction), so the extrapolation is exact."""
    nx, ny, a = 8, 8, 0.1
    row = np.arange(nx) * a
    positions = np.array(
        [[x + 0.5 * a * (j % 2), j * a * np.sqrt(3.0) / 2.0] for j in range(ny) for x in row]
    )
    cell = at.Cell.box([nx * a, ny * a * np.sqrt(3.0) / 2.0])
    packing = at.Packing(positions, np.full(nx * ny, 0.5 * a * (1.0 + 1e-5)), cell)
    cert = certify(packing, at.ContactModel(2.0)).certificate
    assert cert.excess_contacts == 3 * nx * ny - (2 * (nx * ny - 1) + 1)
    assert cert.linearity < 1e-9
    assert cert.linear_phi_c == pytest.approx(np.pi / (2.0 * np.sqrt(3.0)), rel=1e-13)


def test_jam_certify_bisects_below_float64_and_refuses_it_otherwise(tmp_path, capsys):
    out = tmp_path / "j.gsd"
    args = ["jam", "--n", "64", "--seed", "3", "--picture", "none", "--json", "-o", str(out)]
    assert main([*args, "--epsilon", "1e-12"]) == 2
    assert "--certify (alpha = 2) bisects in double-double" in capsys.readouterr().err
    assert main([*args, "--epsilon", "1e-12", "--certify"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["phi_high"] - result["phi_low"] <= 1e-12
    march = result["bisected_in_double_double"]
    assert march["float64_phi_high"] >= result["phi_high"] >= march["float64_phi_low"]
    assert march["float64_phi_high"] - march["float64_phi_low"] <= START_EPSILON  # float64 first
    assert result["pressure"] == result["certificate"]["pressure"] < 1e-11
    assert result["bits"] == f"{MARCH_BITS}; its float64 jam: portable"
    frame = at.read_gsd(out)
    assert frame.packing.phi == result["phi_high"] and frame.position_lo is not None


@pytest.mark.parametrize(
    "name", ["n4096_seed1", "n4096_seed2", "n1024_seed108", "n1024_seed32", "n1024_seed80"]
)
def test_packings_that_shed_contacts_or_rearrange_are_bracketed(name):
    """Packings jammed once and stored (a jam's trajectory differs between CPUs) whose march
    meets what a plain continuation cannot: two hyperstatic ones (N = 4096, 5 and 7 contacts
    above isostatic at epsilon 1e-6) shed contacts; on the first, rattlers left with too few
    bonds have no room in the cage that closes in on them and are readmitted; on the second, a
    contact parts and leaves the network unstable, held by a gap that closes along the unstable
    mode; on the third (N = 1024), an isostatic network turns floppy when a contact parts at a
    pressure of ~1e-8, and the packing rearranges; on the fourth, the contact parts within
    1e-13 of the last jammed trial, a change float64 cannot see, so the rearrangement starts
    along the unstable mode; on the fifth, a trial whose network comes apart under load (its
    tensile contacts part and the rest cascade into rattlers at a pressure of ~1e-8) is not
    unjammed: the packing stays jammed ~3e-8 below it. Every bracket closes to 1e-12 inside
    float64's, at a jammed bound whose pressure vanishes with the bracket."""
    data = np.load(DATA / f"jammed_{name}.npz")
    packing = at.Packing(data["positions"], data["radii"], at.Cell(data["h"]))
    model = at.ContactModel(2.0)
    point = bisect_jamming_point(packing, model, 1e-12)
    assert 0.0 < point.phi_high - point.phi_low <= 1e-12
    assert float(data["phi_low"]) <= point.phi_low < point.phi_high <= float(data["phi_high"])
    if name == "n4096_seed1":
        assert point.contacts_shed > 0 and point.rattlers_readmitted > 0
    if name == "n4096_seed2":
        assert point.contacts_shed > 0 and point.instabilities > 0
    if name in ("n1024_seed108", "n1024_seed32"):
        assert point.rearrangements > 0
    cert = point.jammed.certificate
    assert cert.converged and cert.lowest_eigenvalue > 0.0 and cert.pressure < 1e-11
    # every rattler clear of its cage at the certified point
    pairs = NearPairs(point.jammed.packing, model, GAP_REACH)
    sums = pairs.sums(point.jammed.packing.positions, point.jammed.position_lo)
    _, rattler = contact_network(pairs, point.jammed.packing.positions, sums)
    overlap = sums.overlap[0] + sums.overlap[1]
    assert not np.any((overlap > 0.0) & (rattler[pairs.first] | rattler[pairs.second]))


def test_a_march_resumed_from_any_checkpoint_ends_where_an_uninterrupted_one_does():
    """A march that rearranges (its near pairs then those of the relaxed packing), resumed from
    its states just before and just after the rearrangement, brackets the same point with the
    same certified positions, bit for bit."""
    packing, _, _ = stored("n1024_seed108")
    model = at.ContactModel(2.0)
    states = []
    whole = bisect_jamming_point(packing, model, 1e-12, on_checkpoint=states.append)
    assert whole.rearrangements > 0 and len(states) >= 2
    assert [s.counts[0] for s in states] == [8 * (k + 1) for k in range(len(states))]
    after = next(s for s in states if s.counts[5] > 0)
    before = [s for s in states if s.counts[5] == 0][-1]
    written_before_lifts = replace(before, counts=before.counts[:6])  # six counts: none lifted
    for state in (before, after, written_before_lifts):
        again = bisect_jamming_point(packing, model, 1e-12, resume=state)
        assert (again.phi_low, again.phi_high) == (whole.phi_low, whole.phi_high)
        assert again.march() == whole.march()
        np.testing.assert_array_equal(
            again.jammed.packing.positions, whole.jammed.packing.positions
        )
        np.testing.assert_array_equal(again.jammed.position_lo, whole.jammed.position_lo)


def test_a_rearrangement_float64_cannot_resolve_lands_jammed_higher():
    """A rearrangement that lands within float64's resolution of its own jamming point (stored:
    3D N = 1024, seed 74 of the criticality study, where the network of the last jammed trial
    gave way): float64 finds no minimum there (a saddle it cannot leave, held by pairs that
    touch with no force); ``START_EPSILON`` higher the same start lands jammed, its network
    balanced in double-double."""
    data = np.load(DATA / "rearranged_d3_n1024_seed74.npz")
    phi = float(data["phi"])
    start = at.Packing(data["positions"], data["radii"], at.Cell(data["h"]))
    model = at.ContactModel(2.0)
    with pytest.raises(ConvergenceError, match="found no minimum"):
        _landing(start, model, phi, _KeptFactor(start, model))
    up = phi + START_EPSILON
    lifted = at.Packing(start.positions, start.radii * root(up / phi, 3), start.cell)
    landing = _landing(lifted, model, up, _KeptFactor(lifted, model))
    assert landing is not None and landing.trial[0] is True


def test_rattlers_boxed_in_by_rattlers_move_with_them(monkeypatch):
    """3D N = 256, seed 173 of the criticality study (stored: its float64 jam to 1e-7): a cluster
    of four rattlers whose cage closes as ``phi`` falls. Moved with only their direct rattler
    neighbours, two of them found no room (the other two held them in), were readmitted with
    fewer than d + 1 contacts, and every such trial gave no verdict: the march crept down
    ~2e-13 a trial through spurious rearrangements and was refused after 2000 trials. With the
    rattler neighbours of those moved too (``TOGETHER_DEPTH``), it brackets the jamming point
    with no rearrangement, inside the float64 bracket."""
    packing, low, high = stored("d3_n256_seed173")
    model = at.ContactModel(2.0)
    point = bisect_jamming_point(packing, model, 1e-12, max_trials=60)
    assert point.rearrangements == point.rattlers_readmitted == 0
    assert 0.0 < point.phi_high - point.phi_low <= 1e-12
    assert low < point.phi_high < high
    assert abs(point.phi_high - 0.6389814840386967) < 2e-12  # the same natively and emulated
    certificate = point.jammed.certificate
    assert certificate.converged and certificate.excess_contacts == 0
    monkeypatch.setattr(certify_package, "TOGETHER_DEPTH", 1)  # the direct neighbours only
    with pytest.raises(ConvergenceError, match="no bracket of 1e-12 in 60 trials"):
        bisect_jamming_point(packing, model, 1e-12, max_trials=60)


def test_a_march_takes_a_rearrangement_it_cannot_resolve_higher_once(monkeypatch):
    """The march's first rearrangement made unresolvable (its landing raises, as float64's does
    at the rearranged packing's own jamming point): the march lands it ``START_EPSILON``
    higher and brackets the packing from there; with no lift allowed, it refuses."""
    packing, _, _ = stored("n1024_seed108")
    model = at.ContactModel(2.0)
    real, calls = bisection._landing, []

    def unresolved_first(start, model, phi, kept):
        calls.append(phi)
        if len(calls) == 1:
            raise ConvergenceError("unresolved")
        return real(start, model, phi, kept)

    monkeypatch.setattr(bisection, "_landing", unresolved_first)
    point = bisect_jamming_point(packing, model, 1e-12)
    assert calls[1] == calls[0] + START_EPSILON
    assert point.lifted == 1 and point.rearrangements >= 1
    assert 0.0 < point.phi_high - point.phi_low <= 1e-12
    assert point.jammed.certificate.converged and point.jammed.certificate.pressure < 1e-11
    calls.clear()
    monkeypatch.setattr(bisection, "MAX_LIFTS", 0)
    with pytest.raises(ConvergenceError, match="unresolved; the march took 0"):
        bisect_jamming_point(packing, model, 1e-12)


def test_jam_certify_killed_in_its_march_resumes_to_the_same_packing(tmp_path, capsys, monkeypatch):
    """The march's state is written beside the trajectory every 8 trials; a run stopped after
    the first (Ctrl-C: exit 130) continues with ``--resume`` to the packing an uninterrupted run
    writes, and removes the file."""
    import athermal.studies.jammed as jammed

    args = ["jam", "--n", "256", "--seed", "3", "--certify", "--epsilon", "1e-12"]
    args += ["--picture", "none", "--json", "--quiet"]
    assert main([*args, "-o", str(tmp_path / "whole.gsd")]) == 0
    whole = json.loads(capsys.readouterr().out)
    saved = jammed.save_march

    def stop(path, state, key):
        saved(path, state, key)
        raise KeyboardInterrupt

    monkeypatch.setattr(jammed, "save_march", stop)
    assert main([*args, "-o", str(tmp_path / "cut.gsd")]) == 130
    march = tmp_path / "cut.steps.march.npz"
    assert march.is_file()
    monkeypatch.setattr(jammed, "save_march", saved)
    capsys.readouterr()
    assert main([*args, "-o", str(tmp_path / "cut.gsd"), "--resume"]) == 0
    resumed = json.loads(capsys.readouterr().out)
    assert not march.exists()
    assert resumed["phi_high"] == whole["phi_high"] and resumed["phi_low"] == whole["phi_low"]
    assert resumed["bisected_in_double_double"] == whole["bisected_in_double_double"]
    one, two = at.read_gsd(tmp_path / "whole.gsd"), at.read_gsd(tmp_path / "cut.gsd")
    np.testing.assert_array_equal(one.packing.positions, two.packing.positions)
    np.testing.assert_array_equal(one.position_lo, two.position_lo)


def test_float64_epsilon_is_the_march_start_below_resolution():
    """float64 jams to the bracket asked where it takes the verdict, else to the march's start."""
    assert float64_epsilon(1e-6) == 1e-6
    assert float64_epsilon(RESOLUTION) == RESOLUTION
    assert float64_epsilon(1e-12) == START_EPSILON
