import numpy as np
import pytest

from athermal.minimize.linesearch import strong_wolfe


def wolfe_ok(phi, res, f0, g0, c1=1e-4, c2=0.9):
    f, df = phi(res.step)
    return f <= f0 + c1 * res.step * g0 and abs(df) <= c2 * abs(g0)


CASES = {
    "quadratic": lambda a: ((a - 3.0) ** 2, 2.0 * (a - 3.0)),
    "quartic": lambda a: ((a - 0.7) ** 4 + 0.1 * a**2, 4.0 * (a - 0.7) ** 3 + 0.2 * a),
    "stiff": lambda a: (1e4 * (a - 1e-3) ** 2, 2e4 * (a - 1e-3)),
    "non-convex": lambda a: (-np.sin(3.0 * a) + 0.1 * a * a, -3.0 * np.cos(3.0 * a) + 0.2 * a),
}


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("step", [1e-3, 1.0, 50.0])
@pytest.mark.parametrize("c2", [0.9, 0.1])
def test_accepted_steps_satisfy_the_strong_wolfe_conditions(name, step, c2):
    phi = CASES[name]
    f0, g0 = phi(0.0)
    res = strong_wolfe(phi, f0, g0, step, c2=c2)
    assert res.ok
    assert wolfe_ok(phi, res, f0, g0, c2=c2)
    assert res.evaluations <= 25


def test_step_max_is_respected():
    phi = CASES["quadratic"]
    f0, g0 = phi(0.0)
    res = strong_wolfe(phi, f0, g0, 1.0, step_max=0.5, c2=0.1)
    # the minimum at 3 lies beyond the cap: the capped step is taken, with sufficient decrease
    assert res.ok and res.step == 0.5
    assert res.value <= f0 + 1e-4 * 0.5 * g0 and res.slope < 0


def test_works_below_energy_round_off_from_the_gradient_alone():
    """A minimum whose energy variation (1e-22) is lost in a 1e-3 energy: only phi' sees it."""

    def phi(a):
        return 1e-3 + 1e-22 * (a - 2.0) ** 2, 2e-22 * (a - 2.0)

    f0, g0 = phi(0.0)
    assert phi(2.0)[0] == f0  # the energy cannot tell the minimum apart
    res = strong_wolfe(phi, f0, g0, 1.0)
    assert res.ok
    assert abs(res.slope) <= 0.9 * abs(g0)
    assert 0.2 <= res.step <= 3.8


def test_zero_energy_ends_at_once():
    def phi(a):
        return (0.0, 0.0) if a >= 0.5 else ((0.5 - a) ** 2, -2 * (0.5 - a))

    res = strong_wolfe(phi, *phi(0.0), 1.0)
    assert res.ok and res.value == 0.0 and res.evaluations == 1


def test_ascent_direction_is_rejected():
    with pytest.raises(ValueError, match="descent"):
        strong_wolfe(CASES["quadratic"], 0.0, 1.0, 1.0)
