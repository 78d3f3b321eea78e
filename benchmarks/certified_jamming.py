"""Jamming points bracketed below float64's resolution: the float64 bracket of ``jam --certify``
(epsilon ``START_EPSILON``, 1e-7), then ``bisect_jamming_point`` to epsilon 1e-12 in double-double,
per packing: where the certified point lies in the float64 bracket, the trials, the contacts
shed and formed and the rattlers readmitted on the way, the certificate at the jammed bound,
the time against the jamming run (wall time on one core, warm), and where the jamming point by
linear response (the certificate's ``linear_phi_c``) lies, from the bound and from the float64
packing. Run from the repository
root::

    python -m benchmarks.certified_jamming          # 2D N 256, 1024 (seeds 1-5), 4096 (1-3);
                                                    # 3D N 256, 1024 (seeds 1-3)
    python -m benchmarks.certified_jamming --quick  # N = 256 in 2D and 3D, one seed

Harmonic contacts only (the bisection's springs continue a harmonic contact in tension).
Results: ``benchmarks/results/certified_jamming.md`` and ``certified_jamming.json``.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from athermal.certify import certify
from athermal.certify.bisection import START_EPSILON, bisect_jamming_point
from athermal.errors import ConvergenceError, InputError
from athermal.studies.experiments import JamSpec, jam_packing
from benchmarks.machine import ROOT, pin, save

EPSILON = 1e-12


def one(dim: int, n: int, seed: int) -> dict[str, Any]:
    """Jam one packing in float64, bracket its jamming point to :data:`EPSILON`; its row."""
    spec = JamSpec(n=n, dim=dim, alpha=2.0, epsilon=START_EPSILON)
    t0 = time.perf_counter()
    jammed = jam_packing(spec, seed)
    t1 = time.perf_counter()
    row: dict[str, Any] = {
        "dim": dim,
        "n": n,
        "seed": seed,
        "float64_phi_low": jammed.phi_low,
        "float64_phi_high": jammed.phi_c,
        "jam_seconds": t1 - t0,
    }
    try:
        point = bisect_jamming_point(jammed.packing, spec.model, EPSILON)
    except (InputError, ConvergenceError) as exc:
        return {**row, "refused": str(exc)}
    seconds = time.perf_counter() - t1
    cert = point.jammed.certificate
    above = certify(jammed.packing, spec.model).certificate
    return {
        **row,
        "refused": None,
        "bisect_seconds": seconds,
        "float64_linear_phi_c": above.linear_phi_c,
        "float64_linearity": above.linearity,
        "phi_low": point.phi_low,
        "phi_high": point.phi_high,
        **point.march(),
        **{k: v for k, v in vars(cert).items() if k != "precision"},
    }


def report(rows: list[dict[str, Any]]) -> str:
    """The markdown table, one row per packing, and a summary."""
    lines = [
        f"# Jamming points bracketed to {EPSILON:g} in double-double",
        "",
        "`phi_c` is the certified jammed bound; `in float64` is its place in the float64 "
        "bracket (0: its unjammed bound, 1: its jammed bound); `shed` and `formed` are contacts, "
        "`readmitted` rattlers squeezed by their cage, `unstable` networks that a parted contact "
        "left unstable, held by a gap closing along the unstable mode, `rearranged` trials "
        "relaxed in float64 because their network gave way at any step.",
        "",
        "| d | N | seed | phi_c | width | in float64 | trials | shed | formed | readmitted | "
        "unstable | rearranged | N_c - N_iso | pressure | balance / <f> | lowest eigenvalue | "
        "jam s | bisect s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        head = f"| {r['dim']} | {r['n']} | {r['seed']} |"
        if r["refused"]:
            lines.append(f"{head} refused: {r['refused']} |" + " |" * 16)
            continue
        span = r["float64_phi_high"] - r["float64_phi_low"]
        place = (r["phi_high"] - r["float64_phi_low"]) / span
        lines.append(
            f"{head} {r['phi_high']:.15f} | {r['phi_high'] - r['phi_low']:.1e} | {place:.3f} | "
            f"{r['trials']} | {r['contacts_shed']} | {r['contacts_formed']} | "
            f"{r['rattlers_readmitted']} | {r['instabilities']} | {r['rearrangements']} | "
            f"{r['excess_contacts']} | "
            f"{r['pressure']:.1e} | "
            f"{r['relative_force_balance']:.1e} | {r['lowest_eigenvalue']:.2e} | "
            f"{r['jam_seconds']:.2f} | {r['bisect_seconds']:.2f} |"
        )
    done = [r for r in rows if not r["refused"]]
    lines += [
        "",
        "## The jamming point by linear response",
        "",
        "`linear phi_c` (the certificate's `linear_phi_c`): the isotropic expansion at which the "
        "overlaps of the packing's network vanish, to first order. At the bound its place in the "
        "certified bracket (0: `phi_low`, 1: `phi_high`); from the float64 packing of `jam` "
        f"(epsilon {START_EPSILON:g}), its miss of the bracket over that packing's distance "
        "from it.",
        "",
        "| d | N | seed | bound: linear phi_c in bracket | bound: linearity | float64: linearity "
        "| float64: miss / distance |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in done:
        width = r["phi_high"] - r["phi_low"]
        place = (r["linear_phi_c"] - r["phi_low"]) / width
        distance = r["float64_phi_high"] - r["phi_high"]
        miss = r["float64_linear_phi_c"] - r["phi_high"]
        miss = 0.0 if r["phi_low"] <= r["float64_linear_phi_c"] <= r["phi_high"] else miss
        lines.append(
            f"| {r['dim']} | {r['n']} | {r['seed']} | {place:.3f} | {r['linearity']:.1e} | "
            f"{r['float64_linearity']:.1e} | {miss / distance:+.1e} |"
        )
    inside = sum(
        r["float64_phi_low"] <= r["phi_low"] <= r["phi_high"] <= r["float64_phi_high"] for r in done
    )
    ratio = max((r["bisect_seconds"] / r["jam_seconds"] for r in done), default=float("nan"))
    lines += [
        "",
        f"{len(done)} of {len(rows)} packings bracketed to {EPSILON:g}, {inside} of them inside "
        f"their float64 bracket; every jammed bound certified: "
        f"{all(r['converged'] for r in done)}; the bisection took at most {ratio:.2f} x the "
        "jamming run.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[256, 1024, 4096], help="2D sizes")
    parser.add_argument("--n3d", type=int, nargs="+", default=[256, 1024], help="3D sizes")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument(
        "--large-seeds",
        type=int,
        nargs="+",
        default=[1, 2, 3],
        help="seeds for N >= 4096, and in 3D",
    )
    parser.add_argument("--quick", action="store_true", help="N = 256 in 2D and 3D, one seed")
    parser.add_argument("--output-dir", type=str, default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    sizes = {2: [256], 3: [256]} if args.quick else {2: args.n, 3: args.n3d}
    pin()
    one(2, 64, 0)  # compiles the kernels, so that every row's time is warm
    one(3, 64, 0)
    rows = []
    for dim in (2, 3):
        for n in sizes[dim]:
            seeds = args.large_seeds if n >= 4096 or dim == 3 else args.seeds
            for seed in [1] if args.quick else seeds:
                rows.append(one(dim, n, seed))
                r = rows[-1]
                what = r["refused"] or f"phi_c {r['phi_high']:.15f}, {r['bisect_seconds']:.1f} s"
                print(f"d {dim} N {n} seed {seed}: {what}", flush=True)
    markdown = report(rows) + "\n"
    save(ROOT / args.output_dir, "certified_jamming", {"epsilon": EPSILON, "rows": rows}, markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
