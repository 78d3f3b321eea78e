"""The host side of the JAX engine: an :class:`Engine` holds an objective's pairs and
preconditioner on the device, runs the jitted loops of :mod:`._loops` and rebuilds what they
stop for (the Verlet list, the preconditioner, a full history) between them."""

from __future__ import annotations

import time
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import NDArray

from ...minimize import MinimizeResult, Status
from ...minimize.cg import C2 as CG_C2
from ...minimize.fire import ALPHA_START, default_timesteps
from ...minimize.lbfgs import C2 as LBFGS_C2
from ...model.objective import Objective
from ..precon import ExpPreconditioner
from . import _cells
from ._batch import run_loop
from ._loops import (
    CONVERGED,
    FULL,
    HISTORY,
    LIMIT,
    MARGIN,
    NO_STEP,
    NOT_FINITE,
    PRECON,
    REBUILD,
    RUNNING,
    Descent,
    Fire,
)
from ._pairs import Pairs, block_max, capacity_for, device_pairs, energy_gradient
from ._precon import Hierarchy, apply

apply_compiled = jax.jit(apply)
PAIRS = {2: 3, 3: 6}
"""First guess of the device list's pairs per particle within the engine's skin, by dimension
(above what dense packings hold: ``docs/decisions.md``, section "The list on the device")."""
_CAPACITIES: dict[tuple[Any, ...], tuple[int, int]] = {}
"""The device list's capacities last used for packings of one size and bin layout: the engines
of a protocol's steps start from them (no overflow to find again, no new compilation)."""
_STATUS = {
    CONVERGED: (Status.CONVERGED, "converged"),
    LIMIT: (Status.ITERATION_LIMIT, "iteration limit {maxiter} reached"),
    NO_STEP: (Status.LINE_SEARCH_FAILED, "line search failed: no Wolfe step along descent"),
    NOT_FINITE: (Status.NOT_FINITE, "the energy or gradient is not finite"),
}


class Engine:
    """The JAX engine for the packing of ``objective`` (its radii, cell, contact law, internal
    particle order, step cap and energy round-off): minimizes from flat vectors in that order.

    Parameters
    ----------
    objective : the packing's :class:`~athermal.model.objective.Objective` (host side: the
        tolerances, FIRE's curvature bound and the preconditioner's ``mu`` come from it).
    precon : ``none`` or ``exp`` (the paper's, on the device: :mod:`._precon`).
    A : the Exp weights' decay.
    """

    def __init__(
        self,
        objective: Objective,
        precon: Literal["none", "exp"] = "none",
        *,
        A: float = 0.0,
    ) -> None:
        self.objective = objective
        self.law = objective.model.law
        inner = objective.packing(objective.x0, internal=True)
        self.typeid = np.asarray(objective.model.typeid(inner), dtype=np.int64)
        self.margin = MARGIN * objective.max_step
        self.skin = objective.skin + 2.0 * self.margin
        self.pairs: Pairs | None = None
        cell = objective.cell
        self.nbins = _cells.bins_for(cell, 2.0 * float(objective.radii.max()) + self.skin)
        """Bins of the device's cell list (None: the host builds the list, a small cell)."""
        occupancy = objective.n / float(np.prod(self.nbins)) if self.nbins else 0.0
        self._size_class = (objective.n, objective.dim, self.nbins)
        self.bin_capacity, self.pair_capacity = _CAPACITIES.get(
            self._size_class,
            (
                max(8, int(np.ceil(2.0 * occupancy)) + 2),
                capacity_for(PAIRS[objective.dim] * objective.n),
            ),
        )
        self.overflows = 0
        """Builds of the device's list that overflowed a capacity (and were built again)."""
        self._device = (
            jnp.asarray(objective.radii),
            jnp.asarray(self.typeid),
            jnp.asarray(np.asarray(objective.model.kmat, dtype=np.float64)),
            jnp.asarray(cell.h),
        )
        self.precon = ExpPreconditioner(objective, A=A) if precon == "exp" else None
        self.hierarchy: Hierarchy | None = None
        self.n_rebuilds = 0

    @property
    def precon_name(self) -> str:
        """``exp`` or ``none``."""
        return "none" if self.precon is None else "exp"

    def _positions(self, x: Any) -> NDArray[np.float64]:
        return np.array(x, dtype=np.float64, copy=True).reshape(
            self.objective.n, self.objective.dim
        )

    def _fresh_pairs(self, positions: NDArray[np.float64]) -> Pairs:
        """The device Verlet list, rebuilt at ``positions`` ``(N, d)`` unless it is current."""
        pairs = self.pairs
        if pairs is None or _moved_sq(positions, pairs.reference) > self._reach_sq(pairs):
            capacity = 0 if pairs is None else pairs.capacity
            obj = self.objective
            if self.nbins is None:
                pairs = device_pairs(
                    positions, obj.radii, obj.cell, obj.model, self.typeid, self.skin, capacity
                )
            else:
                pairs = self._cell_list(positions)
            self.pairs = pairs
            self.n_rebuilds += 1
        return pairs

    def _cell_list(self, positions: NDArray[np.float64]) -> Pairs:
        """The list built on the device (:mod:`._cells`), built again with larger capacities
        until none overflows."""
        assert self.nbins is not None
        x = jnp.asarray(positions)
        while True:
            arrays, count, fullest, overflow = _cells.build_compiled(
                x, *self._device, self.skin, self.nbins, self.bin_capacity, self.pair_capacity
            )
            if not bool(overflow):
                _CAPACITIES[self._size_class] = (self.bin_capacity, self.pair_capacity)
                first, second, shift, radius_sum, stiffness = arrays
                return Pairs(
                    first,
                    second,
                    shift,
                    radius_sum,
                    stiffness,
                    int(count),
                    self.pair_capacity,
                    positions,
                    self.skin,
                )
            self.overflows += 1
            self.bin_capacity = max(self.bin_capacity, int(fullest) + 2)
            self.pair_capacity = capacity_for(int(count), self.pair_capacity)

    def _reach_sq(self, pairs: Pairs) -> float:
        """How far (squared) an iterate may move from the list's build."""
        return max(0.5 * pairs.skin - self.margin, 0.0) ** 2

    def _fresh_hierarchy(self, positions: NDArray[np.float64]) -> Hierarchy | None:
        """The device preconditioner, rebuilt at ``positions`` when due."""
        if self.precon is None:
            return None
        old = self.hierarchy
        if old is None or _moved_sq(positions, old.reference) > old.reach_sq:
            matrix = self.precon.assemble(positions.ravel())
            capacities = () if old is None else old.capacities
            self.hierarchy = Hierarchy.of(matrix, positions, self.precon.reach**2, capacities)
        return self.hierarchy

    def minimize(
        self,
        method: str,
        x0: NDArray[np.float64],
        *,
        gtol: float,
        etol: float = 0.0,
        maxiter: int = 100_000,
        memory: int = 10,
        polak: bool = False,
        precon: str | None = None,
    ) -> MinimizeResult:
        """Minimize from ``x0`` ``(N d,)`` (internal order) by ``method`` (``fire``, always
        without the preconditioner; ``lbfgs``; ``cg``, with ``polak`` Polak-Ribiere+) to
        ``max_i |grad_i| <= gtol`` or energy ``<= etol`` within ``maxiter`` iterations; the
        result as the CPU engine's. The engine holds one preconditioner: ``precon`` (an
        :class:`~athermal.engines.Session`'s choice of another) must be None."""
        if precon is not None:
            raise ValueError(f"the JAX engine holds its own preconditioner; got {precon}")
        t0 = time.perf_counter()
        obj = self.objective
        positions = self._positions(x0)
        pairs = self._fresh_pairs(positions)
        lap = self._fresh_hierarchy(positions) if method != "fire" else None
        x = jnp.asarray(positions)
        energy, grad = energy_gradient(x, pairs.arrays, self.law)
        energies, gradients = [float(energy)], [float(block_max(grad))]
        scale, factor, power = obj.hooks.noise
        dt = dt_max = dt_min = 0.0  # FIRE's alone
        if method == "fire":
            dt, dt_max, dt_min = default_timesteps(
                None, None, None, None, obj.curvature_bound(positions.ravel())
            )
        c2 = LBFGS_C2 if method == "lbfgs" else CG_C2
        settings: tuple[float, ...] = (gtol, etol, maxiter, dt_max, dt_min, obj.max_step, c2)
        settings += (scale, factor, power)
        history = jnp.zeros((2, HISTORY))
        state: Any
        zero, running = jnp.int64(0), jnp.int64(RUNNING)
        if method == "fire":
            state = Fire(
                x=x,
                v=jnp.zeros_like(x),
                dt=jnp.float64(dt),
                mix=jnp.float64(ALPHA_START),
                n_pos=zero,
                iterations=zero,
                energy=energy,
                grad=grad,
                history=history,
                recorded=zero,
                code=running,
            )
        else:
            z = grad if lap is None else apply_compiled(grad, *lap.arrays)
            rows = memory if method == "lbfgs" else 1
            empty = jnp.zeros((rows, *x.shape))
            state = Descent(
                x=x,
                grad=grad,
                z=z,
                energy=energy,
                direction=-z,
                slope=-jnp.vdot(grad, z),
                step=jnp.float64(1.0),
                yg=jnp.vdot(z, grad),
                s=empty,
                y=empty,
                py=empty,
                rho=jnp.ones(rows),
                count=zero,
                head=zero,
                restarted=jnp.bool_(True),
                iterations=zero,
                evaluations=zero,
                history=history,
                recorded=zero,
                code=running,
            )
        evaluations = 1
        code = CONVERGED if gradients[-1] <= gtol or energies[-1] <= etol else RUNNING
        if not (np.isfinite(energies[-1]) and np.isfinite(gradients[-1])):
            code = NOT_FINITE
        if code == RUNNING and maxiter == 0:
            code = LIMIT
        while code == RUNNING:
            geometry = (pairs.reference, self._reach_sq(pairs), *self._precon_geometry(lap))
            if method == "fire":
                state = run_loop("fire", state, (pairs.arrays, geometry, settings), (self.law,))
            else:
                hierarchy = lap.arrays if lap is not None else ()
                statics = (self.law, method == "lbfgs", polak, lap is not None)
                operands = (pairs.arrays, geometry, hierarchy, settings)
                state = run_loop("descent", state, operands, statics)
            recorded = int(state.recorded)
            log = np.asarray(state.history[:, :recorded])
            energies.extend(log[0].tolist())
            gradients.extend(log[1].tolist())
            code = int(state.code)
            state = state._replace(recorded=jnp.int64(0), code=jnp.int64(RUNNING))
            if code in (FULL, REBUILD, PRECON):  # whatever stopped it, all is made current
                positions = self._positions(state.x)
                pairs = self._fresh_pairs(positions)
                if lap is not None and self._fresh_hierarchy(positions) is not lap:
                    lap = self.hierarchy
                    state = _refreshed(state, lap)
                code = RUNNING
        iterations = int(state.iterations)
        if method == "fire":
            evaluations += iterations
        else:
            evaluations += int(state.evaluations)
        status, message = _STATUS[code]
        return MinimizeResult(
            x=np.array(state.x).ravel(),  # writable copies: numba's kernels take them
            jac=np.array(state.grad).ravel(),
            converged=status is Status.CONVERGED,
            status=status,
            message=message.format(maxiter=maxiter),
            method=f"{method} (jax)",
            precon=self.precon_name,
            iterations=iterations,
            evaluations=evaluations,
            seconds=time.perf_counter() - t0,
            energy=energies[-1],
            max_gradient=gradients[-1],
            gtol=gtol,
            history_energy=np.array(energies),
            history_max_gradient=np.array(gradients),
            precon_builds=0 if self.precon is None else self.precon.n_builds,
        )

    def _precon_geometry(self, lap: Hierarchy | None) -> tuple[Any, Any]:
        """The preconditioner's build and reach for the loops (None, None without one)."""
        if lap is None:
            return None, None
        return lap.reference, lap.reach_sq


def _refreshed(state: Any, lap: Hierarchy | None) -> Any:
    """``state`` after the preconditioner was rebuilt: ``z`` and L-BFGS's ``P^-1 y`` anew (the
    pairs cleared where one lost ``y.P^-1 y > 0``, the CPU engine's guard); CG restarts along
    the new preconditioned gradient from a unit step."""
    assert lap is not None
    z = apply_compiled(state.grad, *lap.arrays)
    py = jax.vmap(apply_compiled, in_axes=(0, None, None))(state.y, *lap.arrays)
    used = (jnp.arange(state.s.shape[0]) - state.head) % state.s.shape[0] >= (
        state.s.shape[0] - state.count
    )
    curved = jnp.all(jnp.where(used, jnp.sum(state.y * py, axis=(1, 2)) > 0.0, True))
    return state._replace(
        z=z,
        py=py,
        count=jnp.where(curved, state.count, 0),
        slope=jnp.float64(1.0),
        step=jnp.float64(1.0),
        yg=jnp.vdot(z, state.grad),
    )


def _moved_sq(positions: NDArray[np.float64], reference: NDArray[np.float64]) -> float:
    """The largest squared displacement of a particle between ``reference`` and
    ``positions``."""
    return float(np.max(np.sum((positions - reference) ** 2, axis=1)))
