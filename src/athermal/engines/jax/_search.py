"""The strong-Wolfe line search of :mod:`athermal.minimize.linesearch` as a pure JAX state
machine: :func:`begin` sets a search up, each :func:`feed` of ``phi(a), phi'(a)`` at the trial
``search.trial`` names the next trial or ends it. The same rules as the compiled one
(:func:`athermal.minimize._wolfe.feed`: bracketing by fourfold steps up to the step cap, zoom by
safeguarded cubic interpolation, energy comparisons trusted only above the round-off, Hager and
Zhang's approximate Wolfe condition below it), written as branch functions over scalars so that
a whole search runs inside a jitted loop."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from ...minimize._wolfe import ACCEPTED, FAILED, GO_ON
from ...minimize.linesearch import C1, EPS, MAX_EVALUATIONS


class Search(NamedTuple):
    """The state of one search (all float64 scalars but ``code``): ``phi(0) = f0``,
    ``phi'(0) = g0``, the curvature constant ``c2``, the step cap ``cap``, the absolute energy
    round-off ``noise``, the evaluations so far, whether it zooms, the next ``trial``, the
    previous point ``prev``, the bracket ``lo``, ``hi`` (each ``(a, phi, phi')``), the end
    point ``end`` and the ``code`` (``GO_ON``, ``ACCEPTED``, ``FAILED``)."""

    f0: Any
    g0: Any
    c2: Any
    cap: Any
    noise: Any
    evaluations: Any
    zoom: Any
    trial: Any
    prev: Any
    lo: Any
    hi: Any
    end: Any
    code: Any


def begin(f0: Any, g0: Any, step: Any, c2: float, cap: Any, noise: Any) -> Search:
    """A search from ``phi(0) = f0``, ``phi'(0) = g0 < 0``, first trial ``min(step, cap)``."""
    zero = jnp.zeros(3)
    start = jnp.stack([jnp.float64(0.0), f0, g0])
    return Search(
        f0=f0,
        g0=g0,
        c2=jnp.float64(c2),
        cap=cap,
        noise=noise,
        evaluations=jnp.int64(0),
        zoom=jnp.bool_(False),
        trial=jnp.minimum(step, cap),
        prev=start,
        lo=zero,
        hi=zero,
        end=zero,
        code=jnp.int64(GO_ON),
    )


def _resolved(s: Search, f: Any, f_ref: Any) -> Any:
    """Whether ``f`` and ``f_ref`` differ by more than the energy round-off."""
    return jnp.abs(f - f_ref) > jnp.maximum(EPS * jnp.abs(s.f0), s.noise)


def _decrease(s: Search, a: Any, f: Any, df: Any) -> Any:
    return jnp.where(
        _resolved(s, f, s.f0),
        f <= s.f0 + C1 * a * s.g0,
        df <= (1.0 - 2.0 * C1) * jnp.abs(s.g0),
    )


def _curvature(s: Search, df: Any) -> Any:
    return jnp.abs(df) <= s.c2 * jnp.abs(s.g0)


def _interpolate(s: Search, lo: Any, hi: Any) -> Any:
    """Cubic minimizer of the bracket's ends (secant of ``phi'`` below round-off), kept inside
    the middle 80 % of the bracket; its middle when neither exists."""
    a_lo, f_lo, df_lo = lo[0], lo[1], lo[2]
    a_hi, f_hi, df_hi = hi[0], hi[1], hi[2]
    width = a_hi - a_lo
    d1 = df_lo + df_hi - 3.0 * (f_lo - f_hi) / jnp.where(a_lo != a_hi, a_lo - a_hi, 1.0)
    disc = d1 * d1 - df_lo * df_hi
    d2 = jnp.sign(a_hi - a_lo) * jnp.sqrt(jnp.maximum(disc, 0.0))
    denom = df_hi - df_lo + 2.0 * d2
    cubic = a_hi - width * (df_hi + d2 - d1) / jnp.where(denom != 0.0, denom, 1.0)
    cubic_ok = _resolved(s, f_hi, f_lo) & (disc >= 0.0) & (denom != 0.0) & jnp.isfinite(cubic)
    slope_change = df_hi - df_lo
    secant = a_lo - df_lo * width / jnp.where(slope_change != 0.0, slope_change, 1.0)
    secant_ok = (slope_change != 0.0) & jnp.isfinite(secant)
    trial = jnp.where(cubic_ok, cubic, secant)
    low = jnp.minimum(a_lo + 0.1 * width, a_hi - 0.1 * width)
    high = jnp.maximum(a_lo + 0.1 * width, a_hi - 0.1 * width)
    return jnp.where(cubic_ok | secant_ok, jnp.clip(trial, low, high), a_lo + 0.5 * width)


def _zoom_next(s: Search) -> Search:
    """The next trial inside ``[lo, hi]``, or the end of the budget at ``lo``."""
    out = s.evaluations >= MAX_EVALUATIONS
    return s._replace(
        zoom=jnp.bool_(True),
        trial=jnp.where(out, s.trial, _interpolate(s, s.lo, s.hi)),
        end=jnp.where(out, s.lo, s.end),
        code=jnp.where(out, FAILED, GO_ON),
    )


def feed(s: Search, f: Any, df: Any) -> Search:
    """Take ``phi, phi'`` at ``s.trial``; the returned search names the next trial or has
    ended (:func:`athermal.minimize._wolfe.feed` has the rules)."""
    s = s._replace(evaluations=s.evaluations + 1)
    a = s.trial
    point = jnp.stack([a, f, df])
    decrease = _decrease(s, a, f, df)
    curvature = _curvature(s, df)
    a_prev, f_prev = s.prev[0], s.prev[1]
    exhausted = s.evaluations >= MAX_EVALUATIONS
    # the cases of the bracketing phase, then of the zoom, in feed's order
    bracket_high = ~decrease | (_resolved(s, f, f_prev) & (f >= f_prev) & (a_prev > 0.0))
    zoom_high = ~decrease | (_resolved(s, f, s.lo[1]) & (f >= s.lo[1]))
    case = jnp.where(
        (f == 0.0) & (df == 0.0),
        0,
        jnp.where(
            ~s.zoom,
            jnp.select(
                [bracket_high, curvature, df >= 0.0, a >= s.cap, exhausted], [1, 0, 2, 0, 3], 4
            ),
            jnp.select([zoom_high, curvature], [5, 0], 6),
        ),
    )
    branches = [
        lambda s: s._replace(end=point, code=jnp.int64(ACCEPTED)),
        lambda s: _zoom_next(s._replace(lo=s.prev, hi=point)),
        lambda s: _zoom_next(s._replace(lo=point, hi=s.prev)),
        lambda s: s._replace(end=point, code=jnp.int64(FAILED)),
        lambda s: s._replace(prev=point, trial=jnp.minimum(4.0 * a, s.cap)),
        lambda s: _zoom_next(s._replace(hi=point)),
        lambda s: _zoom_next(
            s._replace(hi=jnp.where(df * (s.hi[0] - s.lo[0]) >= 0.0, s.lo, s.hi), lo=point)
        ),
    ]
    return jax.lax.switch(case, branches, s)
