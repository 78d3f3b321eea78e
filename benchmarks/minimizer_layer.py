"""The Table's trajectories and speed before and after a change to the minimizers (issue 36).

Runs every Table method (:data:`athermal.studies.bench.LABELS`) on cases 1-3 at alpha = 2 and 2.5,
``--repeats`` times each (pinned, median seconds), and records per row the iterations, the
evaluations, the final energy (its exact bits, ``float.hex``) and ms per iteration. With
``--before A.json ... --after B.json ...`` it writes the table of the two sides instead (the
median ms per iteration of each side's runs): iterations and energies equal or not, and the
ratio of ms per iteration. Run from the repository root, the two sides alternating so that the
machine's drift falls on both; to time another commit, put its ``src`` first on the path
(here a worktree of the commit before, in ``../before``)::

    for i in 1 2 3; do
        PYTHONPATH=../before/src python -m benchmarks.minimizer_layer --name before_$i \
            --label "before" --output-dir /tmp/layer
        python -m benchmarks.minimizer_layer --name after_$i --output-dir /tmp/layer
    done
    python -m benchmarks.minimizer_layer --before /tmp/layer/before_?.json \
        --after /tmp/layer/after_?.json

Results: ``benchmarks/results/<name>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path
from typing import Any

from athermal.studies.bench import ALPHAS, CASES, LABELS, table1
from benchmarks.machine import ROOT, pin, save


def measure(repeats: int) -> list[dict[str, Any]]:
    """Every Table row: case, alpha, method, iterations, evaluations, energy bits, ms/it."""
    rows = []
    for row in table1(CASES, ALPHAS, LABELS, repeats=repeats):
        rows.append(
            {
                "case": row.case,
                "alpha": row.alpha,
                "method": row.method,
                "iterations": row.iterations,
                "evaluations": row.evaluations,
                "energy": row.energy.hex(),
                "grad_over_f0": row.grad_over_f0,
                "converged": row.converged,
                "ms_per_iteration": 1e3 * row.seconds / max(row.iterations, 1),
            }
        )
        print(rows[-1], flush=True)
    return rows


def row_key(row: dict[str, Any]) -> tuple[int, float, str]:
    """A row's (case, alpha, method)."""
    return row["case"], row["alpha"], row["method"]


def side(runs: list[dict[str, Any]]) -> dict[tuple[int, float, str], dict[str, Any]]:
    """One side's rows by (case, alpha, method): the first run's, with the median ms per
    iteration over the runs and whether every run ended on the same energy bits."""
    out: dict[tuple[int, float, str], dict[str, Any]] = {}
    for key in [row_key(r) for r in runs[0]["rows"]]:
        rows = [r for run in runs for r in run["rows"] if row_key(r) == key]
        out[key] = {
            **rows[0],
            "ms_per_iteration": statistics.median(r["ms_per_iteration"] for r in rows),
            "stable": len({(r["iterations"], r["energy"]) for r in rows}) == 1,
        }
    return out


def compared(before: list[dict[str, Any]], after: list[dict[str, Any]]) -> str:
    """Markdown: each row of ``after`` beside the same row of ``before`` (medians of the runs)."""
    old, new = side(before), side(after)
    lines = [
        f"Before: {before[0]['label']} ({len(before)} runs), after: {after[0]['label']} "
        f"({len(after)} runs), alternating; ms per iteration: the median over the runs.",
        "",
        "| alpha | case | method | iterations before / after | energy bits | "
        "ms/it before | ms/it after | after / before |",
        "|---|---|---|---|---|---:|---:|---:|",
    ]
    ratios: dict[str, list[float]] = {}
    for key, r in new.items():
        b = old.get(key)
        if b is None:
            continue
        same = "equal" if b["energy"] == r["energy"] and b["stable"] and r["stable"] else "differ"
        ratio = r["ms_per_iteration"] / b["ms_per_iteration"]
        ratios.setdefault(r["method"], []).append(ratio)
        lines.append(
            f"| {r['alpha']:g} | {r['case']} | {r['method']} | {b['iterations']} / "
            f"{r['iterations']} | {same} | {b['ms_per_iteration']:.4f} | "
            f"{r['ms_per_iteration']:.4f} | {ratio:.3f} |"
        )
    lines += ["", "| method | median after / before over the six cases |", "|---|---:|"]
    lines += [f"| {m} | {statistics.median(v):.3f} |" for m, v in ratios.items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--name", default="minimizer_layer")
    parser.add_argument("--label", default="after")
    parser.add_argument("--before", type=Path, nargs="+", default=None)
    parser.add_argument("--after", type=Path, nargs="+", default=None)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    if args.before and args.after:
        load = lambda paths: [json.loads(p.read_text()) for p in paths]  # noqa: E731
        before, after = load(args.before), load(args.after)
        markdown = "# The Table before and after (issue 36)\n\n" + compared(before, after)
        machine = before[0]["machine"]
        save(args.output_dir, args.name, {"before": before, "after": after}, markdown, machine)
        print(markdown)
        return 0
    pin()
    rows = measure(args.repeats)
    markdown = f"# The Table, {args.label}\n"
    save(args.output_dir, args.name, {"label": args.label, "rows": rows}, markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
