"""Same input, same bits: the portable arithmetic against exact references, and the golden runs
(``tests/golden.py``) reproduced exactly under emulated CPUs (numba's compile target, OpenBLAS's
kernels and NumPy's SIMD paths chosen as on other machines), in subprocesses."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from decimal import Decimal, getcontext
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from athermal._portable import (
    dot,
    power,
    power_of,
    root,
    row_dots,
    row_norms,
    sin_2pi,
    transform,
    upper_inverse,
    vdot,
    vnorm,
)

HERE = Path(__file__).parent
GOLDEN = json.loads((HERE / "data" / "golden.json").read_text())

# Emulated CPUs: a compile target without AVX or FMA, Haswell's (AVX2, FMA), OpenBLAS's kernels of
# an old and of an AVX2 CPU, NumPy without its AVX-512 paths (SVML's pow, sin, exp, log)
EMULATED = {
    "generic, Prescott BLAS": {"NUMBA_CPU_NAME": "generic", "OPENBLAS_CORETYPE": "Prescott"},
    "haswell, Haswell BLAS, no AVX-512 NumPy": {
        "NUMBA_CPU_NAME": "haswell",
        "OPENBLAS_CORETYPE": "Haswell",
        "NPY_DISABLE_CPU_FEATURES": "AVX512F,AVX512CD,AVX512_SKX,AVX512_CLX,AVX512_CNL,"
        "AVX512_ICL,AVX512_SPR",
    },
}


def test_dot_sums_in_its_fixed_order():
    rng = np.random.default_rng(3)
    for n in (0, 1, 7, 8, 9, 1000, 1027):
        a, b = rng.normal(size=n), rng.normal(size=n)
        lanes = [0.0] * 8
        for p in range(n):
            lanes[p % 8] += a[p] * b[p]
        expected = ((lanes[0] + lanes[1]) + (lanes[2] + lanes[3])) + (
            (lanes[4] + lanes[5]) + (lanes[6] + lanes[7])
        )
        assert dot(a, b) == expected  # bit for bit, whatever the CPU
        assert vdot(a.reshape(-1, 1), b) == expected
        assert math.isclose(dot(a, b), math.fsum(a * b), rel_tol=1e-12, abs_tol=1e-12)
    v = rng.normal(size=33)
    assert vnorm(v) == math.sqrt(dot(v, v))


def test_row_products_and_the_cell_matrices():
    rng = np.random.default_rng(4)
    x, m = rng.normal(size=(50, 3)), rng.normal(size=(3, 3))
    expected = np.array([[(m[r, 0] * p[0] + m[r, 1] * p[1]) + m[r, 2] * p[2] for r in range(3)]
                         for p in x])  # fmt: skip
    np.testing.assert_array_equal(transform(x, m), expected)
    np.testing.assert_array_equal(row_dots(x, x), (x[:, 0] ** 2 + x[:, 1] ** 2) + x[:, 2] ** 2)
    np.testing.assert_array_equal(row_norms(x), np.sqrt(row_dots(x, x)))
    h = np.triu(rng.uniform(0.5, 2.0, size=(3, 3)))
    np.testing.assert_allclose(upper_inverse(h) @ h, np.eye(3), atol=1e-15)
    assert np.all(np.tril(upper_inverse(h), -1) == 0.0)


def test_powers_of_half_integers_are_products_and_one_square_root():
    x = np.array([0.0, 1e-12, 3e-7, 0.25, 1.0, 1.7])
    np.testing.assert_array_equal(power(x, 2.0), x * x)
    np.testing.assert_array_equal(power(x, 1.5), x * np.sqrt(x))
    np.testing.assert_array_equal(power(x, 2.5), (x * x) * np.sqrt(x))
    np.testing.assert_array_equal(power(x, 0.5), np.sqrt(x))
    np.testing.assert_array_equal(power(x, 0.0), np.ones_like(x))
    assert power(x, 3.0).shape == x.shape and power(2.0, 2.0).shape == ()
    assert power_of(1.7, 2.5) == power(1.7, 2.5)


@pytest.mark.parametrize("e", [0.4, 0.6, 1.2, 1.7, 2.2, 3.5 + 1e-9])
def test_other_powers_against_extended_precision(e):
    getcontext().prec = 40
    for x in (1e-14, 2.5e-9, 3e-4, 0.5, 0.99, 1.0, 1.3, 7.0):
        exact = Decimal(x) ** Decimal(e)
        got = power_of(x, e)
        # exp(t) carries the rounding of t = e ln x: a relative error of a few ulp of |t|
        bound = (abs(e * math.log(x)) + 8.0) * 2.0**-52
        assert abs(Decimal(got) - exact) <= Decimal(bound) * exact, (x, e)
    assert power_of(0.0, 0.6) == 0.0


def test_cube_roots_are_correctly_rounded():
    rng = np.random.default_rng(5)
    getcontext().prec = 50
    for x in [*rng.uniform(1e-6, 10.0, 300), 8.0, 27.0, 1e-300, 0.125]:
        y = root(float(x), 3)
        target = Decimal(float(x)) ** (Decimal(1) / Decimal(3))
        for other in (math.nextafter(y, 0.0), math.nextafter(y, math.inf)):
            assert abs(Decimal(y) - target) <= abs(Decimal(other) - target)
    assert root(8.0, 3) == 2.0 and root(2.0, 2) == math.sqrt(2.0) and root(3.0, 1) == 3.0
    assert Fraction(root(27.0, 3)) ** 3 == 27


def test_sine_of_full_turns():
    s = np.linspace(-2.0, 2.0, 4001)
    np.testing.assert_allclose(sin_2pi(s), np.sin(2.0 * np.pi * s), atol=3e-15)
    assert sin_2pi(np.array([0.25]))[0] == 1.0 and sin_2pi(np.array([0.5]))[0] == 0.0


def _golden_runs(env: dict[str, str], cache: Path) -> dict[str, list[str]]:
    environment = {**os.environ, **env, "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run(
        [sys.executable, str(HERE / "golden.py")],
        env=environment,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_golden_values_on_this_cpu():
    """Every run reproduces the stored bits (``tests/data/golden.json``) on this CPU."""
    import golden  # type: ignore[import-not-found]

    assert golden.runs() == GOLDEN


@pytest.mark.parametrize("name", sorted(EMULATED))
def test_golden_values_on_emulated_cpus(name, tmp_path_factory):
    """The same bits where numba compiles for another CPU, OpenBLAS runs another CPU's kernels
    and NumPy leaves its AVX-512 paths out (a fresh compile cache for each)."""
    cache = tmp_path_factory.mktemp("numba-cache")
    assert _golden_runs(EMULATED[name], cache) == GOLDEN


def test_amg_and_arpack_are_the_same_from_run_to_run():
    """pyamg's setup and ARPACK's start draw from a fixed seed, and leave the caller's global
    random state as it was: two relaxations with AMG give the same bits."""
    import athermal as at
    from athermal.linalg import arpack_start

    start = at.random_packing(256, 0.86, seed=1)
    minimizer = at.Minimizer("lbfgs", "exp", solver="amg")
    np.random.seed(7)  # noqa: NPY002 (the legacy state pyamg draws from)
    before = np.random.get_state()[1].copy()  # noqa: NPY002
    runs = [at.relax(start, at.ContactModel(2.5), minimizer, rtol=1e-9) for _ in range(2)]
    np.testing.assert_array_equal(np.random.get_state()[1], before)  # noqa: NPY002
    assert runs[0].iterations == runs[1].iterations and runs[0].energy == runs[1].energy
    np.testing.assert_array_equal(runs[0].packing.positions, runs[1].packing.positions)
    np.testing.assert_array_equal(arpack_start(10), arpack_start(10))


def test_the_commands_say_whether_their_bits_are_portable(tmp_path, capsys):
    """``relax`` prints ``bits``: ``portable`` on the default path, the reason with AMG."""
    from athermal.cli import main

    start = str(tmp_path / "p.gsd")
    assert main(["random", "--n", "64", "--phi", "0.86", "-o", start, "--json"]) == 0
    capsys.readouterr()
    for solver, expected in (("direct", "portable"), ("amg", "AMG")):
        out = str(tmp_path / f"{solver}.gsd")
        argv = ["relax", start, "-o", out, "--precon", "exp", "--solver", solver, "--json"]
        assert main(argv) == 0
        assert json.loads(capsys.readouterr().out)["bits"].startswith(expected)
