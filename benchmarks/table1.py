"""B1: the paper's Table — minimizers and preconditioners on the three benchmark cases.

The cases and methods live in :mod:`athermal.studies.bench` (also run by ``athermal bench``); this
script adds what a results file needs: the machine, the commit, one pinned core and atomic writes
(:mod:`machine`).

Run from the repository root::

    python -m benchmarks.table1            # full table, median of 3 (10-20 minutes)
    python -m benchmarks.table1 --lammps   # the same, with LAMMPS min cg rows from the same run
    python -m benchmarks.table1 --quick    # smoke test: case 3, alpha 2, three methods, 1 repeat

``--lammps`` needs LAMMPS (``python -m benchmarks.lammps_cg --install``); it adds a row
"LAMMPS min cg" per case (:func:`lammps_cg.run_case`, same criterion) and a comparison:
athermal's fastest method against LAMMPS, and P-L-BFGS against L-BFGS, in wall time.

Results: ``benchmarks/results/table1.md`` and ``table1.json``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from pathlib import Path

from athermal.studies.bench import (
    ALPHAS,
    CASES,
    LABELS,
    QUICK_LABELS,
    RTOL,
    Row,
    make_case,
    markdown,
    reference_packing,
    table1,
)
from benchmarks.machine import ROOT, pin, save

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


LAMMPS = "LAMMPS min cg"


def lammps_rows(cases: list[int], alphas: list[float], repeats: int) -> list[Row]:
    """One LAMMPS ``min cg`` row per case (:mod:`lammps_cg`)."""
    from benchmarks import lammps_cg

    if lammps_cg.load_lammps() is None:
        raise SystemExit(lammps_cg.HOW_TO_INSTALL)
    rows = []
    for alpha in alphas:
        base = reference_packing(alpha)
        for case in cases:
            out = lammps_cg.run_case(make_case(base, case), alpha, repeats)
            row = Row(
                case,
                alpha,
                f"{LAMMPS} ({out['pair_style']})",
                out["iterations"],
                out["evaluations"],
                out["seconds"],
                out["energy"],
                out["grad_over_f0"],
                out["converged"],
            )
            report(row)
            rows.append(row)
    return rows


def comparison(rows: list[Row]) -> str:
    """Per case: athermal's fastest converged method against LAMMPS, P-L-BFGS against L-BFGS."""
    lines = [
        "| alpha | case | fastest athermal method | seconds | LAMMPS seconds | LAMMPS / fastest "
        "| P-L-BFGS / L-BFGS seconds |",
        "|---:|---:|---|---:|---:|---:|---:|",
    ]
    for alpha, case in dict.fromkeys((r.alpha, r.case) for r in rows):
        mine = [r for r in rows if (r.alpha, r.case) == (alpha, case)]
        ours = [r for r in mine if r.converged and not r.method.startswith(("LAMMPS", "scipy"))]
        theirs = [r for r in mine if r.method.startswith(LAMMPS)]
        by_name = {r.method: r.seconds for r in mine}
        if not ours:
            continue
        best = min(ours, key=lambda r: r.seconds)
        ratio = "-"
        if "P-L-BFGS" in by_name and "L-BFGS" in by_name:
            ratio = f"{by_name['P-L-BFGS'] / by_name['L-BFGS']:.2f}"
        lammps = "- | -"
        if theirs:
            lammps = f"{theirs[0].seconds:.3f} | {theirs[0].seconds / best.seconds:.2f}"
        lines.append(
            f"| {alpha:g} | {case} | {best.method} | {best.seconds:.3f} | {lammps} | {ratio} |"
        )
    return "\n".join(lines) + "\n"


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
    parser.add_argument("--lammps", action="store_true", help="add LAMMPS min cg rows")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    if args.quick:
        args.cases, args.alphas, args.repeats, args.methods = [3], [2.0], 1, list(QUICK_LABELS)
    pin()
    rows = table1(args.cases, args.alphas, args.methods, args.repeats, progress=report)
    if args.lammps:
        rows += lammps_rows(args.cases, args.alphas, args.repeats)
        rows.sort(key=lambda r: (r.alpha, r.case))
    header = ["# B1 — the paper's Table (N = 4096, phi = 0.8438)", ""]
    header += [f"- {key}: {value}" for key, value in META.items()]
    text = "\n".join(header) + "\n\n" + markdown(rows) + "\n" + comparison(rows)
    save(args.output_dir, "table1", {"meta": dict(META), "rows": [asdict(r) for r in rows]}, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
