"""The energy+gradient and the neighbour list on many cores: the slab kernel on 1 ... T numba
threads against the one-thread kernel, in the same run
(:func:`athermal.model.loops.energy_gradient_slabs`), and the neighbour-list build on 1 ... T
threads (:func:`athermal.model.neighbors.collect_chunks` from ``PARALLEL_BUILD`` particles).

For each size a bidisperse random packing (``random_packing(N, phi, dim=d, seed=1)``, phi = 0.84
in 2D, 0.64 in 3D, alpha = 2) and its neighbour list (default skin) are built once; then, in
``--rounds`` rounds, each variant (the one-thread kernel, the slab kernel on each thread count)
runs 2 warm-up calls and ``--calls`` timed calls in a row (consecutive evaluations on one list,
as in a minimization). Reported: the median time of each variant, the speed-up over the
one-thread kernel and the parallel efficiency (speed-up / threads), with the range of the
rounds' speed-ups (a shared machine is noisy). Both kernels must agree first (energy to 1e-12
relative, gradient to 1e-12 x max |grad|), and the slab kernel must give the same bits on every
thread count. The build is timed the same way (``--calls`` builds per round) against its own
one-thread time; its list must be the same on every thread count. Run from the repository
root, not pinned (it needs the cores)::

    python -m benchmarks.threads            # 2D N = 65536, 262144, 1048576; 3D N = 262144
    python -m benchmarks.threads --quick    # 2D N = 65536

Results: ``benchmarks/results/threads.md`` and ``threads.json``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np

from athermal import ContactModel, random_packing
from athermal.model.contact import energy_gradient, energy_gradient_contacts
from athermal.model.neighbors import build_neighbor_list
from benchmarks.machine import ROOT, save


def timed(call: Callable[[], object], calls: int) -> list[float]:
    """Seconds of ``calls`` calls after 2 untimed ones."""
    call()
    call()
    out = []
    for _ in range(calls):
        t0 = time.perf_counter()
        call()
        out.append(time.perf_counter() - t0)
    return out


def one(dim: int, n: int, threads: list[int], rounds: int, calls: int) -> dict[str, Any]:
    """The rows of one size."""
    p = random_packing(n, 0.84 if dim == 2 else 0.64, dim=dim, seed=1)
    model = ContactModel(2.0)
    nl = build_neighbor_list(p.positions, p.radii, p.cell)
    x, typeid, shifts = np.ascontiguousarray(p.positions), model.typeid(p), nl.shifts(p.cell)
    serial_grad, grad = np.empty_like(x), np.empty_like(x)
    energy = energy_gradient(x, p.radii, typeid, shifts, nl, model, serial_grad)
    bits = None
    for t in threads:
        numba.set_num_threads(t)
        e, _ = energy_gradient_contacts(
            x, p.radii, typeid, shifts, nl, model, grad, slabs=(nl.slabs, True)
        )
        if (
            abs(e / energy - 1.0) > 1e-12
            or np.abs(grad - serial_grad).max() > 1e-12 * np.abs(serial_grad).max()
        ):
            raise SystemExit(f"N = {n}: the slab kernel disagrees with the one-thread kernel")
        if bits is not None and (e != bits[0] or not np.array_equal(grad, bits[1])):
            raise SystemExit(f"N = {n}: the slab kernel's bits depend on the threads")
        bits = (e, grad.copy())
    times: dict[str, list[float]] = {"serial": []}
    ratios: dict[int, list[float]] = {t: [] for t in threads}
    for _ in range(rounds):
        numba.set_num_threads(max(threads))
        serial = timed(lambda: energy_gradient(x, p.radii, typeid, shifts, nl, model, grad), calls)
        times["serial"] += serial
        for t in threads:
            numba.set_num_threads(t)
            run = timed(
                lambda: energy_gradient_contacts(
                    x, p.radii, typeid, shifts, nl, model, grad, slabs=(nl.slabs, True)
                ),
                calls,
            )
            times.setdefault(str(t), []).extend(run)
            ratios[t].append(float(np.median(serial) / np.median(run)))
    serial_ms = 1e3 * float(np.median(times["serial"]))
    build = build_times(p, threads, rounds, calls)
    rows = []
    for t in threads:
        ms = 1e3 * float(np.median(times[str(t)]))
        rows.append(
            {
                "dim": dim,
                "n": n,
                "pairs": nl.n_pairs,
                "slabs": nl.slabs.size - 1,
                "threads": t,
                "serial_ms": serial_ms,
                "slab_ms": ms,
                "speedup": serial_ms / ms,
                "efficiency": serial_ms / ms / t,
                "speedup_range": [min(ratios[t]), max(ratios[t])],
                **build[t],
            }
        )
    return {"rows": rows}


def build_times(p: Any, threads: list[int], rounds: int, calls: int) -> dict[int, dict[str, Any]]:
    """The neighbour-list build of ``p`` on each thread count: median ms, speed-up over one
    thread and its range over the rounds; refused unless every count lists the same pairs."""
    lists = []
    for t in threads:
        numba.set_num_threads(t)
        lists.append(build_neighbor_list(p.positions, p.radii, p.cell))
    for nl in lists[1:]:
        if not all(
            np.array_equal(getattr(nl, k), getattr(lists[0], k))
            for k in ("first", "second", "code", "slabs")
        ):
            raise SystemExit(f"N = {p.n}: the threaded build lists other pairs")
    times: dict[int, list[float]] = {t: [] for t in threads}
    ratios: dict[int, list[float]] = {t: [] for t in threads}
    for _ in range(rounds):
        medians = {}
        for t in threads:
            numba.set_num_threads(t)
            run = timed(lambda: build_neighbor_list(p.positions, p.radii, p.cell), calls)
            times[t] += run
            medians[t] = float(np.median(run))
        for t in threads:
            ratios[t].append(medians[threads[0]] / medians[t])
    one_ms = 1e3 * float(np.median(times[threads[0]]))
    return {
        t: {
            "build_ms": 1e3 * float(np.median(times[t])),
            "build_speedup": one_ms / (1e3 * float(np.median(times[t]))),
            "build_speedup_range": [min(ratios[t]), max(ratios[t])],
        }
        for t in threads
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=10)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args()
    cores = numba.config.NUMBA_NUM_THREADS
    threads = sorted({1, *range(2, cores + 1, 2), cores})
    sizes = [(2, 65536)] if args.quick else [(2, 65536), (2, 262144), (2, 1048576), (3, 262144)]
    rows = [r for dim, n in sizes for r in one(dim, n, threads, args.rounds, args.calls)["rows"]]
    lines = [
        "# The energy+gradient and the neighbour list on many cores (benchmarks/threads.py)",
        "",
        "The slab kernel on T numba threads against the one-thread kernel, same packing and list, "
        f"medians over {args.rounds} rounds of {args.calls} calls; the range is the rounds' "
        "speed-ups. Equal to the one-thread kernel to 1e-12 and the same bits on every T "
        "(checked first).",
        "",
        "| d | N | pairs | slabs | T | one thread (ms) | slabs (ms) | speed-up | efficiency | "
        "speed-up range |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lo, hi = r["speedup_range"]
        lines.append(
            f"| {r['dim']} | {r['n']} | {r['pairs']} | {r['slabs']} | {r['threads']} | "
            f"{r['serial_ms']:.2f} | {r['slab_ms']:.2f} | {r['speedup']:.2f} | "
            f"{100 * r['efficiency']:.0f}% | {lo:.2f} ... {hi:.2f} |"
        )
    lines += [
        "",
        "The neighbour-list build (default skin) on T threads against T = 1, medians as above; the "
        "same list on every T (checked first).",
        "",
        "| d | N | pairs | T | build (ms) | speed-up | efficiency | speed-up range |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lo, hi = r["build_speedup_range"]
        lines.append(
            f"| {r['dim']} | {r['n']} | {r['pairs']} | {r['threads']} | {r['build_ms']:.1f} | "
            f"{r['build_speedup']:.2f} | {100 * r['build_speedup'] / r['threads']:.0f}% | "
            f"{lo:.2f} ... {hi:.2f} |"
        )
    save(args.output_dir, "threads", {"rows": rows}, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
