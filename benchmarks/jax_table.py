"""The Table on both engines in one run: the JAX engine's minimizers (on whatever device JAX
finds; JAX's CPU build without an accelerator) against the numba engine's P-L-BFGS and P-FR-CG.

For each of the six cases (N = 4096, alpha = 2 and 2.5, to 1e-9 F0): iterations, seconds (the
median of ``--repeats`` runs after a compiling one) and the relative energy of each end against
the numba engine's P-L-BFGS minimum. The in-run reference is the numba engine's P-L-BFGS time.

    python -m benchmarks.jax_table [--cases 1 2 3] [--alphas 2 2.5] [--repeats 3]

Results: ``benchmarks/results/jax_table_<platform>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

from athermal.engines.jax import device as jaxengine
from athermal.model.contact import ContactModel
from athermal.relaxation import Minimizer, relax
from athermal.studies.bench import ALPHAS, CASES, make_case, reference_packing
from benchmarks.machine import ROOT, pin, save

NUMBA = (Minimizer("plbfgs"), Minimizer("pcg"))
JAX = tuple(Minimizer(m, backend="jax") for m in ("fire", "lbfgs", "plbfgs", "pcg"))  # type: ignore[arg-type]


def timed(start: Any, model: ContactModel, how: Minimizer, repeats: int) -> dict[str, Any]:
    """Iterations, median seconds of ``repeats`` runs (after one that compiles, on an engine that
    compiles per size), convergence and energy of ``how`` on ``start``."""
    if how.engine.capabilities.warm_up:
        relax(start, model, how)
    seconds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run = relax(start, model, how)
        seconds.append(time.perf_counter() - t0)
    return {
        "method": how.name,
        "iterations": run.iterations,
        "seconds": statistics.median(seconds),
        "converged": run.converged,
        "energy": run.energy,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, nargs="+", default=list(CASES))
    parser.add_argument("--alphas", type=float, nargs="+", default=list(ALPHAS))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    pin(args.core)
    platform = jaxengine.jax.devices()[0].platform
    rows = []
    for alpha in args.alphas:
        model, base = ContactModel(alpha), reference_packing(alpha)
        for case in args.cases:
            start = make_case(base, case)
            runs = [timed(start, model, how, args.repeats) for how in (*NUMBA, *JAX)]
            rows.append({"alpha": alpha, "case": case, "runs": runs})
            print(rows[-1], flush=True)
    names = [r["method"] for r in rows[0]["runs"]]
    lines = [
        f"# The Table on both engines (JAX on {platform})",
        "",
        "Iterations, median seconds and the relative energy against the numba engine's "
        "P-L-BFGS minimum; every run to 1e-9 F0 (a run that did not converge is marked).",
        "",
        "| alpha | case | " + " | ".join(names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for row in rows:
        reference = row["runs"][0]["energy"]
        cells = [
            f"{r['iterations']} ({r['seconds']:.2f} s), {abs(r['energy'] / reference - 1):.0e}"
            + ("" if r["converged"] else " NOT CONVERGED")
            for r in row["runs"]
        ]
        lines.append(f"| {row['alpha']:g} | {row['case']} | " + " | ".join(cells) + " |")
    save(args.output_dir, f"jax_table_{platform}", {"rows": rows}, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
