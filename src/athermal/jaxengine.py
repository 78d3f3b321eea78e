"""A second engine on JAX (float64): the contact energy, its gradient and FIRE 2.0 as one jitted
loop, for accelerators (issue 37; this is its first part).

The engine sets ``jax_enable_x64`` when imported: JAX computes in float32 by default, whose
resolution (1e-7) is far above the force balance athermal relaxes to (1e-9 of the mean contact
force, and the jamming protocol's 1e-6 of its own forces at overlaps of 1e-9), so every array
here is float64. Without JAX installed, importing this module raises an
:class:`~athermal.errors.InputError` naming the extra (``pip install "athermal[jax]"``).

The pairs come from the CPU engine's Verlet list (:func:`athermal.neighbors.build_neighbor_list`,
exact in any sheared cell), padded to a capacity that only grows (a power of two), so that the
jitted functions are compiled once per capacity, not once per list; padding pairs join particle
0 to itself with a zero radius sum and contribute nothing. The FIRE loop runs on the device until
it converges, reaches its iteration limit or history, or a particle moves more than half the
skin from the list's build: then Python rebuilds the list and the loop goes on from where it
stopped, with the same state. One step is :func:`athermal.minimize.fire.fire`'s (FIRE 2.0 of
Guénolé et al. 2020, its time step, mixing, delay and step cap), so the two engines follow the
same equations; their trajectories agree to round-off, which chaotic relaxations amplify.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .contact import ContactModel
from .errors import JAX_MISSING, InputError
from .minimize import MinimizeResult, Status
from .minimize.fire import ALPHA_START, F_ALPHA, F_DEC, F_INC, N_DELAY, default_timesteps
from .neighbors import NeighborList, build_neighbor_list, default_skin
from .objective import MAX_STEP_FACTOR, Objective
from .packing import Packing
from .relaxation import RTOL, Relaxation

try:
    import jax
    import jax.numpy as jnp
except ModuleNotFoundError as exc:  # pragma: no cover - the extra is installed in CI
    raise InputError(JAX_MISSING) from exc

jax.config.update("jax_enable_x64", True)

HISTORY = 4096
"""Iterates the device loop records before it hands its history to Python."""


@dataclass(frozen=True)
class Pairs:
    """A Verlet list on the device, padded to ``capacity`` pairs: ends ``first``, ``second``
    ``(capacity,)``, image shifts ``shift`` ``(capacity, d)``, radius sums ``reach``
    ``(capacity,)`` (0 for padding) and stiffnesses ``stiffness`` ``(capacity,)``; ``count``
    real pairs, built at ``reference`` ``(N, d)`` and valid while no particle has moved more
    than ``sqrt(reach_sq)`` from it."""

    first: Any
    second: Any
    shift: Any
    radius_sum: Any
    stiffness: Any
    count: int
    capacity: int
    reference: NDArray[np.float64]
    reach_sq: float


def capacity_for(count: int, current: int = 0) -> int:
    """The padded length for ``count`` pairs: ``current`` if it holds them, else the power of
    two at or above ``1.25 count`` (room to grow without recompiling)."""
    if count <= current:
        return current
    return 1 << max(4, int(np.ceil(np.log2(max(1.25 * count, 1.0)))))


def device_pairs(
    positions: NDArray[np.float64],
    packing: Packing,
    model: ContactModel,
    typeid: NDArray[np.int64],
    skin: float,
    capacity: int = 0,
) -> Pairs:
    """The Verlet list of ``positions`` ``(N, d)`` (radii and cell of ``packing``) on the
    device, padded to :func:`capacity_for` ``(count, capacity)``."""
    nlist: NeighborList = build_neighbor_list(positions, packing.radii, packing.cell, skin)
    count = int(nlist.first.size)
    size = capacity_for(count, capacity)
    pad = size - count
    first = np.concatenate([nlist.first.astype(np.int64), np.zeros(pad, np.int64)])
    second = np.concatenate([nlist.second.astype(np.int64), np.zeros(pad, np.int64)])
    shift = np.concatenate([nlist.shifts(packing.cell)[nlist.code], np.zeros((pad, packing.dim))])
    radius_sum = np.concatenate(
        [packing.radii[nlist.first] + packing.radii[nlist.second], np.zeros(pad)]
    )
    kmat = np.asarray(model.kmat, dtype=np.float64)
    stiffness = np.concatenate([kmat[typeid[nlist.first], typeid[nlist.second]], np.zeros(pad)])
    return Pairs(
        jnp.asarray(first),
        jnp.asarray(second),
        jnp.asarray(shift),
        jnp.asarray(radius_sum),
        jnp.asarray(stiffness),
        count,
        size,
        np.array(nlist.reference, copy=True),
        nlist.reach_sq,
    )


def energy_gradient(
    x: Any, first: Any, second: Any, shift: Any, radius_sum: Any, stiffness: Any, alpha: float
) -> tuple[Any, Any]:
    """The contact energy ``sum_c k delta^alpha / alpha`` and its gradient ``(N, d)`` at
    positions ``x`` ``(N, d)`` over the padded pairs (:class:`Pairs`); ``alpha`` static."""
    sep = x[first] - x[second] + shift
    length_sq = jnp.sum(sep * sep, axis=1)
    safe = jnp.where(length_sq > 0.0, length_sq, 1.0)
    length = jnp.sqrt(safe)
    delta = jnp.where(length_sq > 0.0, radius_sum - length, 0.0)
    overlap = jnp.maximum(delta, 0.0)
    energy = jnp.sum(stiffness * overlap**alpha) / alpha
    force = stiffness * overlap ** (alpha - 1.0)  # on first, along +sep
    pull = (force / length)[:, None] * sep
    grad = jnp.zeros_like(x).at[first].add(-pull).at[second].add(pull)
    return energy, grad


def _block_max(v: Any) -> Any:
    """The largest Euclidean norm of a row of ``v`` ``(N, d)``."""
    return jnp.sqrt(jnp.max(jnp.sum(v * v, axis=1)))


def _fire_loop(
    state: tuple[Any, ...], pairs: tuple[Any, ...], settings: tuple[Any, ...], alpha_c: float
) -> Any:
    """FIRE steps on the device from ``state`` until convergence, the iteration limit, a full
    history or a particle beyond the list's reach (see the module docstring); the contact
    exponent ``alpha_c`` is static (why: ``docs/decisions.md``, section "The JAX engine")."""
    first, second, shift, radius_sum, stiffness, reference, reach_sq = pairs
    gtol, etol, maxiter, dt_max, dt_min, max_step = settings

    def evaluate(x: Any) -> tuple[Any, Any]:
        return energy_gradient(x, first, second, shift, radius_sum, stiffness, alpha_c)

    def cond(s: tuple[Any, ...]) -> Any:
        x, _, _, _, _, step, energy, _, _, recorded, gmax = s
        moved = jnp.max(jnp.sum((x - reference) ** 2, axis=1))
        return (
            (step < maxiter)
            & (recorded < HISTORY)
            & (gmax > gtol)
            & (energy > etol)
            & (moved <= reach_sq)
        )

    def body(s: tuple[Any, ...]) -> tuple[Any, ...]:
        x, v, dt, mix, n_pos, step, energy, grad, history, recorded, _ = s
        step = step + 1
        downhill = jnp.sum(grad * v) < 0.0
        n_pos = jnp.where(downhill, n_pos + 1, 0)
        grow = downhill & (n_pos > N_DELAY)
        reset = (~downhill) & (step >= N_DELAY)
        dt = jnp.where(grow, jnp.minimum(dt * F_INC, dt_max), dt)
        dt = jnp.where(reset & (dt * F_DEC >= dt_min), dt * F_DEC, dt)
        mix = jnp.where(grow, mix * F_ALPHA, jnp.where(reset, ALPHA_START, mix))
        x = jnp.where(downhill, x, x - 0.5 * dt * v)
        v = jnp.where(downhill, v, 0.0)
        v = v - dt * grad
        vv, gg = jnp.sum(v * v), jnp.sum(grad * grad)
        keep = jnp.where(gg > 0.0, 1.0 - mix, 1.0)
        toward = jnp.where(
            gg > 0.0, -mix * jnp.sqrt(vv) / jnp.sqrt(jnp.where(gg > 0, gg, 1.0)), 0.0
        )
        v = keep * v + toward * grad
        length = dt * _block_max(v)
        v = v * jnp.where(length > max_step, max_step / length, 1.0)
        x = x + dt * v
        energy, grad = evaluate(x)
        gmax = _block_max(grad)
        history = history.at[:, recorded].set(jnp.stack([energy, gmax]))
        return x, v, dt, mix, n_pos, step, energy, grad, history, recorded + 1, gmax

    return jax.lax.while_loop(cond, body, state)


_fire_compiled = jax.jit(_fire_loop, static_argnums=3)


def relax_fire(
    packing: Packing,
    model: ContactModel,
    *,
    gtol: float | None = None,
    rtol: float | None = None,
    maxiter: int = 1_000_000,
    etol: float = 0.0,
) -> Relaxation:
    """Relax ``packing`` (radii and cell fixed) by FIRE 2.0 on the JAX engine to
    ``max_i |grad_i| <= gtol``, or ``rtol`` x the mean contact force at the start (default
    :data:`~athermal.relaxation.RTOL` when neither is given), or energy ``<= etol``, within
    ``maxiter`` steps; the time steps and the step cap are :func:`~athermal.minimize.fire.fire`'s
    defaults for the packing (``dt_max = 1.6 / sqrt(curvature bound)``, a tenth of the mean
    radius per step). Returns a :class:`~athermal.relaxation.Relaxation` (its ``x`` and
    ``packing`` in the caller's particle order; no Verlet-list reordering here)."""
    if int(maxiter) != maxiter or maxiter < 0:
        raise InputError(f"maxiter: must be an integer >= 0, got {maxiter!r}")
    if not 0.0 <= etol < np.inf:
        raise InputError(f"etol: energy tolerance must be finite and >= 0, got {etol}")
    start = Objective(packing, model, sort=False)
    x0 = start.x0
    tol = start.tolerance(gtol, RTOL if gtol is None and rtol is None else rtol, x0)
    dt, dt_max, dt_min = default_timesteps(None, None, None, None, start.curvature_bound(x0))
    max_step = MAX_STEP_FACTOR * float(np.mean(packing.radii))
    typeid = np.asarray(model.typeid(packing), dtype=np.int64)
    skin = default_skin(packing.radii)
    t0 = time.perf_counter()
    positions = np.array(packing.positions, dtype=np.float64, copy=True)
    pairs = device_pairs(positions, packing, model, typeid, skin)
    x = jnp.asarray(positions)
    arrays = (pairs.first, pairs.second, pairs.shift, pairs.radius_sum, pairs.stiffness)
    energy, grad = energy_gradient(x, *arrays, float(model.alpha))
    gmax = _block_max(grad)
    energies, gradients = [float(energy)], [float(gmax)]
    state = (
        x,
        jnp.zeros_like(x),
        jnp.float64(dt),
        jnp.float64(ALPHA_START),
        jnp.int64(0),
        jnp.int64(0),
        energy,
        grad,
        jnp.zeros((2, HISTORY)),
        jnp.int64(0),
        gmax,
    )
    rebuilds = 1
    settings = (tol, etol, int(maxiter), dt_max, dt_min, max_step)
    while gradients[-1] > tol and energies[-1] > etol and int(state[5]) < maxiter:
        device = (*arrays, jnp.asarray(pairs.reference), pairs.reach_sq)
        state = _fire_compiled(state, device, settings, float(model.alpha))
        recorded = int(state[9])
        history = np.asarray(state[8][:, :recorded])
        energies.extend(history[0].tolist())
        gradients.extend(history[1].tolist())
        state = (*state[:9], jnp.int64(0), state[10])  # the history read: recorded again
        moved = np.asarray(state[0])
        if float(np.max(np.sum((moved - pairs.reference) ** 2, axis=1))) > pairs.reach_sq:
            pairs = device_pairs(moved, packing, model, typeid, skin, pairs.capacity)
            arrays = (pairs.first, pairs.second, pairs.shift, pairs.radius_sum, pairs.stiffness)
            energy, grad = energy_gradient(state[0], *arrays, float(model.alpha))
            gmax = _block_max(grad)
            state = (*state[:6], energy, grad, state[8], state[9], gmax)
            # the step that left the list's reach was evaluated over the old list: its record
            # is the new list's
            energies[-1], gradients[-1] = float(energy), float(gmax)
            rebuilds += 1
    x_final = np.asarray(state[0]).ravel()
    grad_final = np.asarray(state[7]).ravel()
    steps = int(state[5])
    converged = gradients[-1] <= tol or energies[-1] <= etol
    status = Status.CONVERGED if converged else Status.ITERATION_LIMIT
    message = f"converged after {steps} steps" if converged else f"iteration limit {maxiter}"
    result = MinimizeResult(
        x=x_final,
        jac=grad_final,
        converged=converged,
        status=status,
        message=message,
        method="fire (jax)",
        precon="none",
        iterations=steps,
        evaluations=steps + rebuilds,
        seconds=time.perf_counter() - t0,
        energy=energies[-1],
        max_gradient=gradients[-1],
        gtol=tol,
        history_energy=np.array(energies),
        history_max_gradient=np.array(gradients),
        precon_builds=0,
    )
    return Relaxation.of(result, start, rebuilds)
