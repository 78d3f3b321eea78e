"""Arithmetic whose result is the same bits on every IEEE-754 machine: what the paths that decide
a trajectory use in place of BLAS and libm (``docs/decisions.md``, "Same input, same bits").

A BLAS kernel (``np.dot``, ``@``, ``np.linalg.norm``) sums in an order chosen for the CPU it runs
on, and a libm or SIMD ``pow``, ``sin`` or ``cbrt`` rounds as the CPU's variant does; both make a
chaotic relaxation end in another minimum on another machine. Here every result is a fixed
sequence of correctly rounded operations (``+ - * /`` and ``sqrt``):

* :func:`dot` and :func:`norm`: a sum in eight interleaved lanes, combined pairwise; :func:`matvec`
  a dot product a row; :func:`solve_small`: Gaussian elimination for a small dense system;
* :func:`transform`: points times a small matrix, ``(N, d) @ m.T``, each entry summed in order;
  :func:`outer_sum`: a sum of outer products (stress, fabric); :func:`upper_inverse`: the
  inverse of a cell matrix;
* :func:`power` and :func:`power_of`: ``x^e``, for ``e`` a multiple of 1/2 (the contact law's
  2, 2.5 and 3 and their derivatives) as products and one square root, else by series of
  ``exp`` and ``ln``;
* :func:`root`: ``x^(1/d)`` for ``d`` = 1, 2, 3, the radii's scale at a packing fraction;
* :func:`sin_2pi`: ``sin(2 pi s)`` by a fixed polynomial.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from numpy.typing import ArrayLike, NDArray

from ._jit import _jit

LANES = 8
"""Interleaved partial sums of :func:`dot` (element ``p`` goes to lane ``p mod 8``)."""
_LANE_VECTOR = ir.VectorType(ir.DoubleType(), LANES)


def _flat_float64(array: types.Type) -> bool:
    """Whether numba's ``array`` type is a flat C-contiguous float64 array."""
    return (
        isinstance(array, types.Array)
        and array.dtype == types.float64
        and array.layout == "C"
        and array.ndim == 1
    )


@intrinsic
def _add_products(typingctx, lanes, rows, row_at, columns, column_at, blocks):  # type: ignore[no-untyped-def]
    """For ``q < blocks`` in turn and ``k < 8``: ``lanes[r, c, k] += rows[r][row_at[r] + 8 q + k]
    * columns[c][column_at[c] + 8 q + k]`` for every row ``r`` and column ``c`` (``rows`` and
    ``columns`` tuples of one or two flat C-contiguous float64 arrays, ``row_at`` and
    ``column_at`` an offset into each; ``lanes (R, C, 8)``).

    ``R x C`` vectors of eight partial sums, held in registers through the loop, each block one
    vector multiply and one vector add per sum: each lane rounds as the scalar operations would
    (no fused multiply-add: the instructions carry no fast-math flag), so the sums are the same
    bits on any CPU, at the speed of the CPU's vectors, up to four sums in flight."""
    for arrays, at in ((rows, row_at), (columns, column_at)):
        if not (isinstance(arrays, types.BaseTuple) and 1 <= len(arrays) <= 2):
            return None
        if not all(_flat_float64(array) for array in arrays):
            return None
        if not (isinstance(at, types.BaseTuple) and len(at) == len(arrays)):
            return None
    if not (isinstance(lanes, types.Array) and lanes.layout == "C" and lanes.ndim == 3):
        return None
    shape = (len(rows), len(columns))

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        lanes_v, rows_v, row_at_v, columns_v, column_at_v, blocks_v = args
        lanes_t, rows_t, _, columns_t, _, _ = signature.args

        def data(array_type, value):  # type: ignore[no-untyped-def]
            return context.make_array(array_type)(context, builder, value).data

        def vector_at(pointer, offset):  # type: ignore[no-untyped-def]
            return builder.bitcast(builder.gep(pointer, [offset]), _LANE_VECTOR.as_pointer())

        def unpacked(value, count):  # type: ignore[no-untyped-def]
            return [builder.extract_value(value, k) for k in range(count)]

        sums = data(lanes_t, lanes_v)
        into = [
            vector_at(sums, ir.Constant(blocks_v.type, LANES * k))
            for k in range(shape[0] * shape[1])
        ]
        totals = []
        for pointer in into:
            total = cgutils.alloca_once(builder, _LANE_VECTOR)  # a register once promoted
            builder.store(builder.load(pointer, align=8), total)
            totals.append(total)
        row_data = [data(rows_t[k], value) for k, value in enumerate(unpacked(rows_v, shape[0]))]
        column_data = [
            data(columns_t[k], value) for k, value in enumerate(unpacked(columns_v, shape[1]))
        ]
        row_offsets = unpacked(row_at_v, shape[0])
        column_offsets = unpacked(column_at_v, shape[1])
        step = ir.Constant(blocks_v.type, LANES)
        with cgutils.for_range(builder, blocks_v) as loop:
            offset = builder.mul(loop.index, step)
            xs = [
                builder.load(vector_at(pointer, builder.add(at, offset)), align=8)
                for pointer, at in zip(row_data, row_offsets, strict=True)
            ]
            ys = [
                builder.load(vector_at(pointer, builder.add(at, offset)), align=8)
                for pointer, at in zip(column_data, column_offsets, strict=True)
            ]
            for r in range(shape[0]):
                for c in range(shape[1]):
                    total = totals[shape[1] * r + c]
                    product = builder.fmul(xs[r], ys[c])
                    builder.store(builder.fadd(builder.load(total), product), total)
        for pointer, total in zip(into, totals, strict=True):
            builder.store(builder.load(total), pointer, align=8)
        return context.get_dummy_value()

    return types.void(lanes, rows, row_at, columns, column_at, types.intp), codegen


@_jit
def add_products(lanes, rows, row_at, columns, column_at, count):  # type: ignore[no-untyped-def]
    """``lanes[r, c, k] += sum rows[r][row_at[r] + j] columns[c][column_at[c] + j]`` over
    ``j < count`` with ``j = k mod 8``, in increasing ``j``, for every row and column
    (:func:`_add_products`: tuples of one or two flat C-contiguous arrays, an offset into
    each; ``lanes (R, C, 8)``): up to four dot products' lanes at once."""
    blocks = count // LANES
    _add_products(lanes, rows, row_at, columns, column_at, blocks)
    top = blocks * LANES
    for j in range(top, count):
        for r in range(len(rows)):
            for c in range(len(columns)):
                lanes[r, c, j - top] += rows[r][row_at[r] + j] * columns[c][column_at[c] + j]


@_jit
def lane_total(lanes):  # type: ignore[no-untyped-def]
    """The eight lanes added pairwise: ``((l0 + l1) + (l2 + l3)) + ((l4 + l5) + (l6 + l7))``."""
    return ((lanes[0] + lanes[1]) + (lanes[2] + lanes[3])) + (
        (lanes[4] + lanes[5]) + (lanes[6] + lanes[7])
    )


@_jit
def dot(a, b):  # type: ignore[no-untyped-def]
    """``sum_p a_p b_p`` of two flat C-contiguous float64 vectors of one length, in a fixed
    order: lane ``k`` sums the products ``p = k, k + 8, ...`` in turn (:func:`add_products`),
    and the lanes are added pairwise (:func:`lane_total`)."""
    lanes = np.zeros((1, 1, LANES))
    add_products(lanes, (a.reshape(a.size),), (0,), (b.reshape(b.size),), (0,), a.size)
    return lane_total(lanes[0, 0])


@_jit
def norm(a):  # type: ignore[no-untyped-def]
    """Euclidean norm of a flat float64 vector, ``sqrt(dot(a, a))``."""
    return np.sqrt(dot(a, a))


@_jit
def matvec(m, v):  # type: ignore[no-untyped-def]
    """``m @ v`` for a C-contiguous ``m (r, c)`` and ``v (c,)``: each entry a :func:`dot`."""
    out = np.empty(m.shape[0])
    for i in range(m.shape[0]):
        out[i] = dot(m[i], v)
    return out


@_jit
def solve_small(a, b):  # type: ignore[no-untyped-def]
    """``a^-1 b`` for a small square ``a (n, n)`` and ``b (n, k)``: Gaussian elimination with
    partial pivoting (the first row of largest magnitude), then back substitution, each sum in
    order (LAPACK's ``gesv`` sums in its BLAS's order). ``a`` and ``b`` are not changed."""
    n = a.shape[0]
    lu = a.copy()
    x = b.copy()
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(lu[row, col]) > abs(lu[pivot, col]):
                pivot = row
        if pivot != col:
            for j in range(n):
                lu[col, j], lu[pivot, j] = lu[pivot, j], lu[col, j]
            for j in range(x.shape[1]):
                x[col, j], x[pivot, j] = x[pivot, j], x[col, j]
        for row in range(col + 1, n):
            factor = lu[row, col] / lu[col, col]
            for j in range(col, n):
                lu[row, j] -= factor * lu[col, j]
            for j in range(x.shape[1]):
                x[row, j] -= factor * x[col, j]
    for row in range(n - 1, -1, -1):
        for j in range(x.shape[1]):
            acc = x[row, j]
            for q in range(row + 1, n):
                acc -= lu[row, q] * x[q, j]
            x[row, j] = acc / lu[row, row]
    return x


def vdot(a: ArrayLike, b: ArrayLike) -> float:
    """:func:`dot` of two arrays of one size read flat (any shape, made contiguous float64)."""
    return float(
        dot(
            np.ascontiguousarray(a, dtype=np.float64).ravel(),
            np.ascontiguousarray(b, dtype=np.float64).ravel(),
        )
    )


def vnorm(a: ArrayLike) -> float:
    """:func:`norm` of an array read flat."""
    return float(norm(np.ascontiguousarray(a, dtype=np.float64).ravel()))


def row_norms(a: ArrayLike) -> NDArray[np.float64]:
    """Euclidean norm of each row of ``(M, d)``, summed over the row in order."""
    rows = np.asarray(a, dtype=np.float64)
    total = np.zeros(rows.shape[0])
    for k in range(rows.shape[1]):
        total = total + rows[:, k] * rows[:, k]
    return np.sqrt(total)


def row_dots(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """``sum_k a_ik b_ik`` of each row of two ``(M, d)`` arrays, summed over the row in order."""
    left = np.asarray(a, dtype=np.float64)
    right = np.asarray(b, dtype=np.float64)
    total = np.zeros(left.shape[0])
    for k in range(left.shape[1]):
        total = total + left[:, k] * right[:, k]
    return total


def transform(points: ArrayLike, matrix: ArrayLike) -> NDArray[np.float64]:
    """``points @ matrix.T`` for points ``(M, d)`` and a matrix ``(e, d)``: entry ``(i, r)`` is
    ``sum_c m_rc x_ic`` summed over ``c`` in order. Returns ``(M, e)``."""
    x = np.asarray(points, dtype=np.float64)
    m = np.asarray(matrix, dtype=np.float64)
    out = np.zeros((x.shape[0], m.shape[0]))
    for r in range(m.shape[0]):
        column = np.zeros(x.shape[0])
        for c in range(m.shape[1]):
            column = column + m[r, c] * x[:, c]
        out[:, r] = column
    return out


def outer_sum(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """``sum_c a_c (x) b_c`` ``(d, e)`` of rows ``a (M, d)`` and ``b (M, e)``: each entry NumPy's
    pairwise sum of the products (a fixed order; ``einsum`` may sum in its SIMD paths' order)."""
    left = np.asarray(a, dtype=np.float64)
    right = np.asarray(b, dtype=np.float64)
    out = np.zeros((left.shape[1], right.shape[1]))
    for r in range(left.shape[1]):
        for c in range(right.shape[1]):
            out[r, c] = np.sum(left[:, r] * right[:, c])
    return out


def upper_inverse(h: ArrayLike) -> NDArray[np.float64]:
    """Inverse of an upper-triangular matrix ``(d, d)`` by back substitution, column by column
    in a fixed order (LAPACK's ``inv`` sums in the order of the CPU's BLAS kernels)."""
    m = np.asarray(h, dtype=np.float64)
    d = m.shape[0]
    out = np.zeros((d, d))
    for col in range(d):
        for row in range(col, -1, -1):
            acc = 1.0 if row == col else 0.0
            for k in range(row + 1, col + 1):
                acc -= m[row, k] * out[k, col]
            out[row, col] = acc / m[row, row]
    return out


# ln(m) = 2 atanh(u), u = (m - 1) / (m + 1), |u| < 0.172 for m in [1/sqrt 2, sqrt 2): the series
# to u^23 (remainder below 1e-18); exp(r) for |r| <= ln(2) / 2: the Taylor series to r^16
# (remainder below 1e-18); ln 2 split into a part with a short mantissa and the rest
_ATANH_TERMS = tuple(1.0 / (2 * k + 1) for k in range(12))
_EXP_TERMS = tuple(1.0 / math.factorial(k) for k in range(17))
_LN2_HI = 0.693147180369123816490  # 2^-32 resolution: k ln2_hi is exact for |k| < 2^20
_LN2_LO = 1.90821492927058770002e-10
_SQRT_HALF = 0.7071067811865476


@_jit
def _log(x):  # type: ignore[no-untyped-def]
    """Natural logarithm of ``x > 0`` by ``frexp`` and the atanh series, basic operations only."""
    m, e = math.frexp(x)
    if m < _SQRT_HALF:
        m *= 2.0
        e -= 1
    u = (m - 1.0) / (m + 1.0)
    u2 = u * u
    acc = _ATANH_TERMS[11]
    for k in range(10, -1, -1):
        acc = acc * u2 + _ATANH_TERMS[k]
    return (e * _LN2_HI + 2.0 * u * acc) + e * _LN2_LO


@_jit
def _exp(t):  # type: ignore[no-untyped-def]
    """``e^t`` by ``t = k ln 2 + r`` and the Taylor series of ``e^r``, basic operations only."""
    k = math.floor(t / (_LN2_HI + _LN2_LO) + 0.5)
    r = (t - k * _LN2_HI) - k * _LN2_LO
    acc = _EXP_TERMS[16]
    for j in range(15, -1, -1):
        acc = acc * r + _EXP_TERMS[j]
    return math.ldexp(acc, k)


@_jit
def power_of(x, e):  # type: ignore[no-untyped-def]
    """``x^e`` for ``x >= 0`` from ``+ - * /`` and ``sqrt`` alone, the same bits on every
    IEEE-754 machine: for ``e`` a multiple of 1/2 up to 16, ``x^floor(e)`` by repeated products
    and one factor ``sqrt(x)`` (correctly rounded steps); for another ``e``, ``exp(e ln x)`` by
    the series above (a relative error of a few ulp of ``1 + |e ln x|``, the rounding of the
    exponent; no libm ``pow``, whose rounding is the CPU's variant's)."""
    twice = 2.0 * e
    if twice == math.floor(twice) and 0.0 <= twice <= 32.0:
        whole = math.floor(e)
        out = 1.0
        for _ in range(whole):
            out = out * x
        if e != whole:
            out = out * np.sqrt(x) if whole else np.sqrt(x)
        return out
    if x == 0.0:
        return 0.0 if e > 0.0 else (1.0 if e == 0.0 else np.inf)
    return _exp(e * _log(x))


@_jit
def _power_into(x, e, out):  # type: ignore[no-untyped-def]
    """``out[p] = power_of(x[p], e)`` over flat arrays."""
    for p in range(x.size):
        out[p] = power_of(x[p], e)


def power(x: ArrayLike, e: float) -> NDArray[np.float64]:
    """:func:`power_of` elementwise over an array ``x >= 0`` (any shape)."""
    base = np.array(x, dtype=np.float64)  # a C-ordered copy, 0-d for a scalar
    out = np.empty_like(base)
    _power_into(base.reshape(-1), float(e), out.reshape(-1))
    return out


def root(x: float, d: int) -> float:
    """``x^(1/d)`` for ``x > 0`` and ``d`` in 1, 2, 3, correctly rounded but in the rarest
    ties: ``sqrt`` for 2; for 3, Newton's iteration in plain arithmetic from a start made of
    ``frexp``'s exponent, then the neighbour of the float64 result whose cube is nearest ``x``
    (compared exactly as rationals)."""
    x = float(x)
    if d == 1:
        return x
    if d == 2:
        return math.sqrt(x)
    if d != 3:
        raise ValueError(f"root: d must be 1, 2 or 3, got {d}")
    if not (x > 0.0 and math.isfinite(x)):
        raise ValueError(f"root: x must be positive and finite, got {x}")
    _, exponent = math.frexp(x)  # x < 2^exponent
    y = math.ldexp(1.0, -(-exponent // 3))  # y^3 >= x: Newton then falls monotonically
    for _ in range(60):
        y_next = y - (y * y * y - x) / (3.0 * y * y)
        if y_next == y:
            break
        y = y_next
    target = Fraction(x)
    candidates = (math.nextafter(y, 0.0), y, math.nextafter(y, math.inf))
    return min(candidates, key=lambda c: (abs(Fraction(c) ** 3 - target), c))


def coarse(x: float, bits: int = 24) -> float:
    """``x`` cut to its ``bits`` leading significant bits (toward zero; infinities and NaN as
    they are): a value that LAPACK or ARPACK computes, whose last bits follow the BLAS kernel
    and the threads, made the same on every machine but where it lies within those bits of a
    cut."""
    if not math.isfinite(x) or x == 0.0:
        return float(x)
    mantissa, exponent = math.frexp(x)
    return math.ldexp(math.trunc(math.ldexp(mantissa, bits)), exponent - bits)


# sin(2 pi s) on s in [-1/4, 1/4] as t * P(t^2), t = 2 pi s: the Taylor series to t^23 (its
# remainder below 2e-17 at |t| = pi / 2), coefficients (-1)^k / (2k + 1)!
_SIN_TERMS = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(12))


def sin_2pi(s: ArrayLike) -> NDArray[np.float64]:
    """``sin(2 pi s)`` elementwise by plain arithmetic: ``s`` reduced to ``[-1/2, 1/2)`` by its
    nearest integer, folded to ``[-1/4, 1/4]`` by ``sin(pi - t) = sin t``, then the Taylor
    polynomial (within a few 1e-16 of ``sin``); the same bits on every machine."""
    u = np.asarray(s, dtype=np.float64)
    u = u - np.floor(u + 0.5)
    u = np.where(u > 0.25, 0.5 - u, np.where(u < -0.25, -0.5 - u, u))
    t = (2.0 * math.pi) * u
    t2 = t * t
    acc = np.full_like(t, _SIN_TERMS[-1])
    for coefficient in reversed(_SIN_TERMS[:-1]):
        acc = acc * t2 + coefficient
    return np.asarray(t * acc, dtype=np.float64)
