"""What only the caller of a minimizer knows about its function: how its coordinates group into
blocks (the stop rule's norm), how far a block may move in one iteration, and the round-off of
its value. The physics gives these for particles of ``d`` coordinates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .. import _blocks
from .._jit import _jit
from .._portable import power_of
from ..errors import InputError


@_jit
def round_off(scale: float, factor: float, power: float, value: float) -> float:
    """``scale (factor max(value, 0))^power``: the absolute round-off of ``f`` near ``value``
    (:attr:`Hooks.noise`), the one formula the line search uses from Python and compiled code."""
    return scale * power_of(factor * max(value, 0.0), power)


@dataclass(frozen=True)
class Hooks:
    """What only the caller knows about its function (physics: particles of ``d`` coordinates).

    Parameters
    ----------
    block : coordinates per block; the stop rule's norm is the largest Euclidean norm of a
        block of the gradient (1: ``max_i |grad_i|``).
    max_step : largest Euclidean move of one block in one iteration (the line search's first
        trial and its bracket are capped there; FIRE scales its step down to it).
    noise : ``(scale, factor, power)``: the absolute round-off of ``f`` near a value ``f`` is
        ``scale (factor max(f, 0))^power``; energy differences below it (or below the relative
        round-off) are not trusted by the line search. ``(0, 1, 1)``: only the relative one.
    """

    block: int = 1
    max_step: float = np.inf
    noise: tuple[float, float, float] = (0.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        if int(self.block) != self.block or self.block < 1:
            raise InputError(f"block: must be an integer >= 1, got {self.block!r}")
        if not self.max_step > 0.0:
            raise InputError(f"max_step: must be > 0, got {self.max_step!r}")
        scale, factor, power = self.noise
        if not (scale >= 0.0 and factor > 0.0 and power >= 0.0):
            raise InputError(f"noise: need scale >= 0, factor > 0, power >= 0, got {self.noise}")

    def constants(self) -> tuple[int, float, float, float, float]:
        """``(block, max_step, noise scale, factor, power)`` as compiled loops take them."""
        scale, factor, power = self.noise
        return int(self.block), float(self.max_step), float(scale), float(factor), float(power)

    def max_gradient(self, grad: NDArray[np.float64]) -> float:
        """The largest Euclidean norm of a block of ``grad``."""
        return float(_blocks.max_row_norm(grad, self.block))

    def step_limit(self, direction: NDArray[np.float64]) -> float:
        """Largest ``a`` for which ``a direction`` moves no block more than :attr:`max_step`
        (``inf`` for a zero direction)."""
        return float(_blocks.step_limit(self.max_step, direction, self.block))

    def energy_noise(self, energy: float) -> float:
        """The absolute round-off of ``f`` near ``energy`` (see :attr:`noise`)."""
        return float(round_off(*self.noise, energy))
