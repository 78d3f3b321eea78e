import numpy as np
import pytest

from athermal.errors import InputError
from athermal.fitting import fit_power_law


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
    from athermal.fitting import fit_jamming_point

    dphi = np.logspace(-7, -1, 25)
    phi = 0.84 + 3e-6 + dphi  # the data start 3e-6 above the true jamming point
    phi_0, law = fit_jamming_point(phi, 0.5 * (phi - 0.84) ** 1.5)
    assert phi_0 == pytest.approx(0.84, abs=1e-9)
    assert law.exponent == pytest.approx(1.5, abs=1e-6) and law.prefactor == pytest.approx(0.5)
    naive = fit_power_law(dphi, 0.5 * (phi - 0.84) ** 1.5)  # Delta phi from the data's start
    assert abs(naive.exponent - 1.5) > 0.1
    with pytest.raises(InputError, match="at least 4"):
        fit_jamming_point(phi[:3], phi[:3])


def test_jammed_branch_starts_after_the_last_unjammed_step():
    from types import SimpleNamespace

    from athermal.protocols.compress import jammed_branch

    def step(p, dz):
        return SimpleNamespace(pressure=p, z_excess=dz)

    steps = [step(1e-6, 0.0), step(1e-13, -0.2), step(0.0, -4.0), step(2e-5, 0.01), step(3e-5, 0)]
    assert jammed_branch(steps) == steps[3:]
    assert jammed_branch(steps[3:]) == steps[3:]
