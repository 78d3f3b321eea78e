"""Truncated Newton (line-search Newton-CG) with a lagged sparse Cholesky factor of the Hessian.

Beyond the paper, for its open problem: near jamming every gradient method slows down as a power
of ``Delta phi`` (the soft modes of the contact network), while the exact Newton step of a
quasi-static step is one linear solve with the stiffness matrix. Each iteration:

1. ``H`` = the Hessian at ``x`` (:meth:`SecondOrderProblem.hessian`: contacts, rattlers and
   zero modes included), applied matrix-free;
2. the Newton direction ``p`` from preconditioned CG on ``H p = -g``, stopped at
   ``|r| <= eta |g|`` with the forcing term ``eta = min(0.5, sqrt(|g| / |g_0|))`` (superlinear
   convergence, Eisenstat & Walker), or at a direction of non-positive curvature (Nocedal &
   Wright, Algorithm 7.1: the iterate so far, or the preconditioned gradient at the first one);
3. the strong-Wolfe line search of :mod:`.linesearch` along ``p``, unit step first;
4. when CG stopped at a direction ``d`` of non-positive curvature after its first iteration, a
   second strong-Wolfe search from the new point along ``d``, signed downhill, from a step as
   long as the one just taken (:func:`follow_negative_curvature`): ``p`` stops short of ``d``,
   the direction in which the energy falls fastest, and without this search Newton creeps along
   it.

The preconditioner of step 2 is a CHOLMOD factor of ``M = H(x_b) + sigma kappa I`` at an earlier
iterate ``x_b`` (``kappa`` the mean positive diagonal of ``H``). ``sigma`` lifts the zero modes
(translations, rattlers) and the negative curvature that the tangential terms of particles with one
or two contacts, and saddles, give ``H``: it starts at a tenth of the last build's (the last one
itself if that build had to raise it), never below :data:`SHIFT_MIN` nor below :data:`BLOCK_MARGIN`
times the most negative eigenvalue of a particle's diagonal block (an upper bound on the lowest
eigenvalue of ``H``: a lower shift cannot succeed), and is raised tenfold (:data:`SHIFT_RAISE`)
until CHOLMOD succeeds. ``M`` is factored anew at the iterate after a direction that needed more
than :data:`REFACTOR_INNER` CG iterations: while the contact network holds, ``H`` barely changes
and CG converges in a few iterations on the lagged factor.

Between builds the factor follows the contacts that form (:meth:`LaggedFactor.follow`): their
blocks are added to ``M`` by a low-rank (Woodbury) correction, each new contact costing one
solve with ``d`` right-hand sides instead of a factorization. Contacts lost since the build stay
in ``M``: taken out, they leave ``M`` as soft as ``H`` along the modes they held, and near a
saddle CG's first direction ``M^-1 g`` runs far along them.

Near jamming a quasi-static shear step takes tens of iterations where the L-BFGS family needs
thousands. Where contacts keep breaking and forming over a long rearrangement (``shear_steps`` to
large strain, the jamming protocol's trials near ``phi_c``) it is slower than L-BFGS and
P-L-BFGS; the protocols hand a Newton relaxation on to P-L-BFGS after
:data:`~athermal.relaxation.NEWTON_PATIENCE` iterations.

Measurements (iterations and time per step, each choice above, and what was tried and not
kept): ``docs/decisions.md``, section "Newton-CG".
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .._portable import matvec, solve_small, transform, vdot, vnorm
from ..linalg import Factor, cholesky
from ._step import advance
from .result import MinimizeResult, Problem, Status, Tracker

SHIFT_MIN = 1e-5
"""Smallest shift ``sigma`` of the factored matrix, in units of ``kappa``. A smaller one makes
``M^-1`` blow the soft and rattling modes up into long directions the line search cuts back,
and each build probes it (a failed factorization where ``H`` is indefinite); a larger one
makes ``M`` a poorer model of ``H``. Measurements: ``docs/decisions.md``, section "Newton-CG",
``SHIFT_MIN``."""
SHIFT_MAX = 1e2
"""Largest; beyond it the preconditioner is the scaled identity (``H`` tells nothing)."""
REFACTOR_INNER = 20
"""CG iterations of one Newton direction beyond which ``H`` is factored anew: a factorization
costs as much as tens of CG iterations on the lagged factor. Measurements:
``docs/decisions.md``, section "Newton-CG", ``REFACTOR_INNER``."""
SHIFT_RAISE = 10.0
"""Factor the shift is raised by after a failed factorization."""
BLOCK_MARGIN = 2.0
"""A build starts no lower than this many times the most negative eigenvalue of a particle's
diagonal block of ``H`` (over ``kappa``): below it ``M`` is indefinite and CHOLMOD fails."""
CORRECTION_MAX = 32
"""Most contacts formed since the factor's build that :meth:`LaggedFactor.follow` adds to it (a
change of rank ``d`` each); beyond them the factor is used as it was built."""
CORRECTION_BYTES = 2**26
"""Memory the correction's columns ``M^-1 U`` may take (they are dense, ``N d`` by ``d`` per
contact, and held twice): at most 32 contacts at N = 4096 in 2D, 4 at N = 262144, 1 at 10^6."""
INNER_MAX = 200
"""Hard cap on the CG iterations of one Newton direction."""
ETA_MAX = 0.5
"""Largest forcing term ``eta`` (relative residual CG stops at)."""


class Hessian(Protocol):
    """``d^2 f / dx dx`` ``(n_dof, n_dof)`` at one point, over ``n`` blocks of ``d``
    coordinates; a sum of pair terms when :attr:`pairs` is given (the physics'
    :class:`~athermal.model.contact.HessianOperator`: one term per contact), which lets
    :class:`LaggedFactor` follow the pairs that form (:meth:`LaggedFactor.follow`).
    :class:`SparseHessian` is one for any sparse matrix."""

    n: int

    @property
    def pairs(self) -> NDArray[np.int64] | None:
        """``(M, 2)`` blocks ``(i, j)`` coupled by a ``d x d`` term ``K_p`` (``+K_p`` on the
        diagonal blocks ``(i, i)`` and ``(j, j)``, ``-K_p`` on ``(i, j)`` and ``(j, i)``;
        ``i == j``: no coupling), or None when ``H`` is not given as such a sum."""
        ...

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_dof, n_dof)``."""
        ...

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """``H v`` ``(n_dof,)``."""
        ...

    def matrix(self) -> sp.csr_matrix:
        """``H`` as a symmetric sparse matrix."""
        ...

    def lowest_block_eigenvalue(self) -> float:
        """An upper bound on the lowest eigenvalue of ``H`` (the physics: the smallest
        eigenvalue of its diagonal blocks), which spares :class:`LaggedFactor` factorizations
        bound to fail; ``inf`` when nothing is known."""
        ...

    def contact_blocks(self, rows: NDArray[np.int64] | None = None) -> NDArray[np.float64]:
        """The terms ``K_p`` ``(m, d, d)`` of the pairs ``rows`` of :attr:`pairs`."""
        ...


class SparseHessian:
    """A symmetric sparse matrix as a :class:`Hessian` of ``n`` blocks (no pair terms)."""

    pairs = None

    def __init__(self, matrix: sp.spmatrix, block: int = 1) -> None:
        self._matrix = sp.csr_matrix(matrix, dtype=np.float64)
        self.n = self._matrix.shape[0] // block

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_dof, n_dof)``."""
        rows, cols = self._matrix.shape
        return int(rows), int(cols)

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """``H v``."""
        return np.asarray(self._matrix @ v, dtype=np.float64)

    def matrix(self) -> sp.csr_matrix:
        """``H``."""
        return self._matrix

    def lowest_block_eigenvalue(self) -> float:
        """``inf``: no bound known."""
        return float("inf")

    def contact_blocks(self, rows: NDArray[np.int64] | None = None) -> NDArray[np.float64]:
        """No pair terms: an empty ``(0, 0, 0)`` array."""
        return np.zeros((0, 0, 0))


def _contacts(hessian: Hessian) -> tuple[NDArray[np.int64], NDArray[np.int64]] | None:
    """The keys ``lo n + hi`` of the contacts of ``hessian`` between two particles ``lo < hi``,
    sorted, and their rows in its ``pairs``; None when it does not give its contacts or a pair
    occurs twice (periodic images of a small cell)."""
    pairs = hessian.pairs
    if pairs is None:
        return None
    rows = np.flatnonzero(pairs[:, 0] != pairs[:, 1])
    first, second = pairs[rows, 0], pairs[rows, 1]
    keys = np.minimum(first, second) * hessian.n + np.maximum(first, second)
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    if np.any(keys[1:] == keys[:-1]):
        return None
    return keys, rows[order]


def _members(keys: NDArray[np.int64], sorted_keys: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Which of ``keys`` occur in ``sorted_keys`` (ascending): ``np.isin`` by binary search."""
    if sorted_keys.size == 0:
        return np.zeros(keys.shape, dtype=bool)
    at = np.minimum(np.searchsorted(sorted_keys, keys), sorted_keys.size - 1)
    return sorted_keys[at] == keys


@runtime_checkable
class SecondOrderProblem(Problem, Protocol):
    """A :class:`Problem` that also gives its Hessian."""

    def hessian(self, x: NDArray[np.float64]) -> Hessian:
        """The Hessian at ``x``."""
        ...


class LaggedFactor:
    """The factor of ``M = H(x_b) + sigma kappa I`` that CG is preconditioned with (module doc).

    ``n_builds`` counts factorizations, ``n_failed`` the attempts that found ``M`` indefinite
    (each raises ``sigma`` tenfold); ``shift`` is the last ``sigma``, ``scale`` the last
    ``kappa``. Between builds it follows the contacts that form (:meth:`follow`).
    """

    name = "hessian"

    def __init__(self) -> None:
        self.n_builds = 0
        self.n_failed = 0
        self.shift = SHIFT_MIN
        self._factor: Factor | None = None
        self.scale = 1.0
        self._lowered_ok = True  # the last build needed no raise: try a lower shift next
        self._keys: NDArray[np.int64] | None = None  # the build's contacts (:func:`_contacts`)
        self._columns: dict[int, NDArray[np.float64]] = {}  # M^-1 U_c (n d, d) by contact key
        self._correction: tuple[Any, ...] | None = None  # (keys, lo, hi, W, C (I + X C)^-1)

    def build(self, hessian: Hessian) -> None:
        """Factor ``M`` at ``hessian`` (``sigma`` as the module doc says)."""
        matrix = hessian.matrix()
        diagonal = matrix.diagonal()
        positive = diagonal[diagonal > 0.0]
        self.scale = float(positive.mean()) if positive.size else 1.0
        identity = sp.identity(matrix.shape[0], format="csr")
        failed = self.n_failed
        shift = max(SHIFT_MIN, 0.1 * self.shift) if self._lowered_ok else self.shift
        shift = max(shift, -BLOCK_MARGIN * hessian.lowest_block_eigenvalue() / self.scale)
        while True:
            self._factor = cholesky(matrix + (shift * self.scale) * identity)
            if self._factor is not None or shift >= SHIFT_MAX:
                break
            self.n_failed += 1
            shift *= SHIFT_RAISE
        self.shift = shift
        self._lowered_ok = self.n_failed == failed
        self.n_builds += 1
        self._columns, self._correction = {}, None
        contacts = _contacts(hessian)
        self._keys = None if contacts is None else contacts[0]

    def follow(self, hessian: Hessian) -> bool:
        """Add to ``M`` the blocks, at ``hessian``, of the contacts formed since the build: a
        change ``U C U^T`` of rank ``d`` per contact that :meth:`solve` applies by the Woodbury
        identity, ``(M + U C U^T)^-1 = M^-1 - W C (I + X C)^-1 W^T`` with ``W = M^-1 U`` (kept
        per contact until the next build) and ``X = U^T W``, so that CG meets the new contacts
        already solved. Contacts lost since the build stay in ``M``: taken out, they leave ``M``
        as soft as ``H`` along the modes they held, and near a saddle ``M^-1`` sends CG's first
        direction far along those. ``M`` stays as it was built when more contacts
        formed than :data:`CORRECTION_MAX` (or than :data:`CORRECTION_BYTES` hold), or when
        ``hessian`` does not give its contacts: CG's iterations then decide the next build, as
        they always do (:data:`REFACTOR_INNER`). Returns False when ``M + U C U^T`` is not
        positive definite (an eigenvalue of ``I + C X`` not above 0): the new contacts need a
        larger shift, and ``H`` is to be factored anew. Measurements: ``docs/decisions.md``,
        section "Newton-CG", "Following the contacts that form"."""
        contacts = _contacts(hessian)
        if self._factor is None or self._keys is None or contacts is None:
            return True
        keys, rows = contacts
        formed = ~_members(keys, self._keys)
        count = int(formed.sum())
        n, d = hessian.n, hessian.shape[0] // hessian.n
        if count == 0 or count > min(CORRECTION_MAX, CORRECTION_BYTES // (16 * n * d * d)):
            self._correction = None
            return True
        new = keys[formed]
        if self._correction is not None and np.array_equal(new, self._correction[0]):
            return True  # the same contacts as at the last iteration: M is as it was
        self._columns = {key: self._columns[key] for key in new.tolist() if key in self._columns}
        blocks = hessian.contact_blocks(rows[formed])
        lo, hi = new // n, new % n
        self._solve_columns(new, lo, hi, n, d)
        w = np.concatenate([self._columns[key] for key in new.tolist()], axis=1)
        ends = w.reshape(n, d, d * count)
        x = (ends[lo] - ends[hi]).reshape(d * count, d * count)
        c: NDArray[np.float64] = np.zeros((count, d, count, d))
        c[np.arange(count), :, np.arange(count), :] = blocks
        c = c.reshape(d * count, d * count)
        capacitance = np.eye(d * count) + transform(0.5 * (x + x.T), c).T  # c @ sym(x)
        if not np.linalg.eigvals(capacitance).real.min() > 0.0:  # a verdict, not a value
            self._correction = None
            return False
        g = np.ascontiguousarray(solve_small(capacitance, c).T)
        self._correction = (new, lo, hi, np.ascontiguousarray(w), g)
        return True

    def _solve_columns(
        self,
        keys: NDArray[np.int64],
        lo: NDArray[np.int64],
        hi: NDArray[np.int64],
        n: int,
        d: int,
    ) -> None:
        """``M^-1 U_c`` ``(n d, d)`` for the contacts ``keys`` (ends ``lo``, ``hi``) not yet
        kept, in one solve; ``U_c`` is ``+I`` at ``lo``, ``-I`` at ``hi``."""
        new = [k for k, key in enumerate(keys.tolist()) if key not in self._columns]
        if not new:
            return
        u = np.zeros((n * d, d * len(new)))
        for col, k in enumerate(new):
            for a in range(d):
                u[lo[k] * d + a, col * d + a] = 1.0
                u[hi[k] * d + a, col * d + a] = -1.0
        assert self._factor is not None
        solved = self._factor.solve(u)
        for col, k in enumerate(new):
            self._columns[int(keys[k])] = solved[:, col * d : (col + 1) * d].copy()

    def solve(self, r: NDArray[np.float64]) -> NDArray[np.float64]:
        """``M^-1 r``, corrected as :meth:`follow` says (a scaled identity when even
        ``SHIFT_MAX`` left ``M`` indefinite)."""
        if self._factor is None:
            return r / (self.shift * self.scale)
        z = self._factor.solve(r[:, None])[:, 0]
        if self._correction is not None:
            _, lo, hi, w, g = self._correction
            points = z.reshape(-1, w.shape[1] // lo.size)
            z -= matvec(w, matvec(g, np.ascontiguousarray((points[lo] - points[hi]).ravel())))
        return z


def newton_direction(
    hessian: Hessian,
    grad: NDArray[np.float64],
    factor: LaggedFactor,
    eta: float,
    maxiter: int,
) -> tuple[NDArray[np.float64], int, NDArray[np.float64] | None]:
    """An approximate solution ``p`` of ``H p = -grad`` by CG preconditioned with ``factor``,
    and the iterations it took. Stops at ``|r| <= eta |grad|``, after ``maxiter`` iterations,
    or at non-positive curvature ``d.H d <= 0``: then the iterate so far, or ``-M^-1 grad`` when
    that is the first direction. Every ``p`` returned has ``p.grad < 0`` (for ``grad != 0``) in
    exact arithmetic; round-off through a nearly singular factor can break it (the caller checks).
    The third value is the CG direction of non-positive curvature found after the first
    iteration (None otherwise)."""
    r = -grad
    z = factor.solve(r)
    p = np.zeros_like(grad)
    d = z.copy()
    rz = vdot(r, z)
    stop = eta * vnorm(grad)
    for k in range(maxiter):
        hd = hessian.dot(d)
        curvature = vdot(d, hd)
        if not curvature > 0.0:
            return (z, k, None) if k == 0 else (p, k, d)
        a = rz / curvature
        p += a * d
        r -= a * hd
        if vnorm(r) <= stop:
            return p, k + 1, None
        z = factor.solve(r)
        rz_new = vdot(r, z)
        if not rz_new > 0.0:  # r = 0 to round-off, or lost to a nearly singular factor
            return p, k + 1, None
        d = z + (rz_new / rz) * d
        rz = rz_new
    return p, maxiter, None


def _fresh_descent(
    hessian: Hessian, grad: NDArray[np.float64], factor: LaggedFactor
) -> NDArray[np.float64]:
    """``-M^-1 grad`` on a factor built afresh at ``hessian``, or ``-grad`` when round-off in a
    nearly singular ``M`` (rattlers' zero modes, a small shift) leaves even that uphill."""
    factor.build(hessian)
    direction = -factor.solve(grad)
    return direction if vdot(direction, grad) < 0.0 else -grad


def follow_negative_curvature(
    problem: SecondOrderProblem,
    x: NDArray[np.float64],
    energy: float,
    grad: NDArray[np.float64],
    curved: NDArray[np.float64],
    length: float,
) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """``(x, energy, grad)`` after a strong-Wolfe search from ``x`` along ``curved`` (a
    direction of non-positive curvature, ``(n_dof,)``), signed so that it descends, from a
    first step of Euclidean ``length``; unchanged when ``curved`` is orthogonal to ``grad`` or
    the search finds no step."""
    slope = vdot(grad, curved)
    norm = vnorm(curved)
    if slope == 0.0 or norm == 0.0 or not length > 0.0:
        return x, energy, grad
    downhill = -np.sign(slope) * curved
    _, x_new, energy_new, grad_new = advance(problem, x, energy, grad, downhill, length / norm, 0.9)
    return x_new, energy_new, grad_new


def newton(
    problem: SecondOrderProblem,
    x0: NDArray[np.float64],
    *,
    gtol: float,
    maxiter: int = 100_000,
    etol: float = -np.inf,
) -> MinimizeResult:
    """Minimize ``problem`` from ``x0`` ``(n_dof,)`` by truncated Newton (see module doc).

    Stopping rules as :func:`~athermal.minimize.lbfgs.lbfgs`; the result's ``precon_builds``
    counts factorizations and ``linear_iterations`` the CG iterations (Hessian-vector products).
    """
    factor = LaggedFactor()
    tracker = Tracker.start(problem, "newton", factor, gtol, maxiter, etol)
    x = np.array(x0, dtype=np.float64, copy=True)
    energy, grad = problem(x)
    if tracker.record(energy, grad):
        return tracker.finish(x, Status.CONVERGED, "converged")
    start_norm = vnorm(grad)
    refactor = True
    while tracker.iterations < maxiter:
        hessian = problem.hessian(x)
        if refactor or not factor.follow(hessian):
            factor.build(hessian)
        eta = min(ETA_MAX, float(np.sqrt(vnorm(grad) / start_norm)))
        direction, inner, negative = newton_direction(hessian, grad, factor, eta, INNER_MAX)
        tracker.linear_iterations += inner
        refactor = inner > REFACTOR_INNER
        if not vdot(direction, grad) < 0.0:  # round-off of a near-singular M: CG's answers
            direction, refactor, negative = _fresh_descent(hessian, grad, factor), True, None
        ls, x_new, energy_new, grad_new = advance(problem, x, energy, grad, direction, 1.0, 0.9)
        if not ls.ok and not refactor:  # retry along -M^-1 g on a fresh factor
            direction = _fresh_descent(hessian, grad, factor)
            ls, x_new, energy_new, grad_new = advance(problem, x, energy, grad, direction, 1.0, 0.9)
        if not ls.ok:
            return tracker.finish(
                x, Status.LINE_SEARCH_FAILED, "line search failed: no Wolfe step along descent"
            )
        x, energy, grad = x_new, energy_new, grad_new
        if negative is not None:
            length = ls.step * vnorm(direction)
            x, energy, grad = follow_negative_curvature(problem, x, energy, grad, negative, length)
        if tracker.record(energy, grad):
            return tracker.finish(x, Status.CONVERGED, "converged")
    return tracker.finish(x, Status.ITERATION_LIMIT, f"iteration limit {maxiter} reached")
