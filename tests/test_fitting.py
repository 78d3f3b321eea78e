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
