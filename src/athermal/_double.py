"""Double-double arithmetic: a number held as the unevaluated sum ``hi + lo`` of two float64
with ``|lo| <= ulp(hi) / 2`` (106 bits of significand, about 32 decimal digits).

The operations are the error-free transformations of Dekker (1971) and Knuth (TAOCP vol. 2),
assembled as in Hida, Li & Bailey's QD library (*Algorithms for quad-double precision floating
point arithmetic*, ARITH-15, 2001): ``two_sum`` gives the rounding error of a sum exactly,
``two_prod`` that of a product by Dekker's splitting (exact in float64 without a fused
multiply-add, so on every CPU the result is the same bits). They need round-to-nearest float64
arithmetic without reassociation, which the plain ``numba.njit`` kernels here keep (no
``fastmath``). Inlined into the kernels that call them (the contact law's double-double form,
:mod:`athermal.model.law`; the certificate's sums, :mod:`athermal.certify.extended`).
"""

from __future__ import annotations

import numba
import numpy as np

SPLITTER = 134217729.0
"""``2^27 + 1``: Dekker's constant splitting a float64 into two halves of 26 bits."""

_jit = numba.njit(cache=True, inline="always")


@_jit
def two_sum(a, b):  # type: ignore[no-untyped-def]
    """``(s, e)`` with ``s = fl(a + b)`` and ``s + e = a + b`` exactly (Knuth)."""
    s = a + b
    v = s - a
    return s, (a - (s - v)) + (b - v)


@_jit
def quick_two_sum(a, b):  # type: ignore[no-untyped-def]
    """``two_sum`` for ``|a| >= |b|`` (Dekker)."""
    s = a + b
    return s, b - (s - a)


@_jit
def _split(a):  # type: ignore[no-untyped-def]
    t = SPLITTER * a
    hi = t - (t - a)
    return hi, a - hi


@_jit
def two_prod(a, b):  # type: ignore[no-untyped-def]
    """``(p, e)`` with ``p = fl(a b)`` and ``p + e = a b`` exactly (Dekker's splitting)."""
    p = a * b
    ah, al = _split(a)
    bh, bl = _split(b)
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


@_jit
def add(ah, al, bh, bl):  # type: ignore[no-untyped-def]
    """``a + b`` in double-double (QD's accurate addition)."""
    s, e = two_sum(ah, bh)
    t, f = two_sum(al, bl)
    e += t
    s, e = quick_two_sum(s, e)
    e += f
    return quick_two_sum(s, e)


@_jit
def sub(ah, al, bh, bl):  # type: ignore[no-untyped-def]
    """``a - b`` in double-double."""
    return add(ah, al, -bh, -bl)


@_jit
def mul(ah, al, bh, bl):  # type: ignore[no-untyped-def]
    """``a b`` in double-double."""
    p, e = two_prod(ah, bh)
    e += ah * bl + al * bh
    return quick_two_sum(p, e)


@_jit
def div(ah, al, bh, bl):  # type: ignore[no-untyped-def]
    """``a / b`` in double-double (three float64 quotient digits, QD's accurate division)."""
    q1 = ah / bh
    ph, pl = mul(q1, 0.0, bh, bl)
    rh, rl = sub(ah, al, ph, pl)
    q2 = rh / bh
    ph, pl = mul(q2, 0.0, bh, bl)
    rh, rl = sub(rh, rl, ph, pl)
    q3 = rh / bh
    q1, q2 = quick_two_sum(q1, q2)
    return add(q1, q2, q3, 0.0)


@_jit
def sqrt(ah, al):  # type: ignore[no-untyped-def]
    """``sqrt(a)`` in double-double for ``a >= 0`` (one Newton step from float64, Karp)."""
    if ah <= 0.0:
        return 0.0, 0.0
    x = 1.0 / np.sqrt(ah)
    ax = ah * x
    sh, sl = two_prod(ax, ax)
    dh, _ = sub(ah, al, sh, sl)
    return two_sum(ax, dh * (x * 0.5))


@_jit
def power(dh, dl, half_steps):  # type: ignore[no-untyped-def]
    """``delta^(half_steps / 2)`` in double-double for an integer ``half_steps >= 0``."""
    ph, pl = 1.0, 0.0
    for _ in range(half_steps // 2):
        ph, pl = mul(ph, pl, dh, dl)
    if half_steps % 2:
        sh, sl = sqrt(dh, dl)
        ph, pl = mul(ph, pl, sh, sl)
    return ph, pl
