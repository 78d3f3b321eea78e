"""B4 (first part): the seed's Case 1 at larger N; L-BFGS vs P-L-BFGS with direct and AMG solves.

A random bidisperse packing (phi = 0.86, above jamming, seed 7) is relaxed by L-BFGS to 1e-10 of
the mean contact force; its radii are then grown by 5e-5 (Case 1) and each method relaxes it to
1e-9 F0. Reports iterations, evaluations, seconds, ms per iteration and peak memory.

    python benchmarks/scale.py                 # N = 65536 (about 10 minutes)
    python benchmarks/scale.py --n 262144      # larger (much longer)

Results: ``benchmarks/results/scale_n<N>.md`` and ``.json`` (written atomically).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

from athermal.contact import ContactModel
from athermal.minimize import minimize
from athermal.objective import Objective
from athermal.packing import random_packing
from athermal.precon import ExpPreconditioner

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import pin, save

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=65536)
    parser.add_argument("--alpha", type=float, default=2.0)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    pin()
    model = ContactModel(args.alpha)
    t0 = time.perf_counter()
    prep = minimize(
        Objective(random_packing(args.n, 0.86, seed=7), model), "lbfgs", rtol=1e-10, maxiter=500_000
    )
    prep_s = time.perf_counter() - t0
    print(
        f"prepared: {prep.iterations} iterations, {prep_s:.0f} s, converged {prep.converged}",
        file=sys.stderr,
        flush=True,
    )
    start = prep.packing.scale_radii(1.0 + 5e-5)
    probe = ExpPreconditioner(Objective(start, model), solver="direct")
    probe.update(probe.objective.x0)
    lines = [
        f"# B4 — Case 1 at N = {args.n} (alpha = {args.alpha:g})",
        "",
        f"- start: random_packing({args.n}, 0.86, seed=7) relaxed by L-BFGS to 1e-10 F0 "
        f"({prep.iterations} iterations, {prep_s:.0f} s), radii x (1 + 5e-5); criterion 1e-9 F0",
        f"- sine-test mu at the start: {probe.mu:.4g}",
        "",
        "| method | iterations | evaluations | seconds | ms / iteration | converged "
        "| peak RSS (MB) |",
        "|---|---:|---:|---:|---:|---|---:|",
    ]
    rows: list[dict[str, object]] = []
    for label, solver, mu_scale in (
        ("L-BFGS", None, 1.0),
        ("P-L-BFGS (Exp, direct)", "direct", 1.0),
        ("P-L-BFGS (Exp, AMG)", "amg", 1.0),
        ("P-L-BFGS (Exp, direct, mu x 10)", "direct", 10.0),
    ):
        objective = Objective(start, model)
        mu = mu_scale * probe.mu if mu_scale != 1.0 else None  # None: sine test at each build
        precon = ExpPreconditioner(objective, solver=solver, mu=mu) if solver else None
        t0 = time.perf_counter()
        res = minimize(
            objective, "lbfgs", precon=precon if precon else "none", rtol=1e-9, maxiter=500_000
        )
        seconds = time.perf_counter() - t0
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
        row = (
            f"| {label} | {res.iterations} | {res.evaluations} | {seconds:.1f} | "
            f"{1e3 * seconds / max(res.iterations, 1):.2f} | "
            f"{'yes' if res.converged else 'no'} | {rss} |"
        )
        print(row, file=sys.stderr, flush=True)
        lines.append(row)
        rows.append(
            {
                "method": label,
                "iterations": res.iterations,
                "evaluations": res.evaluations,
                "seconds": seconds,
                "converged": bool(res.converged),
                "peak_rss_mb": rss,
            }
        )
    text = "\n".join(lines) + "\n"
    data = {
        "n": args.n,
        "alpha": args.alpha,
        "prepare": {"iterations": prep.iterations, "seconds": prep_s},
        "mu": probe.mu,
        "rows": rows,
    }
    save(args.output_dir, f"scale_n{args.n}", data, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
