"""A second engine on JAX (float64), for accelerators: the contact energy, its gradient, the
stress and the contact count on the device, and FIRE 2.0, L-BFGS and nonlinear CG (with the
paper's Exp preconditioner applied on the device) each as one jitted loop (issue 37).

The engine sets ``jax_enable_x64`` when imported: JAX computes in float32 by default, whose
resolution (1e-7) is far above the force balance athermal relaxes to (1e-9 of the mean contact
force, and the jamming protocol's 1e-6 of its own forces at overlaps of 1e-9), so every array
here is float64. Without JAX installed, importing this package raises an
:class:`~athermal.errors.InputError` naming the extra (``pip install "athermal[jax]"``).

The physics facade selects it (``Minimizer(..., backend="jax")``,
:mod:`athermal.relaxation`); the protocols never see it. The Verlet list is built on the device
by a cell list with fixed capacities that report their overflow (:mod:`._cells`; in a cell too
small for three bins a direction, by the CPU engine's search on the host), padded to a capacity
that only grows, so that the jitted loops compile once per capacity; a loop stops for a new list
before any point it evaluates could leave the list's reach (:mod:`._loops`). Many packings
of one size relax as one batch on the device, each in the thread of its own realization
(:class:`Batcher`).
"""

from __future__ import annotations

from ...errors import JAX_MISSING, InputError

try:
    import jax
    import jax.numpy as jnp
except ModuleNotFoundError as exc:  # pragma: no cover - the extra is installed in CI
    raise InputError(JAX_MISSING) from exc

jax.config.update("jax_enable_x64", True)

from ._batch import Batcher, device_bytes, member_bytes  # noqa: E402
from ._engine import (  # noqa: E402
    Engine,
)
from ._pairs import (  # noqa: E402
    Pairs,
    block_max,
    capacity_for,
    device_pairs,
    energy_gradient,
    stress_contacts,
)
from ._precon import Hierarchy  # noqa: E402

__all__ = [
    "Batcher",
    "Engine",
    "Hierarchy",
    "Pairs",
    "block_max",
    "capacity_for",
    "device_bytes",
    "device_pairs",
    "energy_gradient",
    "jax",
    "jnp",
    "member_bytes",
    "stress_contacts",
]
