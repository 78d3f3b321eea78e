"""Does the jamming point converge with epsilon? Nesting of the brackets over epsilon, and phi_c
over starts, for the two bisection protocols (``seed`` and ``ohern``).

For each N, start seed, protocol and epsilon the default jamming run (alpha = 2, dphi = 1e-3,
P-L-BFGS) is made once; a pair ``eps1 > eps2`` of the same start and protocol *nests* when
``phi_c(eps2)`` lies in ``[phi_low(eps1), phi_high(eps1)]`` (both bounds within round-off,
1e-12). The table gives per N and protocol: the nesting rate over all such pairs, the mean and
spread over starts of phi_c at the smallest epsilon, the largest ``|phi_c(eps1) - phi_c(eps2)|``,
how many runs reopened their bracket, passed every check, and the run times.

Run from the repository root (each worker pinned to its own core; every finished run is kept in
``runs.jsonl`` of the output directory, so an interrupted study continues where it stopped)::

    python -m benchmarks.jamming_convergence --n 256 1024 --starts 16 --workers 2

Results: ``benchmarks/results/jamming_convergence.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import multiprocessing
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from athermal.atomic import write_text
from athermal.errors import ConvergenceError
from athermal.protocols import JAM_PROTOCOLS
from athermal.studies.experiments import JamSpec, jam_packing
from benchmarks.machine import ROOT, pin, save

ROUND_OFF = 1e-12
"""Slack on the bracket bounds when nesting is checked (packing fraction)."""


def _worker(cores: Any) -> None:
    """Pin this worker to a core of its own, taken from the queue ``cores``."""
    pin(cores.get())


def one_run(job: tuple[int, int, str, float]) -> dict[str, Any]:
    """Jam start ``seed`` of ``n`` particles with ``protocol`` to ``epsilon`` and return its
    numbers."""
    n, seed, protocol, epsilon = job
    done = {"n": n, "seed": seed, "protocol": protocol, "epsilon": epsilon}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = jam_packing(JamSpec(n=n, epsilon=epsilon, protocol=protocol), seed)  # type: ignore[arg-type]
        except ConvergenceError as exc:  # counted in the table, not a crash of the study
            return {**done, "error": str(exc)}
    history = result.history
    reopened = sum(
        1
        for before, step in itertools.pairwise(history)
        if np.isinf(step.phi_high) and np.isfinite(before.phi_high)
    )
    return {
        **done,
        "phi_low": result.phi_low,
        "phi_c": result.phi_c,
        "seconds": result.seconds,
        "steps": result.steps,
        "iterations": result.iterations,
        "reopened": reopened,
        "passed": result.check.passed,
        "z": result.observables.z,
        "warnings": [str(w.message) for w in caught],
    }


def nesting(runs: list[dict[str, Any]]) -> tuple[int, int, float]:
    """Nested pairs, all pairs and the largest ``|phi_c(eps1) - phi_c(eps2)|`` over the pairs of
    ``runs`` (one N and protocol) that share a start."""
    nested = pairs = 0
    largest = 0.0
    by_seed: dict[int, list[dict[str, Any]]] = {}
    for r in runs:
        by_seed.setdefault(r["seed"], []).append(r)
    for group in by_seed.values():
        for coarse, fine in itertools.permutations(group, 2):
            if fine["epsilon"] >= coarse["epsilon"]:
                continue
            pairs += 1
            low, high = coarse["phi_low"] - ROUND_OFF, coarse["phi_c"] + ROUND_OFF
            nested += int(low <= fine["phi_c"] <= high)
            largest = max(largest, abs(fine["phi_c"] - coarse["phi_c"]))
    return nested, pairs, largest


def report(runs: list[dict[str, Any]], epsilons: list[float]) -> str:
    """The markdown table of ``runs``."""
    finest = min(epsilons)
    head = (
        "| N | protocol | nested pairs | phi_c at eps "
        f"{finest:g}: mean (sd over starts) | largest change of phi_c over eps | reopened | "
        "checks passed (runs stopped by an error) | "
        + " | ".join(f"s per run at {e:g}: mean (max)" for e in epsilons)
        + " |"
    )
    lines = [head, "|" + "---|" * (7 + len(epsilons))]
    labels = list(JAM_PROTOCOLS) + sorted({r["protocol"] for r in runs} - set(JAM_PROTOCOLS))
    for n in sorted({r["n"] for r in runs}):
        for protocol in labels:
            every = [r for r in runs if r["n"] == n and r["protocol"] == protocol]
            group = [r for r in every if "error" not in r]
            if not group:
                continue
            nested, pairs, largest = nesting(group)
            phis = np.array([r["phi_c"] for r in group if r["epsilon"] == finest])
            starts = phis.size
            times = []
            for e in epsilons:
                t = np.array([r["seconds"] for r in group if r["epsilon"] == e])
                times.append(f"{t.mean():.2f} ({t.max():.2f})" if t.size else "-")
            sd = phis.std(ddof=1) if phis.size > 1 else float("nan")
            lines.append(
                f"| {n} | {protocol} | {nested} / {pairs} | {phis.mean():.5f} ({sd:.5f}), "
                f"{starts} starts | {largest:.1e} | {sum(r['reopened'] > 0 for r in group)} of "
                f"{len(group)} | {sum(r['passed'] for r in group)} of {len(every)} "
                f"({len(every) - len(group)} stopped) | " + " | ".join(times) + " |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[256, 1024])
    parser.add_argument("--starts", type=int, default=16, help="start seeds 1 ... S")
    parser.add_argument("--epsilons", type=float, nargs="+", default=[1e-5, 1e-6, 1e-8])
    parser.add_argument("--protocols", nargs="+", choices=JAM_PROTOCOLS, default=JAM_PROTOCOLS)
    parser.add_argument("--workers", type=int, default=2, help="processes, one core each")
    parser.add_argument(
        "--output-dir", type=Path, default=ROOT / "benchmarks" / "results" / "jamming_convergence"
    )
    parser.add_argument(
        "--compare",
        type=Path,
        nargs="*",
        default=[],
        help="JSON-lines files of the same runs by other code (e.g. an older commit), each "
        "line one run with this script's keys; their 'protocol' labels their rows",
    )
    args = parser.parse_args(argv)
    args.output_dir.mkdir(parents=True, exist_ok=True)
    store = args.output_dir / "runs.jsonl"
    runs = [json.loads(t) for t in store.read_text().splitlines()] if store.exists() else []
    done = {(r["n"], r["seed"], r["protocol"], r["epsilon"]) for r in runs}
    jobs = [
        (n, seed, protocol, eps)
        for n in args.n
        for seed in range(1, args.starts + 1)
        for protocol in args.protocols
        for eps in args.epsilons
        if (n, seed, protocol, eps) not in done
    ]
    cores = sorted(os.sched_getaffinity(0))[: args.workers]
    queue: Any = multiprocessing.Queue()
    for core in cores:
        queue.put(core)
    with multiprocessing.Pool(len(cores), initializer=_worker, initargs=(queue,)) as pool:
        for run in pool.imap_unordered(one_run, jobs):
            runs.append(run)
            write_text(store, "".join(json.dumps(r) + "\n" for r in runs))
            what = run.get("error") or (
                f"[{run['phi_low']:.10f}, {run['phi_c']:.10f}] {run['seconds']:.2f} s"
            )
            print(
                f"N {run['n']} seed {run['seed']} {run['protocol']} eps {run['epsilon']:g}: {what}",
                flush=True,
            )
    wanted = [
        r
        for r in runs
        if r["n"] in args.n and r["epsilon"] in args.epsilons and r["protocol"] in args.protocols
    ]
    for other in args.compare:
        wanted += [json.loads(t) for t in other.read_text().splitlines() if t.strip()]
    table = report(wanted, sorted(args.epsilons, reverse=True))
    markdown = (
        "# Jamming point against epsilon: nesting and spread (alpha = 2, dphi = 1e-3, "
        "P-L-BFGS)\n\n" + table + "\n"
    )
    save(
        args.output_dir.parent,
        "jamming_convergence",
        {"epsilons": args.epsilons, "runs": wanted},
        markdown,
    )
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
