"""The JAX engine: its registration (capabilities, the door to :mod:`.device`, imported only
when the engine is first bound, since JAX is the extra ``athermal[jax]``) and, in the modules
beside it, the engine on the device."""

from __future__ import annotations

import importlib.util
import os
from typing import TYPE_CHECKING, Any, Literal, cast

import numpy as np

from ...errors import JAX_MISSING
from .. import Capabilities, Engine

if TYPE_CHECKING:
    from ...model.objective import Objective
    from .device import Engine as Device

DETERMINISTIC_OPS = "--xla_gpu_deterministic_ops=true"
"""The XLA flag of :meth:`JaxEngine.make_deterministic`: deterministic scatter-adds on a GPU."""


class JaxEngine(Engine):
    """The accelerator engine (:mod:`athermal.engines.jax.device`): L-BFGS, CG and FIRE as jitted
    loops on the device, the Exp preconditioner as a V-cycle there; no walls, frozen particles,
    enthalpy or Newton."""

    name = "jax"
    label = "the JAX engine"
    capabilities = Capabilities(
        methods=("lbfgs", "cg", "fire"),
        preconditioners=("none", "exp"),
        batches=True,
        deterministic=True,
        warm_up=True,
    )

    def missing(self) -> str:
        """:data:`~athermal.errors.JAX_MISSING` without JAX."""
        return JAX_MISSING if importlib.util.find_spec("jax") is None else ""

    def bind(self, objective: Objective, precon: str, *, A: float, solver: str) -> Device:
        """The device's :class:`athermal.engines.jax.device.Engine` for ``objective`` (``solver``
        does not apply: the engine has one way); refuses a contact law without a JAX form."""
        from .device import Engine as Device

        objective.model.law.jax_pair(np.zeros(1), np.ones(1))

        return Device(objective, cast(Literal["none", "exp"], precon), A=A)

    def machine_dependence(self, precon: str, solver: str, n: int, dim: int) -> str:
        """Always: XLA compiles for each device."""
        return "the JAX engine: XLA compiles for each device"

    def make_deterministic(self) -> None:
        """Set :data:`DETERMINISTIC_OPS` in ``XLA_FLAGS`` (read when JAX starts its first
        computation, so before any)."""
        flags = os.environ.get("XLA_FLAGS", "")
        if DETERMINISTIC_OPS not in flags:
            os.environ["XLA_FLAGS"] = f"{flags} {DETERMINISTIC_OPS}".strip()

    def batch_bytes(self, n: int, dim: int) -> tuple[int, int]:
        """:func:`athermal.engines.jax.device.member_bytes` and the device's free memory."""
        from .device import device_bytes, member_bytes

        return member_bytes(n, dim), device_bytes()

    def batcher(self, size: int) -> Any:
        """An :class:`athermal.engines.jax.device.Batcher`."""
        from .device import Batcher

        return Batcher(size)

    def describe(self) -> str:
        """``JAX engine on <platform> (<device kind>)``."""
        from .device import jax

        device = jax.devices()[0]
        return f"JAX engine on {device.platform} ({getattr(device, 'device_kind', device)})"
