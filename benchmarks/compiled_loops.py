"""The compiled minimizer loops against the Python ones, on the jamming protocol.

Each realization is jammed (``athermal.studies.experiments.jam_packing``, the protocol's defaults:
P-L-BFGS with the Exp preconditioner's incomplete factor) alternately with the compiled loops
(L-BFGS iterations and line searches in compiled code, :mod:`athermal.minimize.lbfgs`) and with
the Python loops (the objective's compiled search hidden, so that the minimizers evaluate
every trial point through ``Objective.__call__``), ``--repeats`` times each after a warm-up, in
one process: the medians and the median of the per-pair time ratios, and the iterations, which
must agree.

    python -m benchmarks.compiled_loops                      # N = 1024, realizations 0-2 (~3 min)
    python -m benchmarks.compiled_loops --n 4096 --realizations 0 --repeats 1

Results: ``benchmarks/results/compiled_loops_n<N>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from athermal.model.objective import Objective
from athermal.studies.experiments import JamSpec, child_seeds, jam_packing
from benchmarks.machine import ROOT, pin, save


def jam_both_ways(spec: JamSpec, seed: int, repeats: int) -> dict[str, Any]:
    """Jam ``seed`` with the compiled and the Python loops alternately; times and iterations."""
    compiled_search = Objective.compiled_search
    times: dict[str, list[float]] = {"compiled": [], "python": []}
    results: dict[str, tuple[float, int]] = {}
    try:
        for _ in range(repeats):
            for name in ("compiled", "python"):
                hidden = compiled_search if name == "compiled" else (lambda self: None)
                Objective.compiled_search = hidden  # type: ignore[method-assign]
                t0 = time.perf_counter()
                result = jam_packing(spec, seed)
                times[name].append(time.perf_counter() - t0)
                results[name] = (result.phi_c, result.iterations)
    finally:
        Objective.compiled_search = compiled_search  # type: ignore[method-assign]
    ratios = [a / b for a, b in zip(times["compiled"], times["python"], strict=True)]
    return {
        "seed": seed,
        "phi_c": {k: v[0] for k, v in results.items()},
        "iterations": {k: v[1] for k, v in results.items()},
        "seconds": {k: statistics.median(v) for k, v in times.items()},
        "ratio": statistics.median(ratios),
        "ratio_range": [min(ratios), max(ratios)],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=1024)
    parser.add_argument("--realizations", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--root-seed", type=int, default=0)
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    pin(args.core)
    spec = JamSpec(n=args.n)
    jam_packing(JamSpec(n=64), 1)  # warm-up: compilation
    seeds = child_seeds(args.root_seed, max(args.realizations) + 1)
    rows = []
    for k in args.realizations:
        row = {"realization": k} | jam_both_ways(spec, seeds[k], args.repeats)
        rows.append(row)
        print(f"realization {k}: compiled / python {row['ratio']:.3f}", file=sys.stderr)
    md = [
        f"# Compiled against Python minimizer loops: `athermal jam`, N = {args.n}, 2D, alpha = 2",
        "",
        f"Each realization of root seed {args.root_seed} jammed with the protocol's defaults, "
        f"alternately with the compiled loops and the Python ones, {args.repeats} times each in "
        "one process (medians; ratio: median of the per-pair ratios, and their range).",
        "",
        "| realization | iterations (compiled / Python) | phi_c equal | compiled s | Python s | "
        "compiled / Python |",
        "|---:|---|---|---:|---:|---:|",
    ]
    for r in rows:
        its, phi = r["iterations"], r["phi_c"]
        md.append(
            f"| {r['realization']} | {its['compiled']} / {its['python']} | "
            f"{'yes' if phi['compiled'] == phi['python'] else 'no'} | "
            f"{r['seconds']['compiled']:.2f} | {r['seconds']['python']:.2f} | "
            f"{r['ratio']:.2f} ({r['ratio_range'][0]:.2f}-{r['ratio_range'][1]:.2f}) |"
        )
    text = "\n".join(md) + "\n"
    print(text)
    data = {"n": args.n, "root_seed": args.root_seed, "repeats": args.repeats, "rows": rows}
    save(args.output_dir, f"compiled_loops_n{args.n}", data, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
