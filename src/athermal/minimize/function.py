"""A plain function of a flat vector as the minimizers see it, with the hooks a caller may give.

:class:`Function` wraps ``fun(x) -> (f, grad)`` into a :class:`~.result.Problem`: it counts
evaluations, caches the last one and states the stop rule's norm, the step cap and the
round-off of ``f`` by the :class:`~.hooks.Hooks` (all optional: by default the norm is ``max_i
|grad_i|`` over single coordinates, steps are not capped and ``f`` is trusted to its relative
round-off). :func:`compiled_function` makes a numba-compiled function a first-class one that
compiled minimizer loops take as an argument (:class:`~.result.CompiledSearch`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numba import typeof
from numba.core.types import CompileResultWAP
from numpy.typing import NDArray

from .. import _blocks
from ..errors import InputError
from .hooks import Hooks
from .result import CompiledSearch


class Function:
    """``fun(x) -> (f, grad)`` of a flat float64 vector of ``n_dof`` entries, as a
    :class:`~.result.Problem`: evaluations counted, the last one cached (a repeated call at the
    same ``x`` is free), norms and caps by ``hooks`` (:class:`~.hooks.Hooks`); ``compiled`` its
    compiled line search, if the caller has one."""

    def __init__(
        self,
        fun: Callable[[NDArray[np.float64]], tuple[float, NDArray[np.float64]]],
        n_dof: int,
        hooks: Hooks | None = None,
        compiled: CompiledSearch | None = None,
    ) -> None:
        if not callable(fun):
            raise InputError(f"fun: must be callable, x -> (f, grad); got {type(fun).__name__}")
        self.fun = fun
        self._n_dof = int(n_dof)
        self.hooks = Hooks() if hooks is None else hooks
        if self._n_dof % self.hooks.block:
            raise InputError(f"block: {self.hooks.block} does not divide len(x0) = {n_dof}")
        self._compiled = compiled
        self.n_evaluations = 0
        self._last_x = np.full(self._n_dof, np.nan)
        self._last: tuple[float, NDArray[np.float64]] = (0.0, np.zeros(0))

    @property
    def n_dof(self) -> int:
        """Length of ``x``."""
        return self._n_dof

    def compiled_search(self) -> CompiledSearch | None:
        """The compiled line search given, or None."""
        return self._compiled

    def __call__(self, x: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        """``f`` and ``grad`` at ``x``; a float and a float64 array ``(n_dof,)``."""
        if _blocks.same_values(x, self._last_x):
            return self._last
        f, g = self.fun(x)
        grad = np.ascontiguousarray(g, dtype=np.float64).reshape(-1)
        if grad.shape != (self._n_dof,):
            raise InputError(f"fun: gradient of shape {np.shape(g)}, expected ({self._n_dof},)")
        self.n_evaluations += 1
        self._last_x[:] = x
        self._last = (float(f), grad)
        return self._last


def compiled_function(dispatcher: Any, *example: Any) -> CompileResultWAP:
    """``dispatcher`` (a numba ``njit`` function) compiled for the types of the arguments
    ``example`` and made a first-class function: compiled loops that take it as an argument
    are compiled (and cached on disk) once per signature, not once per function."""
    types = tuple(typeof(value) for value in example)
    dispatcher.compile(types)
    return CompileResultWAP(dispatcher.overloads[types])
