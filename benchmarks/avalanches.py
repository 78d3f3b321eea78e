"""Avalanche statistics of AQS shear over realizations and sizes, and the yielding amplitude of
cyclic shear: ensembles (:func:`athermal.studies.ensemble.run_ensemble`, protocols ``events``
and ``cycles``) at each size, their pooled statistics, and the finite-size scaling.

Each ``--run DIM N M STRAIN`` is an ensemble of M packings of N particles in DIM dimensions,
jammed (the defaults), put at ``phi_c + --dphi`` and sheared (simple shear) to STRAIN with
every plastic event located to ``--tol``; the events below ``--transient`` are left out. Per
ensemble: events, the mean stress drop, energy drop and strain between events (standard errors
over events), the exponents of both drops' distributions (power law with cutoff, maximum
likelihood: :func:`athermal.analysis.avalanches.power_law_tail`), the saddle-node fraction.
Per dimension, with three sizes or more: the exponents of the means against N.

``--yielding DPHI ...`` instead: ensembles of ``--realizations`` packings of ``--n`` particles at
each ``phi_c + DPHI``, each sheared in at most ``--cycles`` cycles at each of ``--amplitudes``:
the fraction that reached a limit cycle, the cycles it took, and the yielding amplitude's
bracket.

The ensembles live in ``--ensembles`` (default ``benchmarks/results/ensembles``, not committed):
rerunning resumes them, finished realizations skipped.

    python -m benchmarks.avalanches --run 2 128 8 0.3 --run 2 256 6 0.3 --run 2 512 4 0.2 ...
    python -m benchmarks.avalanches --yielding 0.02 0.1 --n 64 --realizations 3

Results: ``benchmarks/results/avalanches.md`` / ``yielding.md`` (and ``.json``); figures
``docs/figures/avalanches.png`` / ``yielding.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from athermal.analysis.fitting import fit_power_law
from athermal.errors import InputError
from athermal.model.contact import ContactModel
from athermal.protocols.events import default_max_step, opens_at_once
from athermal.studies import plot
from athermal.studies.avalanches import EventsSpec, pooled_drops
from athermal.studies.ensemble import run_ensemble
from athermal.studies.experiments import JamSpec
from athermal.studies.realization import EnsembleSpec
from benchmarks.machine import ROOT, pin, save

MEANS = (
    ("stress_drop", "<d tau>"),
    ("energy_drop", "<d E>"),
    ("strain_between_events", "<d gamma>"),
)
"""The means fitted against N (key of the statistics, label)."""


def ensemble(spec: EnsembleSpec, directory: Path, realizations: int, workers: int) -> Any:
    """The ensemble of ``spec`` in ``directory`` (resumed where it exists)."""
    return run_ensemble(
        spec,
        directory,
        realizations,
        workers=workers,
        progress=lambda text: print(f"  {directory.name}: {text}", flush=True),
    )


def avalanches(args: argparse.Namespace) -> None:
    """The ``--run`` ensembles, their table, scaling fits and figure."""
    rows, drops = [], {}
    for dim, n, m, strain in args.run:
        dim, n, m = int(dim), int(n), int(m)
        spec = EnsembleSpec(
            "events",
            jam=JamSpec(n=n, dim=dim, alpha=args.alpha),
            events=EventsSpec(
                delta_phi=args.dphi,
                strain=strain,
                transient=args.transient,
                step=args.step,
                max_step=args.max_step,
                tol=args.tol,
            ),
        )
        t0 = time.perf_counter()
        name = f"events_d{dim}_n{n}_a{args.alpha:g}_dphi{args.dphi:g}_s{strain:g}"
        name += f"_h{args.step:g}-{args.max_step:g}"
        result = ensemble(spec, args.ensembles / name, m, args.workers)
        stats = result.summary["avalanches"]
        records = [r.events for r in result.realizations if r.events is not None]
        drops[f"{dim}D N = {n}"] = pooled_drops(records, args.transient)
        rows.append(
            {
                "dim": dim,
                "n": n,
                "realizations": m,
                "strain": strain,
                "seconds": time.perf_counter() - t0,
                "compute_seconds": sum(
                    r.events.seconds for r in result.realizations if r.events is not None
                ),
                **stats,
            }
        )
        print(f"{dim}D N {n}: {stats['events']} events", flush=True)
    scaling = {}
    for dim in sorted({r["dim"] for r in rows}):
        at = [r for r in rows if r["dim"] == dim]
        if len({r["n"] for r in at}) < 3:
            continue
        scaling[dim] = {}
        series = {key: [r[key]["mean"] for r in at] for key, _ in MEANS}
        series["stress_sd"] = [r["stress"]["sd"] for r in at]  # the stress fluctuation
        for key, values in series.items():
            try:
                fit = fit_power_law([r["n"] for r in at], values)
            except InputError:
                continue
            scaling[dim][key] = {"exponent": fit.exponent, "stderr": fit.stderr}
    lines = [
        "# Avalanches of AQS simple shear (benchmarks/avalanches.py)",
        "",
        f"`python -m benchmarks.avalanches {' '.join(sys.argv[1:])}`",
        "",
        f"alpha = {args.alpha:g}, phi_c + {args.dphi:g}; strain step {args.step:g} growing "
        f"to {args.max_step:g}; events located to {args.tol:g} in "
        f"strain; events below strain {args.transient:g} left out. Means with their standard "
        "errors (over events); tau: the exponent of P(S) ~ S^-tau exp(-S/S_c) (maximum "
        "likelihood, S_min chosen by the KS distance) with its standard error, and in brackets "
        "its range over the starts S_min at the 0 ... 0.6 quantiles of the sizes. Drops in "
        "units of k d^(alpha-d) (stress) and k d^alpha (energy), d the mean diameter. Seconds: "
        "the realizations' shear runs summed, one core each.",
        "",
        "| d | N | M | events | <d tau> | <d E> | <d gamma> | <tau>, sd | tau (stress) "
        "| tau (energy) | saddle-node | seconds |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['dim']} | {r['n']} | {r['realizations']} | {r['events']} | "
            + " | ".join(_mean(r[key]) for key, _ in MEANS)
            + f" | {r['stress']['mean']:.3g}, {r['stress']['sd']:.2g}"
            + f" | {_tau(r['stress_drop_exponent'])} | {_tau(r['energy_drop_exponent'])} | "
            f"{r['saddle_node_fraction']:.2f} | {r['compute_seconds']:.0f} |"
        )
    if scaling:
        lines += [
            "",
            "Finite-size scaling, mean (and sd of tau where events start) ~ N^b (least squares "
            "in log-log):",
            "",
        ]
        for dim, fits in scaling.items():
            lines.append(
                f"- {dim}D: "
                + ", ".join(
                    f"{label} b = {fits[key]['exponent']:.2f} +- {fits[key]['stderr']:.2f}"
                    for key, label in (*MEANS, ("stress_sd", "sd of tau"))
                    if key in fits
                )
            )
    figure = plot.avalanche_figure(drops, title=f"alpha = {args.alpha:g}, phi_c + {args.dphi:g}")
    plot.save(figure, args.figure_dir / "avalanches.png")
    lines += ["", "Figure: `docs/figures/avalanches.png`.", ""]
    save(args.output_dir, "avalanches", {"rows": rows, "scaling": scaling}, "\n".join(lines))
    print("\n".join(lines))


def _mean(stats: dict[str, float]) -> str:
    return f"{stats['mean']:.3g} +- {stats['stderr']:.1g}" if stats["n"] else "-"


def _tau(fit: dict[str, Any] | None) -> str:
    if fit is None:
        return "-"
    starts = [v for v in fit["by_start"].values() if np.isfinite(v)]
    return f"{fit['exponent']:.2f} +- {fit['stderr']:.2f} [{min(starts):.2f}, {max(starts):.2f}]"


def yielding(args: argparse.Namespace) -> None:
    """The ``--yielding`` ensembles, their table and figure."""
    rows = []
    for dphi in args.yielding:
        spec = EnsembleSpec(
            "cycles",
            jam=JamSpec(n=args.n, alpha=args.alpha),
            events=EventsSpec(
                delta_phi=dphi,
                step=args.step,
                max_step=args.max_step,
                tol=args.tol,
                amplitudes=tuple(args.amplitudes),
                cycles=args.cycles,
            ),
        )
        amplitudes = "-".join(f"{a:g}" for a in args.amplitudes)
        name = f"cycles_n{args.n}_a{args.alpha:g}_dphi{dphi:g}_c{args.cycles}_A{amplitudes}"
        name += f"_h{args.step:g}-{args.max_step:g}"
        result = ensemble(spec, args.ensembles / name, args.realizations, args.workers)
        rows.append({"delta_phi": dphi, **result.summary["yielding"]})
    lines = [
        "# Yielding under cyclic AQS shear (benchmarks/avalanches.py --yielding)",
        "",
        f"`python -m benchmarks.avalanches {' '.join(sys.argv[1:])}`",
        "",
        f"N = {args.n}, alpha = {args.alpha:g}, {args.realizations} packings per phi_c + "
        f"Delta phi, each sheared 0 -> A -> -A -> 0 at most {args.cycles} cycles at each A "
        f"from the same start; strain step {args.step:g} growing to {args.max_step:g} (each at "
        f"most A/2); events located to {args.tol:g}. A limit cycle: a cycle's end "
        "is an earlier cycle's end (the same minimum to 1e-6 mean diameters). Yielding "
        "amplitude: between the largest A at which more than half reached a limit cycle and "
        "the smallest at which at most half did.",
        "",
        "| Delta phi | A | reached | cycles to reach | period | events / period |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        for a in r["amplitudes"]:
            lines.append(
                f"| {r['delta_phi']:g} | {a['amplitude']:g} | {a['fraction_reached']:.2f} | "
                + " | ".join(
                    "-" if not a["fraction_reached"] else f"{a[k]:.3g} +- {a[k + '_stderr']:.1g}"
                    for k in ("cycles_to_reach", "period", "events_per_period")
                )
                + " |"
            )
    lines.append("")
    for r in rows:
        bracket = r["yielding_bracket"]
        lines.append(
            f"- Delta phi = {r['delta_phi']:g}: yielding amplitude "
            + ("not bracketed" if bracket is None else f"in ({bracket[0]:g}, {bracket[1]:g}]")
        )
    sweeps = {rf"$\Delta\phi$ = {r['delta_phi']:g}": r["amplitudes"] for r in rows}
    figure = plot.yielding_figure(sweeps, title=f"N = {args.n}, alpha = {args.alpha:g}")
    plot.save(figure, args.figure_dir / "yielding.png")
    lines += ["", "Figure: `docs/figures/yielding.png`.", ""]
    save(args.output_dir, "yielding", {"rows": rows}, "\n".join(lines))
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--run",
        type=float,
        nargs=4,
        action="append",
        metavar=("DIM", "N", "M", "STRAIN"),
        help="an ensemble of M packings of N particles in DIM dimensions sheared to STRAIN",
    )
    parser.add_argument("--yielding", type=float, nargs="*", default=[], metavar="DPHI")
    parser.add_argument("--alpha", type=float, default=2.0)
    parser.add_argument("--dphi", type=float, default=0.02)
    parser.add_argument("--transient", type=float, default=0.05)
    parser.add_argument("--tol", type=float, default=1e-9)
    parser.add_argument("--step", type=float, default=1e-4, help="the events' strain step")
    parser.add_argument(
        "--max-step", type=float, default=None, help="the largest step (default: the library's)"
    )
    parser.add_argument("--n", type=int, default=64, help="--yielding: particles")
    parser.add_argument("--realizations", type=int, default=3, help="--yielding: per Delta phi")
    parser.add_argument(
        "--amplitudes",
        type=float,
        nargs="+",
        default=[0.02, 0.04, 0.06, 0.08, 0.1, 0.12, 0.15],
    )
    parser.add_argument("--cycles", type=int, default=10, help="--yielding: at most")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument(
        "--ensembles", type=Path, default=ROOT / "benchmarks" / "results" / "ensembles"
    )
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--figure-dir", type=Path, default=ROOT / "docs" / "figures")
    args = parser.parse_args()
    if args.max_step is None:  # the library's default, named in the folders and tables
        args.max_step = default_max_step(args.step, opens_at_once(ContactModel(args.alpha)))
    pin(args.core)
    args.figure_dir.mkdir(parents=True, exist_ok=True)
    if args.yielding:
        yielding(args)
    if args.run:
        avalanches(args)


if __name__ == "__main__":
    main()
