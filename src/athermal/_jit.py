"""The numba decorators every compiled kernel uses: one place for their options, and for when
the threaded kernels may run (:func:`threads_usable`)."""

from __future__ import annotations

import os
import threading

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
