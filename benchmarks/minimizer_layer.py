"""The Table's trajectories and speed before and after a change to the minimizers (issue 36).

Runs every Table method (:data:`athermal.bench.LABELS`) on cases 1-3 at alpha = 2 and 2.5,
``--repeats`` times each (pinned, median seconds), and records per row the iterations, the
evaluations, the final energy (its exact bits, ``float.hex``) and ms per iteration. With
``--compare OTHER.json`` it writes the table of the two runs side by side: iterations and
energies equal or not, and the ratio of ms per iteration. Run from the repository root; to time
another commit, put its ``src`` first on ``PYTHONPATH`` and give ``--label``::

    python -m benchmarks.minimizer_layer --name minimizer_layer_before --label "before (0b064aa)"
    python -m benchmarks.minimizer_layer --compare benchmarks/results/minimizer_layer_before.json

Results: ``benchmarks/results/<name>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from athermal.bench import ALPHAS, CASES, LABELS, table1
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


def compared(before: dict[str, Any], after: list[dict[str, Any]]) -> str:
    """Markdown: each row of ``after`` beside the same row of ``before``."""
    old = {(r["case"], r["alpha"], r["method"]): r for r in before["rows"]}
    lines = [
        f"Before: {before['label']} ({before['machine']['commit']}, "
        f"{before['machine']['cpu']}); after: this run.",
        "",
        "| alpha | case | method | iterations before / after | energy bits | "
        "ms/it before | ms/it after | after / before |",
        "|---|---|---|---|---|---:|---:|---:|",
    ]
    ratios = []
    for r in after:
        b = old.get((r["case"], r["alpha"], r["method"]))
        if b is None:
            continue
        same = "equal" if b["energy"] == r["energy"] else "differ"
        ratio = r["ms_per_iteration"] / b["ms_per_iteration"]
        ratios.append(ratio)
        lines.append(
            f"| {r['alpha']:g} | {r['case']} | {r['method']} | {b['iterations']} / "
            f"{r['iterations']} | {same} | {b['ms_per_iteration']:.4f} | "
            f"{r['ms_per_iteration']:.4f} | {ratio:.3f} |"
        )
    if ratios:
        ratios.sort()
        lines += ["", f"Median ratio of ms per iteration: {ratios[len(ratios) // 2]:.3f}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--name", default="minimizer_layer")
    parser.add_argument("--label", default="after")
    parser.add_argument("--compare", type=Path, default=None)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    pin()
    rows = measure(args.repeats)
    markdown = "# The Table before and after (issue 36)\n\n"
    if args.compare is not None:
        markdown += compared(json.loads(args.compare.read_text()), rows)
    save(args.output_dir, args.name, {"label": args.label, "rows": rows}, markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
