"""Bulk and shear moduli of a packing at an energy minimum by exact linear response.

Linear response. Deform positions and cell along an affine path ``x -> D(gamma) x`` with
``D(0) = I``, ``D1 = D'(0)``, ``D2 = D''(0)``, and let the particles relax by non-affine
displacements ``u``. For a contact with branch vector ``r = x_i - x_j`` (length ``l``, unit
``n``) and pair energy ``phi(l) = E(delta)`` (the contact law, :mod:`athermal.model.law`),
``delta = r_i + r_j - l``, so that ``phi' = -f(delta)`` and ``phi'' = E''(delta)``:

* affine curvature ``d2E/dgamma2 = sum_c phi'' (n.D1 r)^2 + (phi'/l) (|D1 r|^2 - (n.D1 r)^2)
  + phi' n.D2 r``;
* mixed derivative ``Xi = d2E/du dgamma`` ``(N d,)``: ``+K D1 r`` on ``i`` (the head of ``r``)
  and ``-K D1 r`` on ``j``, with ``K = phi'' n n^T + (phi'/l) (I - n n^T)`` (the Hessian block
  of :func:`~athermal.model.contact.contact_blocks`);
* relaxed curvature ``E''_rel = d2E/dgamma2 - Xi^T H^+ Xi`` (H the Hessian): minimizing the
  quadratic expansion ``E''_aff gamma^2 / 2 + gamma Xi.u + u.H u / 2`` over ``u``.

Rattlers (:func:`~athermal.analysis.observables.rattlers`) and every contact that touches one are
left out of all three terms; the translations along the periodic axes (``d`` of them in a periodic
cell), zero modes of ``H``, are removed by pinning one particle along them (``Xi`` sums to zero
there, so the minimum is unchanged). Between walls (:mod:`athermal.model.walls`) a wall contact adds
its terms with the wall's distance ``n.D r`` (no tangential term, no partner), and a deformation
must keep the walls untilted. Moduli follow from ``E''_rel``:
simple shear ``D1 = e0 e1^T`` gives ``G = E''_rel / V = -d sigma_01 / d gamma``; isotropic
compression at fixed radii ``D = (1 + e) I`` gives ``p(e) = -(1+e)^(1-d) dE/de / (d V0)`` and so
``B = -V dp/dV = E''_rel / (d^2 V) + (d - 1) p / d``.

The paper's finite-strain measurement (small strain steps, each relaxed) lives with the protocols
(:mod:`athermal.protocols.finite_strain`).

Energies are in units of ``k`` x length^alpha, moduli and stresses in ``k`` x length^(alpha-d)
(for a power law).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike, NDArray

from .._portable import row_dots, transform
from .._validate import float_array
from ..errors import InputError
from ..linalg import Factor, arpack_start, cholesky, supernodal_cholesky
from ..model.cell import AXES, pure_shear_derivatives, simple_shear, tilted_wall
from ..model.contact import ContactModel, Contacts, find_contacts, hessian, hessian_floor
from ..model.packing import Packing
from .observables import pressure, rattlers, stress

STABILITY_TOL = 1e-10
"""The pinned Hessian counts as positive semidefinite when ``H + s I`` is positive definite with
``s = STABILITY_TOL`` x its mean diagonal entry. Hessian entries carry round-off of ~1e-16 of the
contact stiffness; the negative curvature of a saddle is set by the contact forces over their
lengths (``f / l`` ~ ``delta / l``, ~1e-7 of the stiffness 1e-6 above jamming); a marginal
minimum relaxed to force balance can show a slightly negative one (``docs/decisions.md``,
"Measured behind the code")."""
DENSE_EIGEN_DOFS = 3000
"""Largest pinned Hessian whose lowest eigenpair is found by a dense solve (ARPACK in
shift-invert mode above it)."""

RESIDUAL_TOL = 1e-8
"""Relative residual ``|H y - Xi| / |Xi|`` above which the direct solve is refined by MINRES."""
RESIDUAL_WARN = 1e-6
"""Relative residual above which :func:`relaxed_strain_curvature` warns (``Xi`` not in the range
of ``H``: a floppy mode couples to the strain and the relaxed curvature is ill-defined)."""

SolverUsed = Literal["none", "cholmod", "minres"]
"""How ``H y = Xi`` was solved: not at all (fewer than two non-rattlers), by CHOLMOD, or by the
MINRES fallback."""


@dataclass(frozen=True)
class LinearResponse:
    """Moduli from the exact linear response of a packing at an energy minimum.

    Attributes
    ----------
    bulk : bulk modulus ``B = -V dp/dV`` at fixed radii (non-affine relaxation included).
    shear : shear modulus ``G = -d sigma_01 / d gamma`` under simple shear ``x += gamma y``
        (between walls normal to x or y: the pure-shear modulus, :func:`linear_response`).
    bulk_affine, shear_affine : the same without relaxation (Born terms, prestress included).
    pressure : ``p`` from the contacts between non-rattlers.
    n_rattlers : particles left out (:func:`~athermal.analysis.observables.rattlers`).
    residual : largest relative residual ``|H y - Xi| / |Xi|`` of the two linear solves.
    solver : ``"cholmod"`` (the pinned Hessian of the non-rattlers was positive definite),
        ``"minres"`` (it was not, or the direct residual was too large) or ``"none"`` (fewer
        than two non-rattlers: nothing to relax).
    """

    bulk: float
    shear: float
    bulk_affine: float
    shear_affine: float
    pressure: float
    n_rattlers: int
    residual: float
    solver: SolverUsed


def strain_terms(
    contacts: Contacts, n: int, d1: NDArray[np.float64], d2: NDArray[np.float64] | None = None
) -> tuple[float, NDArray[np.float64]]:
    """Affine curvature ``d2E/dgamma2`` and mixed derivative ``Xi = d2E/dx dgamma``.

    Parameters
    ----------
    contacts : the contacts to sum over (all of them are used), wall contacts included: a
        wall's distance to a centre is ``n.D r`` (``D`` must keep the walls untilted).
    n : number of particles N.
    d1, d2 : ``(d, d)`` first and second derivatives of the deformation ``D(gamma)`` at
        ``gamma = 0`` (``d2`` None: zero, as for simple shear and isotropic strain).

    Returns
    -------
    curvature : ``d2E/dgamma2`` at fixed non-affine displacements, energy units.
    xi : ``(N, d)`` derivative of the gradient ``dE/dx`` along the affine path, energy / length.
    """
    r = contacts.branch
    length = contacts.distance
    unit = contacts.normal
    dphi = -contacts.force_magnitude
    ddphi = contacts.normal_stiffness
    a = transform(r, d1)  # D1 r, (M, d)
    na = row_dots(unit, a)
    aa = row_dots(a, a)
    tension = dphi / length
    curvature = float(np.sum(ddphi * na**2 + tension * (aa - na**2)))
    if d2 is not None:
        curvature += float(np.sum(dphi * row_dots(unit, transform(r, d2))))
    k_a = (ddphi * na)[:, None] * unit + tension[:, None] * (a - na[:, None] * unit)  # K D1 r
    xi = np.zeros((n, r.shape[1]))
    for axis in range(r.shape[1]):
        xi[:, axis] = np.bincount(contacts.i, k_a[:, axis], n) - np.bincount(
            contacts.j, k_a[:, axis], n
        )
    if contacts.walls is not None and contacts.walls.particle.size:
        wall = contacts.walls  # a flat wall: distance n.D r, no tangential term, no partner
        w_unit, w_r = wall.normal, wall.branch
        w_na = row_dots(w_unit, transform(w_r, d1))
        w_ddphi = wall.normal_stiffness
        curvature += float(np.sum(w_ddphi * w_na**2))
        if d2 is not None:
            curvature -= float(np.sum(wall.force_magnitude * row_dots(w_unit, transform(w_r, d2))))
        np.add.at(xi, wall.particle, (w_ddphi * w_na)[:, None] * w_unit)
    return curvature, xi


def relaxed_strain_curvature(
    packing: Packing, model: ContactModel, d1: ArrayLike, d2: ArrayLike | None = None
) -> tuple[float, float]:
    """Affine and relaxed ``d2E/dgamma2`` along the deformation path with derivatives ``d1, d2``.

    Parameters
    ----------
    packing : a configuration at an energy minimum (radii and cell fixed).
    model : contact law.
    d1, d2 : ``(d, d)`` first and second derivatives of ``D(gamma)`` at 0 (``d2`` None: zero).
        Pure shear ``diag(1 + g, 1 / (1 + g))`` has ``d1 = diag(1, -1)``, ``d2 = diag(0, 2)``.

    Returns
    -------
    (affine, relaxed) curvatures in energy units; rattlers and their contacts left out. A
    ``RuntimeWarning`` reports a linear solve whose relative residual exceeds ``RESIDUAL_WARN``.

    Examples
    --------
    >>> from athermal.model.cell import Cell
    >>> p = Packing([[0.0, 0.0]], [0.1], Cell.box([1.0, 1.0]))
    >>> relaxed_strain_curvature(p, ContactModel(), [[0.0, 1.0], [0.0, 0.0]])
    (0.0, 0.0)
    """
    dim = packing.dim
    d1_arr = _untilting(packing, float_array(d1, "d1", (dim, dim)), "d1")
    d2_arr = None if d2 is None else _untilting(packing, float_array(d2, "d2", (dim, dim)), "d2")
    contacts, rattler = nonrattler_contacts(packing, model)
    affine, xi = strain_terms(contacts, packing.n, d1_arr, d2_arr)
    correction, residual, _ = _nonaffine_correction(
        contacts, rattler, xi[:, :, None], packing.cell.walls
    )
    _warn_if_poor(residual, "relaxed_strain_curvature")
    return affine, affine - float(correction[0])


def nonaffine_displacement(
    packing: Packing, model: ContactModel, d1: ArrayLike
) -> NDArray[np.float64]:
    """The linear-response displacement ``u = -H^+ Xi`` ``(N, d)`` that relaxes the affine
    deformation ``x -> (I + d1) x`` of a packing at an energy minimum, to first order in ``d1``.

    ``Xi`` is :func:`strain_terms`' mixed derivative along the deformation, ``H`` the Hessian of
    the non-rattlers (translations pinned); rattlers get ``u = 0``. ``packing.deform(I + d1)``
    moved by ``u`` is the start a quasi-static step predicts for its relaxation. A
    ``RuntimeWarning`` reports a solve whose relative residual exceeds ``RESIDUAL_WARN``.
    """
    dim = packing.dim
    d1_arr = _untilting(packing, float_array(d1, "d1", (dim, dim)), "d1")
    contacts, rattler = nonrattler_contacts(packing, model)
    return relaxing_displacement(contacts, rattler, d1_arr, packing.cell.walls)


def relaxing_displacement(
    contacts: Contacts,
    rattler: NDArray[np.bool_],
    d1: NDArray[np.float64],
    walls: tuple[int, ...] = (),
    *,
    portable: bool = True,
) -> NDArray[np.float64]:
    """:func:`nonaffine_displacement` on given ``contacts`` between the non-rattlers (those of
    a certified packing, found in double-double): ``u = -H^+ Xi`` ``(N, d)``, zero on the
    ``rattler`` particles (``portable`` as :func:`pinned_solve` takes it). A ``RuntimeWarning``
    reports a poor solve."""
    n, dim = rattler.size, d1.shape[0]
    _, xi = strain_terms(contacts, n, d1)
    y, residual, _ = pinned_solve(contacts, rattler, xi[:, :, None], walls, portable=portable)
    _warn_if_poor(residual, "the linear response to a deformation")
    return -y[:, 0].reshape(n, dim)


def linear_response(packing: Packing, model: ContactModel) -> LinearResponse:
    """Bulk and shear moduli of ``packing`` (at an energy minimum) from its sparse Hessian.

    One factorization of the Hessian serves both: simple shear ``D1 = e0 e1^T`` gives
    ``G = E''_rel / V``; isotropic strain ``D1 = I`` gives ``B = E''_rel / (d^2 V) + (d-1) p / d``
    (radii fixed; walls moving with the cell). Moduli in units of ``k`` x length^(alpha-d).
    Between walls normal to x or y, simple shear would tilt the walls, which carry no shear
    stress; there ``G`` is the biaxial test's: pure shear ``D = diag(1 + gamma, 1 / (1 +
    gamma))`` (walls moving), ``G = (1/2) d tau / d gamma`` with ``tau = (sigma_yy -
    sigma_xx) / 2``, which is ``E''_rel / (4 V) + tau / 2`` (``E' = 2 V tau / (1 + gamma)``),
    and equals the simple-shear ``G`` of an isotropic solid.

    Examples
    --------
    >>> from athermal.model.contact import ContactModel
    >>> from athermal.model.packing import random_packing
    >>> from athermal.relaxation import relax
    >>> p = relax(random_packing(64, 0.88, seed=1), ContactModel(), rtol=1e-12)
    >>> lr = linear_response(p.packing, ContactModel())
    >>> bool(0.0 < lr.shear < lr.shear_affine)
    True
    """
    dim, volume = packing.dim, packing.cell.volume
    contacts, rattler = nonrattler_contacts(packing, model)
    sigma = stress(contacts, packing.cell)
    p = pressure(sigma)
    walls = packing.cell.walls
    if {0, 1} & set(walls):  # simple shear would tilt the walls: the biaxial test's modulus
        d1, d2 = pure_shear_derivatives(dim)
        shear_aff, xi_shear = strain_terms(contacts, packing.n, d1, d2)
        scale, offset = 1.0 / (4.0 * volume), 0.25 * float(sigma[1, 1] - sigma[0, 0])
    else:
        shear_aff, xi_shear = strain_terms(
            contacts, packing.n, simple_shear(1.0, dim) - np.eye(dim)
        )
        scale, offset = 1.0 / volume, 0.0
    bulk_aff, xi_bulk = strain_terms(contacts, packing.n, np.eye(dim))
    correction, residual, solver = _nonaffine_correction(
        contacts, rattler, np.stack([xi_shear, xi_bulk], axis=-1), walls
    )
    iso = (dim - 1) * p / dim
    return LinearResponse(
        bulk=(bulk_aff - float(correction[1])) / (dim**2 * volume) + iso,
        shear=(shear_aff - float(correction[0])) * scale + offset,
        bulk_affine=bulk_aff / (dim**2 * volume) + iso,
        shear_affine=shear_aff * scale + offset,
        pressure=p,
        n_rattlers=int(rattler.sum()),
        residual=residual,
        solver=solver,
    )


def zero_tolerance(h: sp.spmatrix) -> float:
    """Eigenvalues of the stiffness matrix ``h`` within this of zero are zero modes:
    :data:`STABILITY_TOL` x its mean diagonal entry."""
    return STABILITY_TOL * float(np.mean(np.abs(h.diagonal())))


def lowest_eigenpairs(
    h: sp.spmatrix,
    k: int,
    floor: float | None = None,
    *,
    saddle: bool = False,
    factor: Callable[[sp.csr_matrix], Factor | None] = cholesky,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The ``k`` lowest eigenvalues ``(k,)``, ascending, and eigenvectors ``(M, k)`` of the
    symmetric ``h``, none of whose eigenvalues lies below ``floor``
    (:func:`~athermal.model.contact.hessian_floor` of its contacts; None: Gershgorin's bound,
    the least diagonal entry less the absolute sum of its row's others, looser).

    ARPACK in shift-invert mode about ``sigma``, from a fixed start vector
    (:func:`~athermal.linalg.arpack_start`): the eigenvalues nearest ``sigma`` are the lowest
    only where none lies below it, so ``sigma = -zero_tolerance(h)`` where ``h - sigma I`` is
    positive definite (a minimum: the shift that separates its soft modes best), else ``floor -
    zero_tolerance(h)``, below every eigenvalue (a saddle's negative ones included), straight
    away where the caller knows ``h`` not positive definite (``saddle``: a factorization that
    fails costs its time and, in CHOLMOD, its memory). ``h - sigma I`` is factored by
    ``factor`` (default CHOLMOD, :func:`~athermal.linalg.cholesky`), or by SuperLU where that
    fails at the floor (round-off).
    """
    tolerance = zero_tolerance(h)
    if floor is None:
        diagonal = h.diagonal()
        others = np.asarray(abs(h).sum(axis=1)).ravel() - np.abs(diagonal)
        floor = float(np.min(diagonal - others))
    identity = sp.identity(h.shape[0], format="csr")
    shifts = () if saddle else (-tolerance,)
    for sigma in dict.fromkeys((*shifts, min(floor, 0.0) - tolerance)):
        shifted = factor((h - sigma * identity).tocsr())
        if shifted is not None:
            break
    inverse = None
    if shifted is not None:
        solve = shifted.solve
        inverse = spla.LinearOperator(
            h.shape, matvec=lambda v: solve(v.reshape(-1, 1)).ravel(), dtype=np.float64
        )
    values, vecs = spla.eigsh(
        h.tocsc(),
        k=k,
        sigma=sigma,
        which="LM",
        OPinv=inverse,
        tol=1e-12,
        v0=arpack_start(h.shape[0]),
    )
    order = np.argsort(values)
    return values[order], vecs[:, order]


@dataclass(frozen=True)
class Stability:
    """Whether a packing is at a local minimum of its energy (positions free, cell fixed).

    Attributes
    ----------
    stable : the Hessian of the non-rattlers with the translations pinned is positive
        semidefinite to round-off (:data:`STABILITY_TOL`): a minimum, not a saddle.
    lowest_eigenvalue : the lowest eigenvalue of that Hessian (energy / length^2) when it is not
        positive definite at the tolerance; ``None`` when the factorization proved it is.
    mode : ``(N, d)`` unit eigenvector of ``lowest_eigenvalue`` (zero on rattlers), the
        direction that lowers the energy of a saddle; ``None`` when stable.
    tolerance : the shift ``s`` of the test (energy / length^2).
    """

    stable: bool
    lowest_eigenvalue: float | None
    mode: NDArray[np.float64] | None
    tolerance: float


def stability(
    packing: Packing, model: ContactModel, frozen: NDArray[np.bool_] | None = None
) -> Stability:
    """Test that ``packing`` (force balanced) is a local minimum: its pinned Hessian is positive
    semidefinite. With ``frozen`` (a mask ``(N,)`` of particles held fixed, rough walls), the
    Hessian of the other particles is tested, the frozen ones pinned instead of a particle.

    One Cholesky factorization of ``H + s I`` (``s``: :data:`STABILITY_TOL`) decides; when it
    fails, the lowest eigenpair is computed (dense up to :data:`DENSE_EIGEN_DOFS` degrees of
    freedom, above it by :func:`lowest_eigenpairs` shift-inverted below the contacts' bound
    :func:`~athermal.model.contact.hessian_floor`) to tell a saddle (eigenvalue below ``-s``)
    from a marginal minimum.

    Examples
    --------
    >>> from athermal.model.cell import Cell
    >>> import numpy as np
    >>> g = (np.arange(4) + 0.5) / 4
    >>> square = Packing(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), np.full(16, 0.13),
    ...                  Cell.box([1.0, 1.0]))
    >>> s = stability(square, ContactModel(2.0))   # compressed square lattice: a saddle
    >>> s.stable, round(s.lowest_eigenvalue, 9)      # -4 f / l with f = 0.01, l = 0.25
    (False, -0.16)
    """
    dim = packing.dim
    contacts, rattler = nonrattler_contacts(packing, model, frozen)
    h, dofs = nonrattler_hessian(contacts, rattler, dim)
    if frozen is not None:  # the frozen particles pin the rest: no translation is left
        free = np.flatnonzero(~frozen[dofs // dim])
        h, dofs = h[free][:, free].tocsr(), dofs[free]
    if dofs.size <= (dim if frozen is None else 0):  # nothing left to move
        return Stability(True, None, None, 0.0)
    pinned = h
    if frozen is None:
        keep = unpinned(dofs.size, dim, packing.cell.walls)
        pinned = h[keep][:, keep]
    shift = zero_tolerance(h)
    test = pinned + shift * sp.identity(pinned.shape[0], format="csr")
    # a verdict and, for a saddle, a mode to leave it along: on the machine's BLAS (ARPACK's
    # eigenvector is the machine's anyway), many times faster on large 3D networks
    if supernodal_cholesky(test) is not None:
        return Stability(True, None, None, shift)
    # the free Hessian of the non-rattlers: its translations (along the periodic axes) are exact
    # zero modes, so its lowest eigenpair is the packing's (pinning would shift the eigenvalues)
    if h.shape[0] <= DENSE_EIGEN_DOFS:
        values, vectors = np.linalg.eigh(h.toarray())
    else:
        floor = hessian_floor(contacts, packing.n)
        values, vectors = lowest_eigenpairs(h, 1, floor, saddle=True, factor=supernodal_cholesky)
    value = float(values[0])
    if value >= -shift:
        return Stability(True, value, None, shift)
    mode = np.zeros((packing.n, dim))
    mode.reshape(-1)[dofs] = vectors[:, 0]
    return Stability(False, value, mode / np.linalg.norm(mode), shift)


def _warn_if_poor(residual: float, what: str) -> None:
    """A ``RuntimeWarning`` for the caller of ``what`` when a solve's relative residual exceeds
    ``RESIDUAL_WARN``."""
    if residual > RESIDUAL_WARN:
        warnings.warn(
            f"{what}: linear solve residual {residual:.2e}; the packing may not be at a stable "
            "minimum",
            RuntimeWarning,
            stacklevel=3,
        )


def nonrattler_contacts(
    packing: Packing, model: ContactModel, fixed: NDArray[np.bool_] | None = None
) -> tuple[Contacts, NDArray[np.bool_]]:
    """The contacts between non-rattlers and their wall contacts, and the rattler mask
    ``(N,)`` (the particles of ``fixed`` are never rattlers)."""
    contacts = find_contacts(packing, model)
    rattler = rattlers(contacts, packing.n, packing.dim, fixed)
    live = contacts.subset(~(rattler[contacts.i] | rattler[contacts.j]))
    if live.walls is not None:
        live = replace(live, walls=live.walls.subset(~rattler[live.walls.particle]))
    return live, rattler


def stiffness_matrix(
    packing: Packing, model: ContactModel, fixed: NDArray[np.bool_] | None = None
) -> tuple[sp.csr_matrix, NDArray[np.intp], NDArray[np.bool_]]:
    """The Hessian ``(N' d, N' d)`` of the non-rattlers (their contacts only, translations
    free), the flat indices ``(N' d,)`` of its rows among the ``N d`` coordinates, and the
    rattler mask ``(N,)`` (the particles of ``fixed`` are never rattlers)."""
    contacts, rattler = nonrattler_contacts(packing, model, fixed)
    h, dofs = nonrattler_hessian(contacts, rattler, packing.dim)
    return h, dofs, rattler


def nonrattler_hessian(
    contacts: Contacts, rattler: NDArray[np.bool_], dim: int
) -> tuple[sp.csr_matrix, NDArray[np.intp]]:
    """The Hessian ``(N' d, N' d)`` of ``contacts`` restricted to the non-rattlers, and the
    flat indices ``(N' d,)`` of its rows among the ``N d`` coordinates."""
    live = np.flatnonzero(~rattler)
    dofs = (live[:, None] * dim + np.arange(dim)).ravel()
    return hessian(contacts, rattler.size)[dofs][:, dofs].tocsr(), dofs


def _nonaffine_correction(
    contacts: Contacts,
    rattler: NDArray[np.bool_],
    xi: NDArray[np.float64],
    walls: tuple[int, ...] = (),
) -> tuple[NDArray[np.float64], float, SolverUsed]:
    """``Xi^T H^+ Xi`` for each of the ``m`` columns of ``xi`` ``(N, d, m)``, the largest
    relative residual of the solves and the solver used (:func:`pinned_solve`)."""
    y, residual, solver = pinned_solve(contacts, rattler, xi, walls)
    n, dim, m = xi.shape
    return np.einsum("km,km->m", xi.reshape(n * dim, m), y), residual, solver


def pinned_solve(
    contacts: Contacts,
    rattler: NDArray[np.bool_],
    xi: NDArray[np.float64],
    walls: tuple[int, ...] = (),
    *,
    iterative: bool = True,
    cholmod: bool = True,
    portable: bool = True,
) -> tuple[NDArray[np.float64], float, SolverUsed]:
    """``y = H^+ Xi`` ``(N d, m)`` for the ``m`` columns of ``xi`` ``(N, d, m)``, zero on the
    rattlers, with the largest relative residual and the solver used.

    H is restricted to the non-rattlers with the first of them pinned along the periodic axes
    (those not in ``walls``, the walled axes of the cell), which takes out the translations,
    and factored once for all columns (:func:`_solve`; without MINRES unless ``iterative``: a
    residual of infinity then says that H is not positive definite; by SuperLU unless
    ``cholmod``, :func:`~athermal.linalg.cholesky`; not ``portable``, by CHOLMOD on the
    machine's BLAS, many times faster on large 3D networks, :func:`~athermal.linalg.
    supernodal_cholesky`).
    """
    n, dim, m = xi.shape
    y = np.zeros((n * dim, m))
    if np.count_nonzero(~rattler) <= 1:
        return y, 0.0, "none"
    h, dofs = pinned_hessian(contacts, rattler, dim, walls)
    b = np.ascontiguousarray(xi.reshape(n * dim, m)[dofs])
    y[dofs], residual, solver = _solve(h, b, iterative, cholmod, portable)
    return y, residual, solver


def pinned_hessian(
    contacts: Contacts, rattler: NDArray[np.bool_], dim: int, walls: tuple[int, ...] = ()
) -> tuple[sp.csr_matrix, NDArray[np.intp]]:
    """The Hessian :func:`pinned_solve` solves with: H on the non-rattlers, the first of them
    pinned along the periodic axes (those not in ``walls``), and its rows' flat coordinates
    ``dofs`` (of ``N d``)."""
    h, dofs = nonrattler_hessian(contacts, rattler, dim)
    keep = unpinned(dofs.size, dim, walls)
    return h[keep][:, keep].tocsr(), dofs[keep]


def _untilting(packing: Packing, d: NDArray[np.float64], name: str) -> NDArray[np.float64]:
    """``d`` ``(d, d)``, refused (:class:`InputError`) when it would tilt the packing's walls
    (an entry off the diagonal in a walled axis's row or column)."""
    a = tilted_wall(d, packing.cell.walls)
    if a is not None:
        raise InputError(f"{name}: the deformation would tilt the walls normal to {AXES[a]}")
    return d


def unit_translations(
    dofs: NDArray[np.intp], dim: int, walls: tuple[int, ...] = ()
) -> NDArray[np.float64]:
    """The unit translations ``(M, t)`` along the periodic axes (those not in ``walls``) over
    the flat coordinates ``dofs`` ``(M,)`` (of ``N d``)."""
    axes = [a for a in range(dim) if a not in walls]
    along = np.zeros((dofs.size, len(axes)))
    for k, a in enumerate(axes):
        along[dofs % dim == a, k] = 1.0
    return along / np.linalg.norm(along, axis=0)


def unpinned(size: int, dim: int, walls: tuple[int, ...]) -> NDArray[np.intp]:
    """The rows ``(size - t,)`` of ``size`` flat coordinates left when the first particle is
    pinned along the ``t`` periodic axes (those not in ``walls``)."""
    periodic = [a for a in range(dim) if a not in walls]
    return np.setdiff1d(np.arange(size), periodic)


def _solve(
    h: sp.csr_matrix,
    b: NDArray[np.float64],
    iterative: bool = True,
    cholmod: bool = True,
    portable: bool = True,
) -> tuple[NDArray[np.float64], float, SolverUsed]:
    """A solution ``y`` ``(n, m)`` of ``h y = b`` for symmetric ``h`` ``(n, n)``, the largest
    relative residual ``|h y - b| / |b|`` over the columns and the solver that gave it.

    A direct factor first (:func:`_cholesky_solve`, reported as ``"cholmod"``); when ``h`` is not
    positive definite, or the residual exceeds ``RESIDUAL_TOL``, MINRES (from the direct answer,
    if any), which also solves consistent singular systems (``b`` in the range of ``h``). Not
    ``iterative``: the direct answer as it is, or zeros, an infinite residual and ``"none"``
    where ``h`` is not positive definite.
    """
    norms = np.linalg.norm(b, axis=0)
    y = _cholesky_solve(h, b, cholmod, portable)
    if y is None and not iterative:
        return np.zeros_like(b), np.inf, "none"
    if y is None:
        y = np.zeros_like(b)
    else:
        residual = _relative_residual(h, y, b, norms)
        if residual <= RESIDUAL_TOL or not iterative:
            return y, residual, "cholmod"
    for col in range(b.shape[1]):
        y[:, col] = spla.minres(h, b[:, col], x0=y[:, col], rtol=1e-14, maxiter=10 * b.shape[0])[0]
    return y, _relative_residual(h, y, b, norms), "minres"


def _cholesky_solve(
    h: sp.csr_matrix, b: NDArray[np.float64], cholmod: bool = True, portable: bool = True
) -> NDArray[np.float64] | None:
    """``h^-1 b`` by CHOLMOD (SuperLU unless ``cholmod``; on the machine's BLAS unless
    ``portable``); None when ``h`` is not positive definite."""
    factor = cholesky(h, cholmod=cholmod) if portable else supernodal_cholesky(h)
    return None if factor is None else factor.solve(b)


def _relative_residual(
    h: sp.csr_matrix, y: NDArray[np.float64], b: NDArray[np.float64], norms: NDArray[np.float64]
) -> float:
    """Largest ``|h y - b| / |b|`` over the columns with ``b != 0`` (``norms`` = ``|b|``; 0 when
    every column is zero)."""
    res = np.linalg.norm(h @ y - b, axis=0)
    nonzero = norms > 0.0
    return float(np.max(res[nonzero] / norms[nonzero], initial=0.0))
