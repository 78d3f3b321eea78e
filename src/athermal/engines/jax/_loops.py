"""The JAX engine's minimizers, each a whole jitted loop: FIRE 2.0 (:func:`fire_loop`) and
L-BFGS or nonlinear CG with the strong-Wolfe line search (:func:`descent_loop`), optionally
preconditioned by the device Exp preconditioner (:mod:`._precon`).

A loop runs on the device until it stops with a code: converged, the iteration limit, a full
history, no Wolfe step even along the (preconditioned) gradient, a value that is not finite, or
an iterate that needs the host (:data:`REBUILD`: it has moved so far from the Verlet list's build
that its next trial points could leave the list's reach; :data:`PRECON`: the preconditioner is
due a rebuild). Every point a loop evaluates lies within the list's reach (the caller's skin
leaves room for one more step: :data:`MARGIN` step caps), so the energy is exact, never over a
stale list. The equations are :mod:`athermal.minimize`'s (FIRE of ``fire``, L-BFGS of ``lbfgs``
with ``H0 = gamma P^-1``, one solve per iteration and its curvature guards, CG of ``cg`` with
Powell's restart), but for one difference: CG restarts along the new preconditioned gradient
when the preconditioner is rebuilt (the CPU engine's goes on with the new one). Trajectories
agree with the CPU engine's to round-off, which chaotic relaxations amplify. The line search's
round-off is the hooks' (:meth:`athermal.minimize.Hooks.energy_noise`), its step cap
:meth:`~athermal.minimize.Hooks.step_limit`'s, written here again in JAX.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from ...minimize._conjugate import POWELL
from ...minimize._wolfe import ACCEPTED, GO_ON
from ...minimize.fire import ALPHA_START, F_ALPHA, F_DEC, F_INC, N_DELAY
from ...model.law import ContactLaw
from ._pairs import block_max, energy_gradient
from ._precon import apply
from ._search import begin, feed

RUNNING, CONVERGED, LIMIT, FULL, NO_STEP, NOT_FINITE, REBUILD, PRECON = range(8)
"""Why a loop stopped (:data:`RUNNING` while it goes on); see the module docstring."""
HISTORY = 4096
"""Iterates a loop records before it hands its history to the host."""
MARGIN = 1.5
"""Step caps one iteration may move a particle (a FIRE step and half its previous one back):
an iterate farther than ``skin / 2 - MARGIN cap`` from the list's build stops the loop."""


def _stop(
    iterations: Any,
    recorded: Any,
    energy: Any,
    gmax: Any,
    x: Any,
    geometry: tuple[Any, ...],
    settings: tuple[Any, ...],
) -> Any:
    """The code after an iterate (:data:`RUNNING` when none applies); ``geometry`` is the
    list's build and reach, then the preconditioner's (None, None without one: no pass over
    the positions for it)."""
    reference, reach_sq, precon_reference, precon_reach_sq = geometry
    gtol, etol, maxiter = settings[:3]
    moved = jnp.max(jnp.sum((x - reference) ** 2, axis=1))
    due = False
    if precon_reference is not None:
        due = jnp.max(jnp.sum((x - precon_reference) ** 2, axis=1)) > precon_reach_sq
    return jnp.select(
        [
            ~(jnp.isfinite(energy) & jnp.isfinite(gmax)),
            (gmax <= gtol) | (energy <= etol),
            iterations >= maxiter,
            recorded >= HISTORY,
            moved > reach_sq,
            due,
        ],
        [NOT_FINITE, CONVERGED, LIMIT, FULL, REBUILD, PRECON],
        RUNNING,
    )


class Fire(NamedTuple):
    """FIRE's loop state: iterate ``x``, velocity ``v``, time step ``dt``, mixing ``mix``,
    steps downhill in a row ``n_pos``, steps, energy and gradient, history ``(2, HISTORY)``,
    entries recorded and the stop code."""

    x: Any
    v: Any
    dt: Any
    mix: Any
    n_pos: Any
    iterations: Any
    energy: Any
    grad: Any
    history: Any
    recorded: Any
    code: Any


def fire_loop(
    state: Fire,
    pairs: tuple[Any, ...],
    geometry: tuple[Any, ...],
    settings: tuple[Any, ...],
    law: ContactLaw,
) -> Fire:
    """FIRE 2.0 steps (:func:`athermal.minimize.fire.fire`: Guénolé et al. 2020) from
    ``state`` until a stop code; ``pairs`` the padded Verlet list, ``geometry`` the list's and
    the preconditioner's builds with their reaches, ``settings`` ``(gtol, etol, maxiter, dt_max,
    dt_min, max_step, ...)``; the contact ``law`` is static."""
    dt_max, dt_min, max_step = settings[3:6]

    def body(s: Fire) -> Fire:
        step = s.iterations + 1
        downhill = jnp.sum(s.grad * s.v) < 0.0
        n_pos = jnp.where(downhill, s.n_pos + 1, 0)
        grow = downhill & (n_pos > N_DELAY)
        reset = (~downhill) & (step >= N_DELAY)
        dt = jnp.where(grow, jnp.minimum(s.dt * F_INC, dt_max), s.dt)
        dt = jnp.where(reset & (dt * F_DEC >= dt_min), dt * F_DEC, dt)
        mix = jnp.where(grow, s.mix * F_ALPHA, jnp.where(reset, ALPHA_START, s.mix))
        x = jnp.where(downhill, s.x, s.x - 0.5 * dt * s.v)
        v = jnp.where(downhill, s.v, 0.0) - dt * s.grad
        vv, gg = jnp.sum(v * v), jnp.sum(s.grad * s.grad)
        keep = jnp.where(gg > 0.0, 1.0 - mix, 1.0)
        toward = jnp.where(
            gg > 0.0, -mix * jnp.sqrt(vv) / jnp.sqrt(jnp.where(gg > 0, gg, 1.0)), 0.0
        )
        v = keep * v + toward * s.grad
        length = dt * block_max(v)
        v = v * jnp.where(length > max_step, max_step / length, 1.0)
        x = x + dt * v
        energy, grad = energy_gradient(x, pairs, law)
        gmax = block_max(grad)
        history = s.history.at[:, s.recorded].set(jnp.stack([energy, gmax]))
        code = _stop(step, s.recorded + 1, energy, gmax, x, geometry, settings)
        return Fire(x, v, dt, mix, n_pos, step, energy, grad, history, s.recorded + 1, code)

    return jax.lax.while_loop(lambda s: s.code == RUNNING, body, state)


class Descent(NamedTuple):
    """L-BFGS's and CG's loop state: iterate ``x``, gradient ``grad``, ``z = P^-1 grad`` (the
    gradient itself without a preconditioner), ``energy``; CG's ``direction``, its ``slope``,
    the next first trial ``step`` and ``yg = z.grad``; L-BFGS's pairs ``s``, ``y``, ``py = P^-1
    y`` ``(m, N, d)`` with ``rho = 1 / s.y`` ``(m,)``, ``count`` stored, next slot ``head``;
    whether the direction under way is the (preconditioned) gradient (``restarted``);
    iterations, evaluations, history, entries recorded and the stop code."""

    x: Any
    grad: Any
    z: Any
    energy: Any
    direction: Any
    slope: Any
    step: Any
    yg: Any
    s: Any
    y: Any
    py: Any
    rho: Any
    count: Any
    head: Any
    restarted: Any
    iterations: Any
    evaluations: Any
    history: Any
    recorded: Any
    code: Any


def lbfgs_direction(state: Descent) -> Any:
    """``-H grad`` by the two-loop recursion with ``H0 = gamma P^-1`` (``gamma = s.y / y.P^-1 y``
    of the newest pair), ``P^-1`` of ``q`` carried as ``z - sum a_i P^-1 y_i``: no solve here."""
    m = state.s.shape[0]

    def newest_first(k: int, carry: tuple[Any, ...]) -> tuple[Any, ...]:
        q, pq, a = carry
        slot = (state.head - 1 - k) % m
        used = k < state.count
        a_k = jnp.where(used, state.rho[slot] * jnp.vdot(state.s[slot], q), 0.0)
        return q - a_k * state.y[slot], pq - a_k * state.py[slot], a.at[slot].set(a_k)

    _, pq, a = jax.lax.fori_loop(0, m, newest_first, (state.grad, state.z, jnp.zeros(m)))
    newest = (state.head - 1) % m
    gamma = jnp.where(
        state.count > 0,
        1.0 / (state.rho[newest] * jnp.vdot(state.y[newest], state.py[newest])),
        1.0,
    )

    def oldest_first(k: int, r: Any) -> Any:
        slot = (state.head - state.count + k) % m
        used = k < state.count
        b = state.rho[slot] * jnp.vdot(state.y[slot], r)
        return jnp.where(used, r + (a[slot] - b) * state.s[slot], r)

    return -jax.lax.fori_loop(0, m, oldest_first, gamma * pq)


def descent_loop(
    state: Descent,
    pairs: tuple[Any, ...],
    geometry: tuple[Any, ...],
    hierarchy: tuple[Any, ...],
    settings: tuple[Any, ...],
    law: ContactLaw,
    lbfgs: bool,
    polak: bool,
    preconditioned: bool,
) -> Descent:
    """L-BFGS (``lbfgs``) or CG (Fletcher-Reeves, or with ``polak`` Polak-Ribiere+)
    iterations from ``state`` until a stop code. ``pairs``, ``geometry`` as
    :func:`fire_loop`'s; ``hierarchy`` the preconditioner's :attr:`~._precon.Hierarchy.arrays`
    (used when ``preconditioned``); ``settings`` ``(gtol,
    etol, maxiter, dt_max, dt_min, max_step, c2, noise scale, factor, power)``; ``law``,
    ``lbfgs``, ``polak``, ``preconditioned`` static."""
    max_step, c2, scale, factor, power = settings[5:10]

    def solve(g: Any) -> Any:
        return apply(g, *hierarchy) if preconditioned else g

    def evaluate(point: Any) -> tuple[Any, Any]:
        return energy_gradient(point, pairs, law)

    def refuse(st: Descent, search: Any, *_: Any) -> Descent:
        """No Wolfe step: a restart along the (preconditioned) gradient, or the end when the
        direction was that already."""
        return st._replace(
            slope=jnp.float64(1.0),  # CG: not a descent direction, restart from a unit step
            step=jnp.float64(1.0),
            count=jnp.int64(0),  # L-BFGS: no pairs, the direction is -z
            restarted=jnp.bool_(True),
            evaluations=st.evaluations + search.evaluations,
            code=jnp.where(st.restarted, NO_STEP, RUNNING),
        )

    def take(st: Descent, search: Any, direction: Any, slope: Any, grad: Any) -> Descent:
        """The accepted step: the new iterate, its pair (L-BFGS) or next direction (CG)."""
        a, energy = search.end[0], search.end[1]
        x = st.x + a * direction
        z = solve(grad)
        if lbfgs:
            s_new, y_new = x - st.x, grad - st.grad
            sy = jnp.vdot(s_new, y_new)
            # a strong-Wolfe step has s.y > 0, an SPD P^-1 y.P^-1 y > 0: the CPU engine's guards
            keep = (sy > 0.0) & (jnp.vdot(y_new, z - st.z) > 0.0)
            head, m = st.head, st.s.shape[0]
            st = st._replace(
                s=st.s.at[head].set(jnp.where(keep, s_new, st.s[head])),
                y=st.y.at[head].set(jnp.where(keep, y_new, st.y[head])),
                py=st.py.at[head].set(jnp.where(keep, z - st.z, st.py[head])),
                rho=st.rho.at[head].set(jnp.where(keep, 1.0 / sy, st.rho[head])),
                count=jnp.where(keep, jnp.minimum(st.count + 1, m), st.count),
                head=jnp.where(keep, (head + 1) % m, head),
            )
        else:
            yg = jnp.vdot(z, grad)
            overlap, change = jnp.vdot(z, st.grad), jnp.vdot(z, grad - st.grad)
            beta = jnp.where(
                jnp.abs(overlap) >= POWELL * yg,
                0.0,
                jnp.maximum(0.0, change / st.yg) if polak else yg / st.yg,
            )
            following = beta * direction - z
            new_slope = jnp.vdot(grad, following)
            guess = a * slope / new_slope
            guess = jnp.where((beta != 0.0) & jnp.isfinite(guess) & (guess > 0.0), guess, 1.0)
            st = st._replace(direction=following, slope=new_slope, step=guess, yg=yg)
        gmax = block_max(grad)
        iterations = st.iterations + 1
        return st._replace(
            x=x,
            grad=grad,
            z=z,
            energy=energy,
            restarted=jnp.bool_(False),
            iterations=iterations,
            evaluations=st.evaluations + search.evaluations,
            history=st.history.at[:, st.recorded].set(jnp.stack([energy, gmax])),
            recorded=st.recorded + 1,
            code=_stop(iterations, st.recorded + 1, energy, gmax, x, geometry, settings),
        )

    def body(st: Descent) -> Descent:
        if lbfgs:
            direction = lbfgs_direction(st)
            slope, step = jnp.vdot(st.grad, direction), jnp.float64(1.0)
        else:
            direction, slope, step = st.direction, st.slope, st.step
        ascent = ~(slope < 0.0)
        direction = jnp.where(ascent, -st.z, direction)
        slope = jnp.where(ascent, -jnp.vdot(st.grad, st.z), slope)
        count = jnp.where(ascent, 0, st.count)
        restarted = ascent | st.restarted | ((count == 0) if lbfgs else False)
        st = st._replace(count=count, restarted=restarted)
        cap = max_step / block_max(direction)
        noise = scale * (factor * jnp.maximum(st.energy, 0.0)) ** power
        search = begin(st.energy, slope, step, c2, cap, noise)

        def trial(carry: tuple[Any, ...]) -> tuple[Any, ...]:
            search, _, _ = carry
            energy, grad = evaluate(st.x + search.trial * direction)
            return feed(search, energy, jnp.vdot(grad, direction)), energy, grad

        search, _, grad = jax.lax.while_loop(
            lambda c: c[0].code == GO_ON, trial, (search, st.energy, st.grad)
        )
        return jax.lax.cond(
            search.code == ACCEPTED, take, refuse, st, search, direction, slope, grad
        )

    return jax.lax.while_loop(lambda s: s.code == RUNNING, body, state)
