"""The numba engine's energy+gradient on many cores: the threaded kernel
(:func:`athermal.contact.energy_gradient_threads`) against the one-thread kernel the engine
takes below :data:`athermal.objective.THREADS_MIN_N`, on :mod:`benchmarks.scale`'s start (the
Table packing tiled k x k, N = 4096 k^2, alpha = 2).

For each N: the one-thread kernel's median ms (the in-run reference), the threaded kernel's
with 1, 2, 4, ... threads up to the cores available, the speed-up against the one-thread kernel
and the parallel efficiency (speed-up / threads). Both kernels must agree (energy to 1e-12,
gradient to 1e-12 of its largest component) before anything is timed.

    python -m benchmarks.threads [--tiles 4 8 16] [--calls 20]

Results: ``benchmarks/results/threads.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path
from typing import Any

import numba
import numpy as np

from athermal.contact import ContactModel, energy_gradient_threads, evaluate
from athermal.neighbors import build_neighbor_list
from benchmarks.machine import ROOT, save
from benchmarks.scale import start_packing


def median_ms(function: Any, calls: int) -> float:
    """Median wall time of ``function()`` over ``calls`` calls after one warm-up, in ms."""
    function()
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        function()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def measure(k: int, calls: int, threads: list[int]) -> dict[str, Any]:
    """The two kernels at the tiled start of ``k``."""
    packing, model = start_packing(2.0, k), ContactModel(2.0)
    order = packing.spatial_order()
    packing = packing.permuted(order)  # the objective's internal order
    nlist = build_neighbor_list(packing.positions, packing.radii, packing.cell)
    shifts, typeid = nlist.shifts(packing.cell), model.typeid(packing)
    start, entry = nlist.incidence
    force = np.empty((nlist.n_pairs, packing.dim))
    x = np.ascontiguousarray(packing.positions)
    serial_grad, threaded_grad = np.empty_like(x), np.empty_like(x)
    pair_args = (packing.radii, nlist.first, nlist.second, nlist.code, shifts, typeid)

    def serial() -> tuple[float, int]:
        return evaluate(x, serial_grad, *pair_args, model.kmat, model.alpha)  # type: ignore[no-any-return]

    def threaded() -> tuple[float, int]:
        return energy_gradient_threads(  # type: ignore[no-any-return]
            x, *pair_args, model.kmat, model.alpha, threaded_grad, start, entry, force
        )

    e1, e2 = serial()[0], threaded()[0]
    scale = float(np.abs(serial_grad).max())
    if abs(e1 - e2) > 1e-12 * abs(e1) or np.abs(serial_grad - threaded_grad).max() > 1e-12 * scale:
        raise SystemExit(f"N = {packing.n}: the kernels disagree; nothing written")
    reference = median_ms(serial, calls)
    row: dict[str, Any] = {"n": packing.n, "pairs": nlist.n_pairs, "serial_ms": reference}
    for count in threads:
        numba.set_num_threads(count)
        ms = median_ms(threaded, calls)
        row[f"threads_{count}"] = {
            "ms": ms,
            "speedup": reference / ms,
            "efficiency": reference / ms / count,
        }
    numba.set_num_threads(max(threads))
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tiles", type=int, nargs="+", default=[4, 8, 16])
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1
    threads = [
        t for t in (1, 2, 4, 8, 16, 32, 64) if t <= min(cores, numba.config.NUMBA_NUM_THREADS)
    ]
    rows = [measure(k, args.calls, threads) for k in args.tiles]
    lines = [
        "# The energy+gradient kernel on many cores",
        "",
        "Median ms of the one-thread kernel and of the threaded one; speed-up against the "
        "one-thread kernel, efficiency = speed-up / threads.",
        "",
        "| N | pairs | one-thread ms | "
        + " | ".join(
            f"{t} thread{'s' if t > 1 else ''}: ms (speed-up, efficiency)" for t in threads
        )
        + " |",
        "|---:|---:|---:|" + "---|" * len(threads),
    ]
    for row in rows:
        cells = [
            f"{row[f'threads_{t}']['ms']:.2f} ({row[f'threads_{t}']['speedup']:.2f}x, "
            f"{100 * row[f'threads_{t}']['efficiency']:.0f} %)"
            for t in threads
        ]
        lines.append(
            f"| {row['n']} | {row['pairs']} | {row['serial_ms']:.2f} | " + " | ".join(cells) + " |"
        )
    markdown = "\n".join(lines) + "\n"
    save(args.output_dir, "threads", {"rows": rows, "threads": threads}, markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
