"""The scaling exponents of a compression against N: over which window a packing of N particles
resolves ``z - z_iso``, and what exponent the fit rules give there (``docs/jamming.md``).

For each N and start seed a packing is jammed (``ohern``, epsilon = 1e-6, alpha = 2) and
compressed from its own phi_c (1e-7 ... 1e-1, ``--per-decade`` steps per decade); ``p``, ``G``
and ``z - z_iso`` are fitted per packing and pooled over the packings of one N, each over the
steps :func:`athermal.protocols.compress.fit_points` takes. Run from the repository root::

    python -m benchmarks.z_exponent --n 256 1024 4096 --seeds 1 2 3 4 --per-decade 2

Results: ``benchmarks/results/z_exponent.md`` and ``.json`` (every compression's rows).
"""

from __future__ import annotations

import argparse
from typing import Any

from athermal.analysis.fitting import fit_power_law
from athermal.errors import InputError
from athermal.protocols.compress import FIT_LAWS, fit_points, pooled_fit
from athermal.studies.experiments import CompressSpec, JamSpec, compress, jam_packing
from benchmarks.machine import ROOT, pin, save

SYMBOLS = dict(zip(FIT_LAWS, ("p", "G", "z"), strict=True))


def one(n: int, seed: int, per_decade: int) -> dict[str, Any]:
    """Jam and compress start ``seed`` of ``n`` particles; its rows and single-packing fits."""
    jammed = jam_packing(JamSpec(n=n), seed)
    run = compress(
        jammed.packing, JamSpec().model, jammed.phi_c, CompressSpec(per_decade=per_decade)
    )
    rows = [step.row() for step in run.steps]
    fits: dict[str, Any] = {}
    for column in FIT_LAWS:
        xs, ys, dropped = fit_points(rows, column)
        try:
            law = fit_power_law(xs, ys)
            fits[column] = {
                "exponent": law.exponent,
                "stderr": law.stderr,
                "points": law.points,
                "window": [law.x_min, law.x_max],
                "left_out": dropped,
            }
        except InputError:
            fits[column] = {"exponent": None, "left_out": dropped}
    return {
        "n": n,
        "seed": seed,
        "phi_c": jammed.phi_c,
        "checks_passed": jammed.check.passed,
        "left_basin": run.fits.left_basin,
        "fits": fits,
        "rows": rows,
    }


def report(runs: list[dict[str, Any]], per_decade: int) -> str:
    """The markdown table: per N the pooled fits and the single packings' exponents."""
    lines = [
        f"# Scaling exponents against N (alpha = 2, {per_decade} compression steps per decade)",
        "",
        "| N | law | pooled: exponent ± stderr (points, window) | single packings | "
        "packings that unjammed (at Delta phi) |",
        "|---|---|---|---|---|",
    ]
    for n in sorted({r["n"] for r in runs}):
        group = [r for r in runs if r["n"] == n]
        left = (
            ", ".join(f"seed {r['seed']} ({r['left_basin']:.0e})" for r in group if r["left_basin"])
            or "none"
        )
        for column in FIT_LAWS:
            try:
                law = pooled_fit([r["rows"] for r in group], column)
                pooled = (
                    f"{law.exponent:.3f} ± {law.stderr:.3f} ({law.points}, "
                    f"{law.x_min:.0e} ... {law.x_max:.0e})"
                )
            except InputError:
                pooled = "no fit"
            single = ", ".join(
                "-"
                if r["fits"][column]["exponent"] is None
                else f"{r['fits'][column]['exponent']:.3f}"
                for r in group
            )
            lines.append(f"| {n} | {SYMBOLS[column]} | {pooled} | {single} | {left} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[256, 1024, 4096])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--per-decade", type=int, default=2)
    parser.add_argument("--output-dir", type=str, default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    pin()
    runs = []
    for n in args.n:
        for seed in args.seeds:
            runs.append(one(n, seed, args.per_decade))
            z = runs[-1]["fits"]["z_excess"]["exponent"]
            print(f"N {n} seed {seed}: z {z if z is None else round(z, 3)}", flush=True)
    markdown = report(runs, args.per_decade) + "\n"
    save(
        ROOT / args.output_dir,
        "z_exponent",
        {"per_decade": args.per_decade, "runs": runs},
        markdown,
    )
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
