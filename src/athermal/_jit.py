"""The numba decorators every compiled kernel uses: one place for their options, for when the
threaded kernels may run (:func:`threads_usable`), and for compiling kernels once more with other
callees (:func:`rebound`)."""

from __future__ import annotations

import os
import threading
import types
from collections.abc import Sequence
from typing import Any

import numba as nb

# No fastmath: every kernel does its IEEE operations in the order written, so the same input
# gives the same bits whatever CPU numba compiles for (no fused multiply-add where the target
# has one, no reduction reordered to the target's vector width, no approximate function).
_jit = nb.njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
# The same on the threads (``prange``), for the kernels of large packings.
_jit_parallel = nb.njit(
    cache=True, nogil=True, parallel=True, error_model="numpy", boundscheck=False
)


def threads_usable() -> bool:
    """Whether a ``prange`` kernel gains from running now: more than one numba thread and one
    allowed core, called from the main thread (numba's default threading layer takes one caller
    at a time)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (
        min(nb.get_num_threads(), cores or 1) >= 2
        and threading.current_thread() is threading.main_thread()
    )


def rebound(functions: Sequence[Any], replacements: dict[str, Any]) -> dict[str, Any]:
    """Copies of the compiled ``functions`` (numba dispatchers), by name, in which the global
    names of ``replacements`` and of the functions themselves resolve to the replacements and
    the copies: the same source compiled once more with other callees, each with its own
    options. The copies are not cached on disk (numba keys its cache by the source's place,
    which they share with the originals)."""
    copies: dict[str, tuple[Any, dict[str, Any]]] = {}
    for function in functions:
        source = function.py_func
        names = dict(source.__globals__)
        copy = types.FunctionType(
            source.__code__, names, source.__name__, source.__defaults__, source.__closure__
        )
        copy.__qualname__ = source.__qualname__
        copy.__doc__ = source.__doc__
        options = {k: v for k, v in function.targetoptions.items() if k != "nopython"}
        copies[source.__name__] = (nb.njit(**{**options, "cache": False})(copy), names)
    compiled = {name: dispatcher for name, (dispatcher, _) in copies.items()}
    for _, names in copies.values():
        names.update(replacements)
        names.update(compiled)
    return compiled
