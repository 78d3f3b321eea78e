"""Sparse symmetric solvers, factored once and applied many times: one module for the
preconditioners (:mod:`athermal.engines.precon`) and the moduli (:mod:`athermal.analysis.moduli`).

* :class:`CholeskyFactor`: CHOLMOD through cholespy, given the lower triangle only (cholespy
  ignores the upper one: passing it would silently factor another matrix);
* :class:`SpluFactor`: SciPy's SuperLU with a symmetric ordering and no pivoting, when cholespy
  is missing;
* :class:`SupernodalFactor`: CHOLMOD's supernodal factor through cvxopt, on the machine's own
  BLAS (OpenBLAS): many times cholespy's speed on large 3D networks, its bits the machine's
  (cholespy's reference BLAS gives the same bits on every CPU; ``docs/decisions.md``,
  "Factorizations on the machine's BLAS"); ordered for less fill by :func:`dissection_order`
  where the caller knows the points;
* :class:`AmgFactor`: a fixed number of smoothed-aggregation V-cycles from a zero start
  (pyamg), a fixed symmetric linear operator;
* :class:`IncompleteCholeskyFactor`: the zero-fill incomplete Cholesky factor ``L L^T ~ A``
  (compiled): no fill, so a fraction of the exact factor's build time and memory;
* :func:`factor_cg`: conjugate gradients preconditioned by the factor of a nearby matrix.

Each maps right-hand sides ``(n, k)`` to solutions ``(n, k)``. :func:`pin_rows` decouples the
rows of coordinates held fixed, so that a solve never moves them.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
from collections.abc import Iterator
from typing import Any, Literal, Protocol

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from ._jit import _jit
from ._portable import vdot, vnorm
from ._validate import choice
from .errors import InputError

SolverName = Literal["auto", "direct", "amg", "ic0"]
SOLVERS: tuple[str, ...] = ("auto", "direct", "amg", "ic0")
AUTO_DIRECT_MAX_N = 200_000
"""``solver="auto"`` in 3D: direct below this number of particles, AMG from it on."""
AUTO_DIRECT_MAX_N_2D = 2_000_000
"""``solver="auto"`` in 2D: direct below this number of particles, AMG from it on. In 2D the
direct solve stays faster per iteration than AMG at the sizes measured (up to N = 1048576;
measurements: ``docs/decisions.md``, section "Sparse solvers", ``AUTO_DIRECT_MAX_N_2D``)."""
AUTO_IC0_MAX_N = 200_000
"""``solver="auto"`` for an M-matrix (the Exp preconditioner's): the incomplete factor
(:class:`IncompleteCholeskyFactor`) below this number of particles, in 2D and 3D: faster than the
exact factor up to N = 65536, even with it at N = 262144 and 1048576 (its iterations grow faster
with N). The contact preconditioner's matrix is no M-matrix: its ``auto`` stays direct.
Measurements: ``docs/decisions.md``, section "Sparse solvers", ``IncompleteCholeskyFactor``."""
DISSECTION_LEAF = 64
""":func:`dissection_order` halves a set of points no further once it holds at most this many."""
AMG_CYCLES = 1
"""Default number of AMG V-cycles per application (N = 65536, 2D: ~19 matrix-vector products)."""
AMG_SEED = 0
"""Seed of the random vectors third-party solvers would otherwise draw afresh: pyamg's setup
(:func:`aggregation_hierarchy`) and ARPACK's start (:func:`arpack_start`)."""


class NotPositiveDefinite(ValueError):
    """CHOLMOD found the matrix not positive definite."""


class Factor(Protocol):
    """A fixed approximation of ``A^-1``: ``solve`` maps ``(n, k)`` columns to ``(n, k)``."""

    backend: str

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]: ...


class CholeskyFactor:
    """Sparse Cholesky factor (CHOLMOD via cholespy) of an SPD matrix, built once; raises
    :class:`NotPositiveDefinite` (with CHOLMOD's own warning kept off stdout) otherwise."""

    backend = "cholespy"

    def __init__(self, matrix: sp.spmatrix) -> None:
        from cholespy import CholeskySolverD, MatrixType

        lower = sp.tril(matrix, format="coo")
        try:
            with c_output_silenced():  # CHOLMOD prints a warning on stdout before raising
                self._solver = CholeskySolverD(
                    matrix.shape[0],
                    np.ascontiguousarray(lower.row, dtype=np.int32),
                    np.ascontiguousarray(lower.col, dtype=np.int32),
                    np.ascontiguousarray(lower.data, dtype=np.float64),
                    MatrixType.COO,
                )
        except ValueError as error:  # "Matrix is not positive definite!"
            raise NotPositiveDefinite(str(error)) from None

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        b = np.ascontiguousarray(rhs, dtype=np.float64)
        out = np.empty_like(b)
        self._solver.solve(b, out)
        return out


class SpluFactor:
    """SciPy SuperLU factor with a symmetric ordering and no pivoting (cholespy missing)."""

    backend = "splu"

    def __init__(self, matrix: sp.spmatrix) -> None:
        self._lu = spla.splu(
            sp.csc_matrix(matrix),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(self._lu.solve(np.asarray(rhs, dtype=np.float64)), dtype=np.float64)

    def positive_pivots(self) -> bool:
        """True when every pivot is > 0: without pivoting ``LU = L D L^T``, so the symmetric
        matrix is positive definite."""
        return bool(np.all(self._lu.U.diagonal() > 0.0))


class SupernodalFactor:
    """Sparse Cholesky factor ``P A P^T = L L^T`` of an SPD matrix by CHOLMOD's supernodal
    method through cvxopt, whose dense blocks run on its optimized BLAS: the bits are the
    machine's. ``order`` (a permutation of the rows, e.g. by :func:`dissection_order` and
    :func:`row_order`) is tried beside CHOLMOD's AMD ordering, the one of less fill kept. Raises
    :class:`NotPositiveDefinite` otherwise (the failed factor freed with it)."""

    backend = "cvxopt"

    def __init__(self, matrix: sp.spmatrix, order: NDArray[np.intp] | None = None) -> None:
        from cvxopt import cholmod, spmatrix
        from cvxopt import matrix as dense

        lower = sp.tril(matrix, format="coo")
        a = spmatrix(
            dense(np.ascontiguousarray(lower.data, dtype=np.float64)),
            lower.row.tolist(),  # (lists: cvxopt's integer width is the platform's)
            lower.col.tolist(),
            size=matrix.shape,
        )
        ordered = {} if order is None else {"p": dense(order.tolist(), tc="i")}
        self._factor = cholmod.symbolic(a, **ordered)
        try:
            cholmod.numeric(a, self._factor)
        except ArithmeticError as error:  # the column where a pivot was not positive
            raise NotPositiveDefinite(f"not positive definite at column {error}") from None

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        from cvxopt import cholmod
        from cvxopt import matrix as dense

        b = dense(np.asfortranarray(rhs, dtype=np.float64))
        cholmod.solve(self._factor, b)
        return np.asarray(b, dtype=np.float64).reshape(rhs.shape)

    @property
    def nonzeros(self) -> int:
        """The nonzeros of ``L`` (the fill: what a solve reads), from a copy of it."""
        from cvxopt import cholmod

        return len(cholmod.getfactor(self._factor))


def supernodal_cholesky(
    matrix: sp.spmatrix, order: NDArray[np.intp] | None = None
) -> Factor | None:
    """A factor of the symmetric ``matrix`` when it is positive definite, else None: by
    :class:`SupernodalFactor` (fast, the machine's bits), or by :func:`cholesky` where cvxopt is
    missing."""
    if not available("cvxopt"):
        return cholesky(matrix)
    try:
        return SupernodalFactor(matrix, order)
    except NotPositiveDefinite:
        return None


def dissection_order(
    points: NDArray[np.float64],
    widths: NDArray[np.float64],
    first: NDArray[np.int64],
    second: NDArray[np.int64],
) -> NDArray[np.intp]:
    """Each point's rank ``(n,)`` in a fill-reducing order of the ``n`` points ``(n, d)`` in the
    box ``[0, widths)`` joined by the edges ``first, second`` (a matrix's pattern over them):
    nested dissection by halves. A set of more than :data:`DISSECTION_LEAF` points splits at the
    median of its widest side; its points in the lower half with an edge into the upper (the
    separator, which periodic edges across the box's faces join too) come after both halves,
    each half ordered so in turn (its effect on a factorization: ``docs/decisions.md``,
    "Factorizations on the machine's BLAS")."""
    n = points.shape[0]
    graph = sp.coo_matrix((np.ones(first.size), (first, second)), shape=(n, n))
    graph = (graph + graph.T).tocsr()
    parts: list[NDArray[np.intp]] = []

    def halve(
        members: NDArray[np.intp], low: NDArray[np.float64], high: NDArray[np.float64]
    ) -> None:
        if members.size <= DISSECTION_LEAF:
            parts.append(members)
            return
        axis = int(np.argmax(high - low))
        coordinate = points[members, axis]
        middle = float(np.median(coordinate))
        lower, upper = members[coordinate < middle], members[coordinate >= middle]
        if not lower.size or not upper.size:  # all at one coordinate: no halves
            parts.append(members)
            return
        in_upper = np.zeros(n)
        in_upper[upper] = 1.0
        touching = (graph[lower] @ in_upper) > 0.0
        top, bottom = high.copy(), low.copy()
        top[axis] = bottom[axis] = middle
        halve(lower[~touching], low, top)
        halve(upper, bottom, high)
        parts.append(lower[touching])

    halve(np.arange(n), np.zeros(points.shape[1]), np.asarray(widths, dtype=np.float64))
    rank = np.empty(n, dtype=np.intp)
    rank[np.concatenate(parts)] = np.arange(n)
    return rank


def row_order(rank: NDArray[np.intp], dofs: NDArray[np.intp], dim: int) -> NDArray[np.intp]:
    """The rows of a matrix over the flat coordinates ``dofs`` ``(M,)`` (of ``N d``) in the
    order of their particles' ``rank`` (:func:`dissection_order`), a particle's coordinates
    together: the permutation ``(M,)`` a :class:`SupernodalFactor` takes."""
    return np.lexsort((dofs % dim, rank[dofs // dim])).astype(np.intp)


def arpack_start(size: int) -> NDArray[np.float64]:
    """A fixed start vector ``(size,)`` for ARPACK (``eigsh``'s ``v0``), whose own is drawn at
    random: unit length, Gaussian entries from :data:`AMG_SEED`, so that it has a part along
    every eigenvector (a constant vector would lie in a packing's translations)."""
    v = np.random.default_rng(AMG_SEED).standard_normal(size)
    return np.asarray(v / np.sqrt(np.sum(v * v)), dtype=np.float64)


def aggregation_hierarchy(
    matrix: sp.spmatrix, near_null: NDArray[np.float64], max_coarse: int | None = None
) -> Any:
    """pyamg's smoothed-aggregation hierarchy of the SPD ``matrix`` with the near-null vectors
    ``near_null`` (one per column), the same in every run: its setup estimates a spectral radius
    from a vector of NumPy's global random state, drawn here from :data:`AMG_SEED`, the caller's
    state put back after."""
    import pyamg

    options = {} if max_coarse is None else {"max_coarse": max_coarse}
    caller = np.random.get_state()  # noqa: NPY002 (pyamg draws from the legacy state)
    np.random.seed(AMG_SEED)  # noqa: NPY002
    try:
        return pyamg.smoothed_aggregation_solver(
            matrix, B=near_null, symmetry="hermitian", **options
        )
    finally:
        np.random.set_state(caller)  # noqa: NPY002


class AmgFactor:
    """``cycles`` smoothed-aggregation V-cycles from a zero start: a fixed SPD linear operator.

    pyamg's default smoothers (symmetric Gauss-Seidel before and after) and exact coarse solve
    make one V-cycle symmetric; with ``tol=0`` no cycle is skipped, so the map is linear. With
    ``k > 1`` near-null vectors (the ``d`` translations of an ``(N d)`` system) the matrix is
    aggregated by ``k x k`` blocks (one block per particle).
    """

    backend = "pyamg"

    def __init__(self, matrix: sp.spmatrix, cycles: int, near_null: NDArray[np.float64]) -> None:
        block = near_null.shape[1]
        system = sp.bsr_matrix(matrix, blocksize=(block, block)) if block > 1 else matrix
        self._cycles = cycles
        self._ml = aggregation_hierarchy(system, near_null)

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        b = np.asarray(rhs, dtype=np.float64)
        out = np.empty_like(b)
        for col in range(b.shape[1]):
            out[:, col] = self._ml.solve(
                b[:, col], x0=np.zeros(b.shape[0]), tol=0.0, maxiter=self._cycles, cycle="V"
            )
        return out


class IncompleteCholeskyFactor:
    """IC(0): ``L`` lower triangular on the pattern of the SPD matrix's lower triangle with
    ``L L^T`` equal to the matrix on that pattern (Meijerink & van der Vorst 1977), applied by
    two compiled triangular solves: a fixed SPD approximation of ``A^-1``.

    It exists for M-matrices (the Exp preconditioner's); for others a pivot may vanish, and the
    factor of ``A + s diag(A)`` is taken, ``s = 1e-3``, tenfold until every pivot is positive
    (``shift`` records it). Cheaper to build and apply than the exact factor, but a weaker
    preconditioner whose iterations grow faster with N; ``auto`` takes it for the Exp matrix
    below :data:`AUTO_IC0_MAX_N`. The solves take the columns in interleaved pairs (a
    substitution is latency-bound: two chains cost about one).

    Measurements (against ``direct``: the Table, large N, ``athermal jam``; the modified factor
    MIC, tried and dropped): ``docs/decisions.md``, section "Sparse solvers",
    ``IncompleteCholeskyFactor``.
    """

    backend = "ic0"

    def __init__(self, matrix: sp.spmatrix) -> None:
        lower = sp.tril(sp.csr_matrix(matrix, dtype=np.float64)).tocsr()
        lower.sort_indices()
        self._indptr = lower.indptr.astype(np.int64)
        self._indices = lower.indices.astype(np.int32)  # solves 10 % faster than with int64
        n = lower.shape[0]
        if np.any(np.diff(self._indptr) == 0) or np.any(
            self._indices[self._indptr[1:] - 1] != np.arange(n)
        ):
            raise InputError("ic0: the matrix needs every diagonal entry")
        self.shift = 0.0
        while True:
            values, ok = incomplete_cholesky(self._indptr, self._indices, lower.data, self.shift)
            if ok:
                break
            self.shift = 1e-3 if self.shift == 0.0 else 10.0 * self.shift
            if self.shift > 1e3:
                raise NotPositiveDefinite("ic0: no positive incomplete factor (not SPD?)")
        self._lower = values
        self._inverse_diagonal = 1.0 / values[self._indptr[1:] - 1]

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        b = np.ascontiguousarray(rhs, dtype=np.float64)
        columns = b.reshape(b.shape[0], -1)
        out = np.empty_like(columns)
        cholesky_solve_columns(*self.arrays(), columns, out)
        return out.reshape(b.shape)

    def arrays(
        self,
    ) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.float64], NDArray[np.float64]]:
        """``(indptr, indices, lower, inverse_diagonal)``: ``L`` in CSR, its diagonal last in
        each row, for :func:`cholesky_solve_columns`."""
        return self._indptr, self._indices, self._lower, self._inverse_diagonal


def available(module: str) -> bool:
    """True when ``module`` can be imported (an optional solver's package)."""
    return importlib.util.find_spec(module) is not None


def resolve_solver(solver: str, n: int, dim: int = 3, *, m_matrix: bool = False) -> str:
    """``"direct"``, ``"amg"`` or ``"ic0"`` for ``solver`` and ``n`` particles in ``dim``
    dimensions (``"auto"`` resolved; ``m_matrix``: the matrix to factor is an M-matrix, so its
    incomplete factor exists and ``auto`` takes it below :data:`AUTO_IC0_MAX_N`).

    pyamg is one of athermal's dependencies; only an environment that lacks it (installed with
    ``--no-deps``, or pyamg removed) makes ``"amg"`` an error and ``"auto"`` stay direct."""
    choice(solver, "solver", SOLVERS)
    if solver == "amg" and not available("pyamg"):
        raise InputError(
            "solver: 'amg' needs pyamg, a dependency of athermal missing from this environment;"
            " install it with `pip install pyamg`"
        )
    if solver == "auto" and m_matrix and n < AUTO_IC0_MAX_N:
        return "ic0"
    if solver == "auto":
        limit = AUTO_DIRECT_MAX_N_2D if dim == 2 else AUTO_DIRECT_MAX_N
        return "amg" if n >= limit and available("pyamg") else "direct"
    return solver


def factorize(
    matrix: sp.spmatrix, solver: str, cycles: int, near_null: NDArray[np.float64]
) -> Factor:
    """Factor (direct: cholespy, else splu; ic0: incomplete) or build the AMG hierarchy of an
    SPD ``matrix``."""
    if solver == "amg":
        return AmgFactor(matrix, cycles, near_null)
    if solver == "ic0":
        return IncompleteCholeskyFactor(matrix)
    if available("cholespy"):
        return CholeskyFactor(matrix)
    return SpluFactor(matrix)


def cholesky(matrix: sp.spmatrix, *, cholmod: bool = True) -> Factor | None:
    """A factor of the symmetric ``matrix`` when it is positive definite, else None: CHOLMOD,
    or (cholespy missing, or not ``cholmod``) SuperLU without pivoting, whose pivots are then
    those of ``L D L^T``. A CHOLMOD factorization that fails keeps its memory (cholespy frees
    it only with a factor it returns; ``docs/decisions.md``, "Three costs of the certified
    march removed"), so a caller that expects failures one after another factors by SuperLU."""
    if cholmod and available("cholespy"):
        try:
            return CholeskyFactor(matrix)
        except NotPositiveDefinite:
            return None
    try:
        factor = SpluFactor(matrix)
    except RuntimeError:  # "Factor is exactly singular"
        return None
    return factor if factor.positive_pivots() else None


def factor_cg(
    matrix: sp.spmatrix, rhs: NDArray[np.float64], factor: Factor, rtol: float, maxiter: int
) -> tuple[NDArray[np.float64], float] | None:
    """``y`` ``(n,)`` of ``matrix y = rhs`` by conjugate gradients from zero, preconditioned by
    ``factor`` (an exact factor of a nearby SPD matrix, so that the preconditioned spectrum
    clusters at 1), to a recursive residual of ``rtol |rhs|``, and its relative residual
    ``|matrix y - rhs| / |rhs|`` recomputed (round-off bounds it, as it bounds a direct
    solve's); None when ``maxiter`` iterations do not reach ``rtol``. Raises
    :class:`NotPositiveDefinite` when a search direction has no positive curvature. Its sums are
    :mod:`~athermal._portable`'s, the same bits on every CPU."""
    size = vnorm(rhs)
    y = np.zeros_like(rhs)
    if size == 0.0:
        return y, 0.0
    r = rhs.copy()
    z = factor.solve(r[:, None])[:, 0]
    p, rz = z.copy(), vdot(r, z)
    for _ in range(maxiter):
        q = matrix @ p
        curvature = vdot(p, q)
        if not curvature > 0.0:
            raise NotPositiveDefinite("conjugate gradients met a direction of no curvature")
        y += (rz / curvature) * p
        r -= (rz / curvature) * q
        if vnorm(r) <= rtol * size:
            return y, vnorm(rhs - matrix @ y) / size
        z = factor.solve(r[:, None])[:, 0]
        rz, previous = vdot(r, z), rz
        p = z + (rz / previous) * p
    return None


def pin_rows(matrix: sp.spmatrix, rows: NDArray[np.intp]) -> sp.csr_matrix:
    """``matrix`` (symmetric ``(n, n)``) with ``rows`` and their columns decoupled: zero off the
    diagonal, the mean diagonal of the other rows on it (1 when there is none). A solve with a
    right-hand side that is zero on ``rows`` then gives zero there, and the other rows see the
    principal submatrix of the rest: ``rows`` held fixed."""
    pinned = np.zeros(matrix.shape[0], dtype=bool)
    pinned[rows] = True
    diagonal = matrix.diagonal()
    free = diagonal[~pinned]
    scale = float(free.mean()) if free.size and free.mean() > 0.0 else 1.0
    keep = sp.diags((~pinned).astype(np.float64))
    return (keep @ matrix @ keep + sp.diags(np.where(pinned, scale, 0.0))).tocsr()


@contextlib.contextmanager
def c_output_silenced() -> Iterator[None]:
    """Send what C code writes to file descriptors 1 and 2 to the null device meanwhile (so
    that ``--json`` output stays one object)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            yield
    finally:
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)


@_jit
def incomplete_cholesky(indptr, indices, data, shift):  # type: ignore[no-untyped-def]
    """IC(0) of a symmetric matrix from its lower triangle in CSR (sorted columns, the
    diagonal last in each row, every diagonal present), diagonal scaled by ``1 + shift``: the
    values of ``L`` on that pattern (``L L^T`` equals the matrix there), and whether every
    pivot was positive (the factor is meaningless otherwise)."""
    n = indptr.size - 1
    lower = data.copy()
    for i in range(n):
        a, b = indptr[i], indptr[i + 1]
        for p in range(a, b - 1):  # L_ij, j < i: the entries of rows i and j left of j
            j = indices[p]
            value = lower[p]
            q, r, r_end = a, indptr[j], indptr[j + 1] - 1
            while q < p and r < r_end:
                if indices[q] == indices[r]:
                    value -= lower[q] * lower[r]
                    q += 1
                    r += 1
                elif indices[q] < indices[r]:
                    q += 1
                else:
                    r += 1
            lower[p] = value / lower[indptr[j + 1] - 1]
        pivot = lower[b - 1] * (1.0 + shift)
        for p in range(a, b - 1):
            pivot -= lower[p] * lower[p]
        if not pivot > 0.0:
            return lower, False
        lower[b - 1] = np.sqrt(pivot)
    return lower, True


@_jit
def cholesky_solve_columns(indptr, indices, lower, inverse_diagonal, rhs, out):  # type: ignore[no-untyped-def]
    """``out = (L L^T)^-1 rhs`` for every column of ``rhs`` ``(n, k)``, in interleaved pairs
    (:func:`cholesky_solve_pair`; an odd last column alone)."""
    last = rhs.shape[1] - 1
    for c in range(0, last + 1, 2):
        cholesky_solve_pair(indptr, indices, lower, inverse_diagonal, rhs, out, c, min(c + 1, last))


@_jit
def cholesky_solve_pair(  # type: ignore[no-untyped-def]
    indptr, indices, lower, inverse_diagonal, rhs, out, c0, c1
):
    """Columns ``c0`` and ``c1`` of ``out = (L L^T)^-1 rhs`` (``rhs``, ``out`` ``(n, k)``), ``L``
    lower triangular in CSR (diagonal last in each row, ``inverse_diagonal`` its reciprocal):
    forward substitution by rows, then back substitution by the same rows read as the columns
    of ``L^T``. Two interleaved columns keep two independent chains in flight (a substitution
    is latency-bound: one column costs about as much as two); ``c0 == c1`` solves one."""
    n = rhs.shape[0]
    for i in range(n):
        s0, s1 = rhs[i, c0], rhs[i, c1]
        for p in range(indptr[i], indptr[i + 1] - 1):
            j, value = indices[p], lower[p]
            s0 -= value * out[j, c0]
            s1 -= value * out[j, c1]
        out[i, c0], out[i, c1] = s0 * inverse_diagonal[i], s1 * inverse_diagonal[i]
    for i in range(n - 1, -1, -1):
        s0, s1 = out[i, c0] * inverse_diagonal[i], out[i, c1] * inverse_diagonal[i]
        out[i, c0], out[i, c1] = s0, s1
        if c1 == c0:  # one column: its updates below must not be applied twice
            s1 = 0.0
        for p in range(indptr[i], indptr[i + 1] - 1):
            j, value = indices[p], lower[p]
            out[j, c0] -= value * s0
            out[j, c1] -= value * s1
