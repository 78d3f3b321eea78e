"""The energy of a packing as a function of a flat vector of positions, for the minimizers.

:class:`Objective` maps ``x`` ``(N d,)`` to the contact energy and its gradient, caches the last
evaluation, counts evaluations and keeps its Verlet list fresh (rebuilt when a particle has moved
more than half the skin). Particles are held internally along a space-filling curve (the
kernels run 2-3.5x faster at N >= 65536); :meth:`Objective.packing` gives them back in the
caller's order. Frozen particles (rough walls, :func:`athermal.protocols.shear.rough_walls`) are
held where they are: their gradient rows are zero, so no minimizer moves them.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import _blocks
from .._blocks import PLACE, max_row_sq  # by name: numba folds PLACE in as a literal
from .._jit import _jit, rebound
from .._portable import dot, power
from ..errors import InputError
from ..linalg import pin_rows
from ..minimize import CompiledSearch, Hooks, SparseHessian, compiled_function
from ..minimize._wolfe import GO_ON, STATE_SIZE, TRIAL, feed
from .contact import ContactModel, HessianOperator, energy_gradient_contacts, find_contacts
from .law import ContactLaw
from .loops import ONE_THREAD, count_overlaps, evaluate, kernels, parallel_slabs
from .neighbors import NeighborList, build_neighbor_list, default_skin
from .packing import Packing
from .walls import WallContacts, find_wall_contacts

MAX_STEP_FACTOR = 0.1
"""Largest displacement of one particle in one iteration, as a multiple of the mean radius."""


class Objective:
    """``E(x)`` and ``grad E(x)`` for the positions of ``packing`` (radii and cell fixed).

    Parameters
    ----------
    packing : start configuration; ``x0`` holds its positions (internal order) and is where
        the next minimization starts (:meth:`start_from` moves it).
    model : contact law.
    skin : Verlet skin (length units); default :func:`~athermal.model.neighbors.default_skin`.
    sort : hold particles along a space-filling curve internally (recommended).
    frozen : mask ``(N,)`` (caller's order) of particles held fixed: their gradient rows are
        zero, the preconditioners and the Hessian decouple them (:func:`~athermal.linalg.
        pin_rows`), and the compiled line search is not offered (it would return their rows).
    """

    def __init__(
        self,
        packing: Packing,
        model: ContactModel,
        *,
        skin: float | None = None,
        sort: bool = True,
        frozen: NDArray[np.bool_] | None = None,
    ) -> None:
        self.order = packing.spatial_order() if sort else np.arange(packing.n)
        self.frozen = None if frozen is None else _frozen_mask(frozen, packing.n)
        """The frozen mask ``(N,)`` in the caller's order, or None."""
        held = np.zeros(0, np.intp)
        if self.frozen is not None:
            held = np.flatnonzero(self.frozen[self.order])
        self.frozen_particles = held
        """The frozen particles ``(F,)`` (internal order)."""
        self.frozen_rows = (held[:, None] * packing.dim + np.arange(packing.dim)).ravel()
        """Their flat coordinates ``(F d,)`` (internal order)."""
        inner = packing.permuted(self.order)
        self.model = model
        self.cell = inner.cell
        self.radii = np.ascontiguousarray(inner.radii)
        self.dim = inner.dim
        self.n = inner.n
        self.skin = default_skin(self.radii) if skin is None else float(skin)
        self.x0 = np.ascontiguousarray(inner.positions).ravel().copy()
        self._typeid = model.typeid(inner)
        self._walls = model.walls(self.cell)
        self._nlist: NeighborList | None = None
        self._shifts = np.zeros((1, self.dim))
        self._slabs = (ONE_THREAD, False)
        self._last_x = np.full(self.n_dof, np.nan)  # NaN: nothing evaluated yet
        self._last: tuple[float, NDArray[np.float64]] = (0.0, np.zeros(0))
        self._last_contacts = 0
        self.n_evaluations = 0
        self.n_rebuilds = 0
        self.max_step = MAX_STEP_FACTOR * float(np.mean(self.radii))
        # the round-off of the energy near E: each overlap carries an absolute error
        # ~eps_mach |x| from the coordinates, so E carries ~eps_mach L |f|_2 with
        # |f|_2^2 = sum_c f_c^2 <= k^(2/alpha) (alpha E)^(2 - 2/alpha); with L the largest cell
        # width this bound overestimates the scatter of E (docs/decisions.md, "Measured behind
        # the code"): a quarter of it
        noise_scale = (
            0.25
            * float(np.finfo(np.float64).eps)
            * float(self.cell.widths.max())
            * float(power(model.kmat.max(), 1.0 / model.alpha))
        )
        alpha = float(model.alpha)
        self.hooks = Hooks(self.dim, self.max_step, (noise_scale, alpha, 1.0 - 1.0 / alpha))
        """The minimizers' hooks: blocks of ``d`` coordinates (one particle each), the step cap
        :attr:`max_step` (``MAX_STEP_FACTOR`` x the mean radius) and the round-off of the
        energy, ``scale (alpha E)^(1 - 1/alpha)``."""
        self._compiled: CompiledSearch | None = None

    @property
    def n_dof(self) -> int:
        """Number of degrees of freedom ``N d``."""
        return self.n * self.dim

    def neighbor_list(self, x: NDArray[np.float64]) -> NeighborList:
        """The Verlet list, rebuilt first if ``x`` moved a particle more than ``skin / 2``."""
        positions = x.reshape(self.n, self.dim)
        if self._nlist is None or not self._nlist.is_current(positions):
            self._nlist = build_neighbor_list(positions, self.radii, self.cell, self.skin)
            self._shifts = self._nlist.shifts(self.cell)
            self._slabs = parallel_slabs(self._nlist)
            self.n_rebuilds += 1
        return self._nlist

    def start_from(self, x: NDArray[np.float64]) -> None:
        """Make ``x`` ``(N d,)`` (internal order) the start ``x0`` of the next minimization."""
        if np.shape(x) != (self.n_dof,):
            raise InputError(f"x: expected shape ({self.n_dof},), got {np.shape(x)}")
        self.x0 = np.array(x, dtype=np.float64, copy=True)

    def __call__(self, x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        """Energy and gradient ``(N d,)`` at ``x``; repeated calls at the same ``x`` are free."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.shape == self._last_x.shape and _blocks.same_values(x, self._last_x):
            return self._last
        nlist = self.neighbor_list(x)
        grad = np.empty(self.n_dof)
        energy, self._last_contacts = energy_gradient_contacts(
            x.reshape(self.n, self.dim),
            self.radii,
            self._typeid,
            self._shifts,
            nlist,
            self.model,
            grad.reshape(self.n, self.dim),
            self._walls,
            self._slabs,
        )
        if self.frozen_rows.size:
            grad[self.frozen_rows] = 0.0
        self.n_evaluations += 1
        self._last_x[:] = x
        self._last = (energy, grad)
        return self._last

    def compiled_search(self) -> CompiledSearch | None:
        """The energy's line search in compiled code, for the minimizers
        (:class:`~athermal.minimize.CompiledSearch`): :func:`energy_search` over the current
        Verlet list, until the search ends or a trial point moves a particle more than
        ``skin / 2`` from the list's build (the minimizer then evaluates that point by
        ``self(...)``, which rebuilds the list); :meth:`took` takes its evaluations back.
        None with frozen particles: compiled loops would carry their gradient rows on."""
        if self.frozen_rows.size:
            return None
        if self._compiled is None:
            x = self.x0
            search = search_for(self.model.law)
            self._compiled = CompiledSearch(
                search,
                compiled_function(
                    search,
                    np.empty(STATE_SIZE),
                    GO_ON,
                    x,
                    x,
                    x,
                    x,
                    self.search_arguments(x),
                ),
                self.search_arguments,
                self.took,
            )
        return self._compiled

    def search_arguments(self, x: NDArray[np.float64]) -> tuple[Any, ...]:
        """The last argument of :func:`energy_search`: the radii, the current Verlet list (built
        at ``x`` ``(N d,)`` if there is none), the walls, the slabs of the threads' kernel
        (:func:`~athermal.model.loops.parallel_slabs`), and the positions the list was built at
        and its reach."""
        nlist = self.neighbor_list(x) if self._nlist is None else self._nlist
        return (
            *self._pair_arguments(nlist),
            *self._walls,
            *self._slabs,
            nlist.reference,
            nlist.reach_sq,
        )

    def _pair_arguments(self, nlist: NeighborList) -> tuple[Any, ...]:
        """What the compiled pair loops take after the positions: radii, ``nlist``'s pairs and
        image codes, their shifts, species and the contact law's ``kmat`` and ``alpha``."""
        return (
            self.radii,
            nlist.first,
            nlist.second,
            nlist.code,
            self._shifts,
            self._typeid,
            self.model.kmat,
            self.model.alpha,
        )

    def took(
        self,
        x: NDArray[np.float64],
        energy: float,
        grad: NDArray[np.float64],
        contacts: int,
        evaluations: int,
    ) -> None:
        """Take back ``evaluations`` made by compiled code, the last one becoming the cached one.

        That last one is at ``x`` ``(N d,)``, with ``energy``, ``grad`` and ``contacts``
        overlapping pairs."""
        self.n_evaluations += evaluations
        self._last_x[:] = x
        self._last = (float(energy), grad)
        self._last_contacts = int(contacts)

    def hessian(self, x: NDArray[np.float64]) -> HessianOperator | SparseHessian:
        """The Hessian of the energy at ``x`` (internal order) over the overlapping pairs of
        the Verlet list, as an operator (products, and the sparse matrix); with frozen
        particles, the sparse matrix with their rows decoupled (:func:`~athermal.linalg.
        pin_rows`)."""
        positions = np.ascontiguousarray(x, dtype=np.float64)
        nlist = self.neighbor_list(positions)
        size = nlist.first.size
        pairs = np.empty((size, 2), dtype=np.int64)
        sep = np.empty((size, self.dim))
        coef = np.empty((size, 2))
        positions_2d = positions.reshape(self.n, self.dim)
        arguments = (positions_2d, *self._pair_arguments(nlist), pairs, sep, coef)
        m = kernels(self.model.law)["hessian_terms"](*arguments)
        walls = self.wall_contacts(positions_2d)
        h = HessianOperator(self.n, pairs[:m], sep[:m], coef[:m], walls.hessian_terms())
        if self.frozen_rows.size:
            return SparseHessian(pin_rows(h.matrix(), self.frozen_rows), self.dim)
        return h

    def wall_contacts(self, positions: NDArray[np.float64]) -> WallContacts:
        """The wall contacts at ``positions`` ``(N, d)`` (internal order)."""
        kwall = self.model.kwall[self._typeid]
        return find_wall_contacts(positions, self.radii, kwall, self.model.law, self.cell)

    def count_contacts(self, x: NDArray[np.float64]) -> int:
        """Number of overlapping pairs and wall contacts at ``x``: counted by the last
        evaluation when ``x`` is its point, else by a compiled pass (the Verlet list is kept
        fresh)."""
        positions = np.ascontiguousarray(x, dtype=np.float64)
        if positions.shape == self._last_x.shape and _blocks.same_values(positions, self._last_x):
            return self._last_contacts
        nlist = self.neighbor_list(positions)
        positions = positions.reshape(self.n, self.dim)
        return self.wall_contacts(positions).particle.size + int(
            count_overlaps(
                positions, self.radii, nlist.first, nlist.second, nlist.code, self._shifts
            )
        )

    def max_gradient(self, grad: NDArray[np.float64]) -> float:
        """``max_i |grad_i|``: the largest Euclidean norm of one particle's gradient."""
        return self.hooks.max_gradient(grad)

    def tolerance(
        self, gtol: float | None, rtol: float | None, x: NDArray[np.float64] | None = None
    ) -> float:
        """The absolute force tolerance on ``max_i |grad_i|``: ``gtol``, or ``rtol`` x the mean
        contact force at ``x`` (default ``x0``); give exactly one of the two."""
        if (gtol is None) == (rtol is None):
            raise InputError("give exactly one of gtol (absolute) and rtol (x mean contact force)")
        at = self.x0 if x is None else x
        tol = gtol if gtol is not None else rtol * self.mean_contact_force(at)  # type: ignore[operator]
        if not np.isfinite(tol) or tol < 0.0:
            raise InputError(f"gtol/rtol: tolerance must be finite and >= 0, got {tol}")
        return float(tol)

    def curvature_bound(self, x: NDArray[np.float64]) -> float:
        """Gershgorin bound ``lambda_G >= lambda_max(H)`` on the Hessian of the energy at ``x``.

        A contact's Hessian block ``K_ij = E'' n n^T - (f/l) (I - n n^T)`` has norm ``E''`` (the
        law's stiffness, :meth:`~athermal.model.law.ContactLaw.stiffness`), and row ``i`` of
        ``H`` holds ``H_ii = sum_j K_ij`` and ``H_ij = -K_ij``, so
        ``lambda_max <= lambda_G = 2 max_i sum_j E''_ij`` (``2 k z_max`` for Hooke contacts); a
        wall contact adds its ``E''`` once, to its particle's row. Units force / length, i.e.
        1 / time^2 for unit masses (FIRE's default time step). Without contacts it falls back to
        a particle with 6 (2D) or 12 (3D) contacts of overlap ``delta`` = the mean radius.
        """
        model = self.model
        contacts = find_contacts(self.packing(x, internal=True), model, self.neighbor_list(x))
        walls = self.wall_contacts(np.asarray(x).reshape(self.n, self.dim))
        if contacts.i.size == 0 and walls.particle.size == 0:
            z_ref = 6.0 if self.dim == 2 else 12.0
            r_mean = float(np.mean(self.radii))
            k_max = max(float(np.max(model.kmat)), float(np.max(model.kwall)))
            return 2.0 * z_ref * float(model.law.stiffness(np.array([r_mean]), k_max)[0])
        stiff = contacts.normal_stiffness
        per_particle = np.bincount(contacts.i, stiff, self.n)
        per_particle += np.bincount(contacts.j, stiff, self.n)
        particle, _, wall_stiff = walls.hessian_terms()
        return float(np.max(2.0 * per_particle + np.bincount(particle, wall_stiff, self.n)))

    def mean_contact_force(self, x: NDArray[np.float64]) -> float:
        """Mean contact force ``f(delta)`` over overlapping pairs at ``x`` (0 with no contacts)."""
        forces = find_contacts(self.packing(x, internal=True), self.model).force_magnitude
        return float(forces.mean()) if forces.size else 0.0

    def packing(self, x: NDArray[np.float64], *, internal: bool = False) -> Packing:
        """The packing at ``x``, particles in the caller's order (or the internal one)."""
        positions = np.asarray(x, dtype=np.float64).reshape(self.n, self.dim)
        if not internal:
            restored = np.empty_like(positions)
            restored[self.order] = positions
            positions = restored
            radii = np.empty_like(self.radii)
            radii[self.order] = self.radii
            return Packing(positions, radii, self.cell)
        return Packing(positions, self.radii, self.cell)


def _frozen_mask(frozen: NDArray[np.bool_], n: int) -> NDArray[np.bool_]:
    """``frozen`` checked: a boolean mask ``(n,)`` that leaves a particle free."""
    mask = np.asarray(frozen)
    if mask.shape != (n,) or mask.dtype != np.bool_:
        raise InputError(
            f"frozen: expected a boolean mask of shape ({n},), got {mask.dtype} {mask.shape}"
        )
    if mask.all():
        raise InputError("frozen: every particle is frozen; nothing is left to relax")
    return mask.copy()


@cache
def search_for(law: ContactLaw) -> Any:
    """:func:`energy_search` for ``law``: this module's own for the power law, else compiled
    once more over the law's loops (:func:`~athermal.model.loops.kernels`), once per law."""
    law_evaluate = kernels(law)["evaluate"]
    if law_evaluate is evaluate:
        return energy_search
    return rebound((energy_search,), {"evaluate": law_evaluate})["energy_search"]


@_jit
def energy_search(state, code, x, direction, trial, grad, arguments):  # type: ignore[no-untyped-def]
    """Run the search of ``state`` (last code ``code``) on the contact energy along
    ``direction`` from ``x`` ``(N d,)``: each trial point is written into ``trial``, its
    gradient into ``grad``, by the energy kernel over the Verlet list in ``arguments``
    (:meth:`Objective.search_arguments`: the radii, ``first``, ``second``, ``images`` and the
    rest as :func:`~athermal.model.loops.energy_gradient_2d` takes them, the walls and slabs as
    :func:`~athermal.model.loops.evaluate` takes them, then the positions
    ``reference`` ``(N, d)`` the list was built at and its reach ``reach_sq``), until the
    search ends or a trial point is farther than ``sqrt(reach_sq)`` from ``reference``.
    Returns the code, the evaluations made, the last energy and contact count, and whether it
    stopped at a trial point out of reach (not evaluated: ``trial`` holds the last point
    evaluated here, or, when none was, the point out of reach).

    Energies and gradients are :func:`evaluate`'s, as in :meth:`Objective.__call__`."""
    evaluated = arguments[:13]  # what evaluate takes after the points and their gradient
    reference, reach_sq = arguments[13], arguments[14]
    n, dim = reference.shape
    points = trial.reshape(n, dim)
    gradient = grad.reshape(n, dim)
    evaluations = 0
    energy = 0.0
    contacts = 0
    last = 0.0  # the step of the last point evaluated here
    while code == GO_ON:
        a = state[TRIAL]
        if _place_trial(x, direction, a, reference, trial) > reach_sq:
            if evaluations:
                _place_trial(x, direction, last, reference, trial)
            return code, evaluations, energy, contacts, True
        energy, contacts = evaluate(points, gradient, *evaluated)
        evaluations += 1
        last = a
        code = feed(state, energy, dot(grad, direction))
    return code, evaluations, energy, contacts, False


@_jit
def _place_trial(x, direction, a, reference, trial):  # type: ignore[no-untyped-def]
    """Write the trial point ``x + a direction`` into ``trial`` (all flat) and return
    ``max_i |trial_i - reference_i|^2`` over the ``(n, d)`` rows of ``reference``: one pass
    over the vectors for the point and its reach test, which sees the very point evaluated."""
    flat = reference.reshape(reference.size)
    return max_row_sq(x, direction, a, flat, trial, reference.shape[1], PLACE)
