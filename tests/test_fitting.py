import numpy as np
import pytest

from athermal.analysis.fitting import fit_power_law
from athermal.errors import InputError


def test_exact_power_law_is_recovered_with_zero_error():
    x = np.logspace(-7, -1, 13)
    fit = fit_power_law(x, 3.0 * x**1.5)
    assert fit.exponent == pytest.approx(1.5, abs=1e-12)
    assert fit.prefactor == pytest.approx(3.0, rel=1e-10)
    assert fit.stderr < 1e-10 and fit.points == 13


def test_noisy_power_law_error_bar_covers_the_truth():
    rng = np.random.default_rng(3)
    x = np.logspace(-6, -1, 40)
    y = x**0.5 * np.exp(rng.normal(0.0, 0.1, x.size))
    fit = fit_power_law(x, y)
    assert 0.0 < fit.stderr < 0.05
    assert abs(fit.exponent - 0.5) < 3 * fit.stderr


def test_window_and_non_positive_points_are_left_out():
    x = np.array([1e-8, 1e-4, 1e-3, 1e-2, 1e-1, 1.0])
    y = np.array([5.0, 1e-4, 1e-3, 1e-2, -1.0, 7.0])
    fit = fit_power_law(x, y, lower=1e-5, upper=0.5)
    assert fit.points == 3 and fit.exponent == pytest.approx(1.0)
    with pytest.raises(InputError, match="at least 3"):
        fit_power_law(x, y, lower=1e-3, upper=0.5)


def test_jamming_point_and_exponent_are_recovered_from_an_offset_power_law():
    from athermal.analysis.fitting import fit_jamming_point

    dphi = np.logspace(-7, -1, 25)
    phi = 0.84 + 3e-6 + dphi  # the data start 3e-6 above the true jamming point
    phi_0, law = fit_jamming_point(phi, 0.5 * (phi - 0.84) ** 1.5)
    assert phi_0 == pytest.approx(0.84, abs=1e-9)
    assert law.exponent == pytest.approx(1.5, abs=1e-6) and law.prefactor == pytest.approx(0.5)
    naive = fit_power_law(dphi, 0.5 * (phi - 0.84) ** 1.5)  # Delta phi from the data's start
    assert abs(naive.exponent - 1.5) > 0.1
    with pytest.raises(InputError, match="at least 4"):
        fit_jamming_point(phi[:3], phi[:3])


def _step(dphi, p, g, dz, events=(), n=16384, rattlers=24):
    """A compression step's row as :class:`~athermal.protocols.CompressionStep` gives it."""
    from types import SimpleNamespace

    row = {
        "n": n,
        "n_rattlers": rattlers,
        "delta_phi": dphi,
        "pressure": p,
        "shear_modulus": g,
        "z_excess": dz,
        "events": ";".join(events),
    }
    return SimpleNamespace(
        delta_phi=dphi, phi=0.84 + dphi, events=tuple(events), row=lambda: dict(row)
    )


def test_scaling_fits_use_the_protocols_delta_phi_and_say_which_points():
    """The fits are against the protocol's Delta phi (no free phi_c); they leave out, and count
    by reason, the steps below the window, with G < 0, unjammed or after the packing left its
    basin, z - z_iso of fewer than 10 contacts, and p and G with Delta phi N^2 < 1."""
    from athermal.protocols import scaling_exponents

    dphis = np.logspace(-7, -1, 7)
    steps = [_step(d, 0.3 * d, 0.2 * d**0.5, 2.0 * d**0.5) for d in dphis]
    steps[3] = _step(dphis[3], 0.3 * dphis[3], -1e-4, 2.0 * dphis[3] ** 0.5, ["unstable to shear"])
    # unjammed: every particle a rattler, a pressure of round-off (6e-15 measured at N = 48);
    # the step after it is in another basin: fitted against the old phi_c it would mislead
    steps[5] = _step(dphis[5], 6e-15, 0.0, -4.0, ["unjammed", "pressure drop"], rattlers=16384)
    fits = scaling_exponents(steps)
    assert fits.phi_c == pytest.approx(0.84) and fits.left_basin == pytest.approx(1e-2)
    assert fits.pressure.exponent == pytest.approx(1.0) and fits.pressure.points == 4
    assert fits.pressure.x_min == pytest.approx(1e-6) and fits.pressure.x_max == pytest.approx(1e-3)
    assert fits.shear_modulus.exponent == pytest.approx(0.5) and fits.shear_modulus.points == 3
    assert fits.z_excess.exponent == pytest.approx(0.5) and fits.z_excess.points == 4
    after = "after the packing left its basin"
    assert fits.left_out["pressure"] == {"outside the fitted range": 1, "unjammed": 1, after: 1}
    assert fits.left_out["shear_modulus"]["unstable to shear (G < 0)"] == 1
    assert fits.events == {
        "unjammed": 1,
        "pressure drop": 1,
        "saddle left": 0,
        "unstable to shear": 1,
    }
    # N = 1024: z - z_iso = 2 sqrt(Delta phi) is 10 contacts of 1000 from Delta phi = 1e-4 up;
    # Delta phi N^2 >= 1 from 1e-6 up
    small = [_step(d, 0.3 * d, 0.2 * d**0.5, 2.0 * d**0.5, n=1024) for d in dphis]
    fits = scaling_exponents(small, lower=1e-7)
    assert fits.left_out["pressure"] == {"finite size (Delta phi N^2 < 1)": 1}
    assert fits.left_out["z_excess"] == {"fewer than 10 contacts beyond isostatic": 3}
    assert fits.z_excess.x_min == pytest.approx(1e-4) and fits.z_excess.points == 4
    assert fits.left_basin is None


def test_rows_without_a_particle_count_and_fits_at_one_x_are_refused():
    from athermal.protocols.compress import fit_points

    row = _step(1e-3, 3e-4, 1e-2, 0.1).row()
    del row["n"]
    with pytest.raises(InputError, match="particle count"):
        fit_points([row], "pressure")
    with pytest.raises(InputError, match="distinct"):
        fit_power_law([1e-3, 1e-3, 1e-3], [1.0, 2.0, 3.0])


def test_pooled_fits_of_an_ensemble_leave_out_unjammed_steps():
    """The ensemble's pooled fit takes each row as the realizations' own fits do: a step that
    unjammed (all rattlers, a pressure of round-off) is no data point of ``p ~ Delta phi``, nor
    is any later step of that compression."""
    from athermal.studies.ensemble import CompressionRecord, pooled_exponent

    def rows(pressures, unjammed=()):
        return tuple(
            _step(d, p, 0.0, 0.0, ["unjammed", "pressure drop"] if i in unjammed else []).row()
            for i, (d, p) in enumerate(zip(dphis, pressures, strict=True))
        )

    dphis = np.logspace(-3, -1, 5)
    jammed = CompressionRecord(rows(0.4 * dphis), {}, None, {})
    unjamming = CompressionRecord(
        rows([0.4 * d if i != 3 else 6e-15 for i, d in enumerate(dphis)], (3,)), {}, None, {}
    )
    pooled = pooled_exponent([jammed, unjamming], "pressure")
    assert pooled["exponent"] == pytest.approx(1.0) and pooled["points"] == 8
    assert pooled["delta_phi_range"] == pytest.approx([1e-3, 1e-1])
    assert pooled_exponent([], "pressure") is None
