"""B1: the seed's Table — minimizers and preconditioners on the three benchmark cases.

The cases and methods live in :mod:`athermal.bench` (also run by ``athermal bench``); this script
adds what a results file needs: the machine, the commit, one pinned core and atomic writes
(:mod:`machine`).

Run from the repository root::

    python benchmarks/table1.py            # full table, median of 3 (10-20 minutes)
    python benchmarks/table1.py --quick    # smoke test: case 3, alpha 2, three methods, 1 repeat

Results: ``benchmarks/results/table1.md`` and ``table1.json``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from pathlib import Path

from athermal.bench import ALPHAS, CASES, LABELS, QUICK_LABELS, RTOL, Row, markdown, table1

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import pin, save

ROOT = Path(__file__).resolve().parent.parent
META = {
    "criterion": f"max_i |grad_i| <= {RTOL:g} F0 (F0: mean contact force at the start)",
    "timing": "median wall time of the repeats; iterations/evaluations of the first",
}


def report(row: Row) -> None:
    print(
        f"alpha {row.alpha:g} case {row.case} {row.method:18s} it {row.iterations:6d} "
        f"ev {row.evaluations:6d} {row.seconds:7.3f}s |g|/F0 {row.grad_over_f0:.2e} "
        f"{'ok' if row.converged else 'NOT CONVERGED'}",
        file=sys.stderr,
        flush=True,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", type=int, nargs="+", default=list(CASES), choices=CASES)
    parser.add_argument("--alphas", type=float, nargs="+", default=list(ALPHAS))
    parser.add_argument(
        "--methods",
        nargs="+",
        default=list(LABELS),
        help="labels of the methods to run",
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="smoke test (seconds)")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    if args.quick:
        args.cases, args.alphas, args.repeats, args.methods = [3], [2.0], 1, list(QUICK_LABELS)
    pin()
    rows = table1(args.cases, args.alphas, args.methods, args.repeats, progress=report)
    header = ["# B1 — the seed's Table (N = 4096, phi = 0.8438)", ""]
    header += [f"- {key}: {value}" for key, value in META.items()]
    text = "\n".join(header) + "\n\n" + markdown(rows)
    save(args.output_dir, "table1", {"meta": dict(META), "rows": [asdict(r) for r in rows]}, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
