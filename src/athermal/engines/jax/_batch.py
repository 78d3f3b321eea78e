"""Batched relaxations: many packings of one size relaxed by one jitted program on the device.

A :class:`Batcher` is shared by the threads that each run one realization of a protocol (the
protocol's code unchanged: each thread relaxes through its own :class:`~._engine.Engine`).
Inside :meth:`Batcher.member` an engine does not run its jitted loop itself but hands the loop's
state to the batcher (:func:`run_loop`) and waits; once every member thread waits, the last one
to arrive runs the loops of all of them as one ``vmap`` over the batch (members of the same loop
and structure together, their lists padded to common lengths, a smaller group filled with idle
members up to the batch size, so that the program compiles once per size class), and hands each
thread its own state back. Each member keeps its own stop codes, tolerances and history: a
member that stops (converged, or for the host to rebuild its list) idles until the batch's call
ends, while the others go on.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ...errors import InputError
from ._loops import CONVERGED, HISTORY, descent_loop, fire_loop
from ._pairs import capacity_for

LOOPS: dict[str, Callable[..., Any]] = {"fire": fire_loop, "descent": descent_loop}
"""The loops by kind, each ``loop(state, *operands, *statics)``."""
_SINGLE = {
    "fire": jax.jit(fire_loop, static_argnums=4),
    "descent": jax.jit(descent_loop, static_argnums=(5, 6, 7, 8)),
}
_local = threading.local()


def run_loop(kind: str, state: Any, operands: tuple[Any, ...], statics: tuple[Any, ...]) -> Any:
    """Run the jitted loop ``kind`` (``fire`` or ``descent``) from ``state``: on this thread's
    :class:`Batcher` when it is a member of one, else at once."""
    batcher: Batcher | None = getattr(_local, "batcher", None)
    if batcher is None:
        return _SINGLE[kind](state, *operands, *statics)
    return batcher.run(kind, state, operands, statics)


@dataclass(eq=False)
class _Request:
    kind: str
    state: Any
    operands: tuple[Any, ...]
    statics: tuple[Any, ...]
    result: Any = None
    error: BaseException | None = None
    done: bool = False
    structure: tuple[Any, ...] = field(init=False)
    """What a batch's members share: the loop, its static arguments, the tree of its arrays
    and their ranks (their lengths may differ: :meth:`Batcher._padded`)."""

    def __post_init__(self) -> None:
        leaves, tree = jax.tree_util.tree_flatten((self.state, self.operands))
        self.structure = (self.kind, self.statics, tree, tuple(np.ndim(a) for a in leaves))


class Batcher:
    """The rendezvous of ``size`` member threads (see the module docstring).

    ``calls`` counts the batched calls made, ``members`` the member loops they ran.
    """

    def __init__(self, size: int) -> None:
        if int(size) != size or size < 1:
            raise InputError(f"batch: must be an integer >= 1, got {size!r}")
        self.size = int(size)
        self._condition = threading.Condition()
        self._live = 0
        self._waiting: list[_Request] = []
        self._compiled: dict[tuple[Any, ...], Callable[..., Any]] = {}
        self._capacity: dict[tuple[Any, ...], list[tuple[int, ...]]] = {}
        self.calls = 0
        self.members = 0

    @contextmanager
    def member(self) -> Iterator[None]:
        """The calling thread's relaxations run in this batch while inside."""
        _local.batcher = self
        with self._condition:
            self._live += 1
        try:
            yield
        finally:
            with self._condition:
                self._live -= 1
                self._dispatch_if_all_wait()
            _local.batcher = None

    def run(
        self, kind: str, state: Any, operands: tuple[Any, ...], statics: tuple[Any, ...]
    ) -> Any:
        """Hand a loop to the batch and wait for its end (:func:`run_loop`)."""
        request = _Request(kind, state, operands, statics)
        with self._condition:
            self._waiting.append(request)
            self._dispatch_if_all_wait()
            while not request.done:
                self._condition.wait()
        if request.error is not None:
            raise request.error
        return request.result

    def _dispatch_if_all_wait(self) -> None:
        """Run every waiting loop when each live member waits (the lock is held). An error
        reaches the threads of the loops it stopped; every waiting thread is woken whatever
        happens."""
        if not self._waiting or len(self._waiting) < self._live:
            return
        waiting, self._waiting = self._waiting, []
        groups: dict[tuple[Any, ...], list[_Request]] = {}
        for request in waiting:
            groups.setdefault(request.structure, []).append(request)
        try:
            for group in groups.values():
                for start in range(0, len(group), self.size):
                    chunk = group[start : start + self.size]
                    try:
                        states = self._batched(chunk)
                        results = [
                            jax.tree_util.tree_map(lambda a, k=k: a[k], states)
                            for k in range(len(chunk))
                        ]
                    except Exception as exc:  # each member's thread raises it
                        for request in chunk:
                            request.error = exc
                        continue
                    for request, result in zip(chunk, results, strict=True):
                        request.result = result
        finally:
            for request in waiting:
                request.done = True
            self._condition.notify_all()

    def _batched(self, chunk: list[_Request]) -> Any:
        """The loops of ``chunk`` (one structure) as one vmapped call: each array zero-padded
        to the batch's capacity for it (:meth:`_padded`), the batch filled with idle
        members."""
        first = chunk[0]
        idle = first.state._replace(code=jnp.int64(CONVERGED))
        members = [(r.state, r.operands) for r in chunk]
        members += [(idle, first.operands)] * (self.size - len(chunk))
        flat = [jax.tree_util.tree_flatten(m)[0] for m in members]
        tree = jax.tree_util.tree_structure(members[0])
        shapes = self._padded(first.structure, [[np.shape(a) for a in leaves] for leaves in flat])
        stacked = jax.tree_util.tree_unflatten(
            tree,
            [
                jnp.stack([_pad(leaves[k], shape) for leaves in flat])
                for k, shape in enumerate(shapes)
            ],
        )
        key = first.structure
        if key not in self._compiled:
            loop = LOOPS[first.kind]

            def call(state: Any, operands: tuple[Any, ...], loop: Any = loop) -> Any:
                return loop(state, *operands, *first.statics)

            self._compiled[key] = jax.jit(jax.vmap(call))
        self.calls += 1
        self.members += len(chunk)
        return self._compiled[key](*stacked)

    def _padded(
        self, key: tuple[Any, ...], shapes: list[list[tuple[int, ...]]]
    ) -> list[tuple[int, ...]]:
        """The shape each array of a call with the structure ``key`` is padded to: along each
        axis the members' largest, grown as :func:`~._pairs.capacity_for` grows a list and
        never shrunk, so that the vmapped program compiles again only when a list outgrows
        it. Arrays all members share the shape of (positions, memory) are never padded."""
        current = self._capacity.setdefault(key, [tuple(s) for s in shapes[0]])
        for k, old in enumerate(current):
            wanted = [max(s[k][axis] for s in shapes) for axis in range(len(old))]
            current[k] = tuple(
                size if size <= have else capacity_for(size, have)
                for size, have in zip(wanted, old, strict=True)
            )
        return current


def _pad(value: Any, shape: tuple[int, ...]) -> Any:
    """``value`` zero-padded at the end of each axis to ``shape`` (a padding pair joins
    particle 0 to itself with a zero radius sum, a padding matrix entry is zero: both add
    nothing)."""
    have = np.shape(value)
    if have == shape:
        return value
    return jnp.pad(jnp.asarray(value), [(0, s - h) for s, h in zip(shape, have, strict=True)])


def member_bytes(n: int, dim: int, memory: int = 10) -> int:
    """An upper estimate of the device memory one member of a batch takes (bytes): ``n``
    particles in ``dim`` dimensions relaxed by L-BFGS with ``memory`` pairs and the V-cycle,
    twice the arrays a loop holds (state, pairs within the engine's skin, hierarchy, history)
    for the temporaries of one iteration."""
    vector = 8 * n * dim
    pairs = (8 if dim == 2 else 30) * n * (80 + 16 * dim)
    hierarchy = 2 * 24 * (7 if dim == 2 else 15) * n
    state = (16 + 3 * memory) * vector + 2 * 8 * HISTORY
    return 2 * (state + pairs + hierarchy)


def device_bytes() -> int:
    """The memory of JAX's first device left to allocate (bytes): the accelerator's limit less
    what is in use, or on a CPU half the machine's physical memory."""
    stats = jax.devices()[0].memory_stats() or {}
    if "bytes_limit" in stats:
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    import os

    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")) // 2
