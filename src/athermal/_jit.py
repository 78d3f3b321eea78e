"""The numba decorators every compiled kernel uses: one place for their options."""

from __future__ import annotations

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
