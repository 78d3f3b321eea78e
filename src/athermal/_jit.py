"""The numba decorators every compiled kernel uses: one place for their options, and for when
the threaded kernels may run (:func:`threads_usable`)."""

from __future__ import annotations

import os
import threading

import numba as nb

_jit = nb.njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)
# Reassociation, contraction and approximate functions only; NaN and inf keep their meaning. No
# reciprocal rewriting ("arcp"): LLVM applied it differently where a kernel was inlined into a
# compiled loop than where it ran on its own, and the energy at one point differed by an ulp
# between the two (alpha = 2.5).
_jit_fast = nb.njit(
    cache=True,
    nogil=True,
    error_model="numpy",
    boundscheck=False,
    fastmath={"nsz", "contract", "afn", "reassoc"},
)
# The fast options on the threads (``prange``), for the kernels of large packings.
_jit_parallel = nb.njit(
    cache=True,
    nogil=True,
    parallel=True,
    error_model="numpy",
    boundscheck=False,
    fastmath={"nsz", "contract", "afn", "reassoc"},
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
