"""Certified jamming points over sizes, dimensions and contact exponents: the force balance each
certificate reaches, the Newton steps, the refusals, and the time against the jamming run.

For each (dim, alpha, N) and seed a packing is jammed
(:func:`athermal.studies.experiments.jam_packing`,
the defaults: ``ohern``, epsilon = 1e-6) and certified (:func:`athermal.certify.certify`, target
1e-20 of the mean contact force); the time of each is wall time on one core after a warm-up (the
first packing of a size is not timed for compilation: every row is warm). Run from the
repository root::

    python -m benchmarks.certificates                      # 2D N 256-4096, 3D N 256-1024
    python -m benchmarks.certificates --n3d 256 1024 4096  # 3D to 4096 too (~15 min each)
    python -m benchmarks.certificates --quick              # N = 256 only

Results: ``benchmarks/results/certify.md`` and ``certify.json``.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from athermal.certify import TARGET, certify
from athermal.errors import ConvergenceError, InputError
from athermal.studies.experiments import JamSpec, jam_packing
from benchmarks.machine import ROOT, pin, save


def one(dim: int, alpha: float, n: int, seed: int) -> dict[str, Any]:
    """Jam and certify one packing; its row."""
    spec = JamSpec(n=n, dim=dim, alpha=alpha)
    t0 = time.perf_counter()
    jammed = jam_packing(spec, seed)
    t1 = time.perf_counter()
    row: dict[str, Any] = {
        "dim": dim,
        "alpha": alpha,
        "n": n,
        "seed": seed,
        "jam_seconds": t1 - t0,
        "checks_passed": jammed.check.passed,
    }
    try:
        done = certify(jammed.packing, spec.model)
    except (InputError, ConvergenceError) as exc:
        return {**row, "refused": str(exc)}
    row["certify_seconds"] = time.perf_counter() - t1
    cert = done.certificate
    return {**row, "refused": None, **{k: v for k, v in vars(cert).items() if k != "precision"}}


def report(rows: list[dict[str, Any]]) -> str:
    """The markdown table, one row per packing, and a summary per group."""
    lines = [
        f"# Certified jamming points (target {TARGET:g} of the mean contact force)",
        "",
        "| d | alpha | N | seed | start / F | certified / F | steps | N_c - N_iso | lowest "
        "eigenvalue | smallest f / <f> | smallest gap | jam s | certify s |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        head = f"| {r['dim']} | {r['alpha']:g} | {r['n']} | {r['seed']} |"
        if r["refused"]:
            lines.append(f"{head} refused: {r['refused']} | | | | | | | {r['jam_seconds']:.2f} | |")
            continue
        lines.append(
            f"{head} {r['start_force_balance'] / r['mean_force']:.1e} | "
            f"{r['relative_force_balance']:.1e} | {r['iterations']} | {r['excess_contacts']} | "
            f"{r['lowest_eigenvalue']:.2e} | {r['smallest_force'] / r['mean_force']:.1e} | "
            f"{r['smallest_gap']:.1e} | {r['jam_seconds']:.2f} | {r['certify_seconds']:.3f} |"
        )
    done = [r for r in rows if not r["refused"]]
    worst = max((r["relative_force_balance"] for r in done), default=float("nan"))
    ratio = max((r["certify_seconds"] / r["jam_seconds"] for r in done), default=float("nan"))
    lines += [
        "",
        f"{len(done)} of {len(rows)} packings certified; the worst force balance "
        f"{worst:.1e} of the mean contact force; certification took at most {ratio:.3f} x its "
        "jamming run.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[256, 1024, 4096], help="2D sizes")
    parser.add_argument("--n3d", type=int, nargs="+", default=[256, 1024], help="3D sizes")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--quick", action="store_true", help="N = 256, one seed")
    parser.add_argument("--output-dir", type=str, default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    sizes = {2: [256], 3: [256]} if args.quick else {2: args.n, 3: args.n3d}
    seeds = [1] if args.quick else args.seeds
    pin()
    one(2, 2.0, 64, 0)  # compiles the kernels, so that every row's time is warm
    one(3, 2.0, 64, 0)
    rows = []
    for dim in (2, 3):
        for alpha in (2.0, 2.5):
            for n in sizes[dim]:
                for seed in seeds:
                    rows.append(one(dim, alpha, n, seed))
                    r = rows[-1]
                    what = r["refused"] or f"{r['relative_force_balance']:.1e}"
                    print(f"d {dim} alpha {alpha:g} N {n} seed {seed}: {what}", flush=True)
    markdown = report(rows) + "\n"
    save(ROOT / args.output_dir, "certify", {"target": TARGET, "rows": rows}, markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
