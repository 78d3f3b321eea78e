"""Plastic events of athermal quasi-static shear: their cost, their statistics, and the
minimizer near an instability.

For each N a bidisperse packing is jammed (:func:`athermal.studies.experiments.jam_packing`,
the defaults) and compressed to ``phi_c + --dphi`` (radii scaled), then sheared (simple shear)
with every event located to 1e-9 in strain
(:func:`athermal.protocols.events.plastic_events`), for ``--strain`` or until ``--budget``
seconds have passed. Reported per N and contact law: events, events per minute (one core),
their stress and energy drops (mean, largest), the particles that moved, the fraction of
events that end in a saddle-node, the strain between events; with ``--newton`` the same run by
Newton-CG against L-BFGS: iterations per relaxation and seconds per event. The pooled energy
drops go into a log-binned histogram; the figure shows each N's stress-strain curve with its
events and the drops' distribution. Cyclic shear and the yielding amplitude:
``benchmarks/avalanches.py --yielding``.

    python -m benchmarks.plasticity                     # N = 256, 1024; Hooke and Hertz
    python -m benchmarks.plasticity --n 64 --strain 0.01 --budget 30 --output-dir "$(mktemp -d)"

Results: ``benchmarks/results/plasticity.md`` and ``.json``; figure
``docs/figures/plasticity.png``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from athermal.protocols.events import (
    BranchState,
    PlasticEvent,
    plastic_events,
)
from athermal.relaxation import Minimizer
from athermal.studies.experiments import JamSpec, jam_packing
from benchmarks.machine import ROOT, pin, save


def one(
    n: int, alpha: float, dphi: float, strain: float, budget: float, method: str
) -> dict[str, Any]:
    """One run: the states' curve, the events' numbers and the cost."""
    spec = JamSpec(n=n, alpha=alpha)
    jammed = jam_packing(spec, 1)
    start = jammed.packing.at_phi(jammed.phi_c + dphi)
    states: dict[str, list[float]] = {"strain": [], "tau": []}
    events: list[dict[str, Any]] = []
    iterations = 0
    t0 = time.perf_counter()
    for item in plastic_events(
        start, spec.model, mode="simple", strain=strain, step=1e-4, minimizer=Minimizer(method)
    ):
        if isinstance(item, BranchState):
            states["strain"].append(item.strain)
            states["tau"].append(item.tau)
            iterations += item.iterations
        elif isinstance(item, PlasticEvent):
            events.append({k: float(v) for k, v in item.row().items()})
        if time.perf_counter() - t0 > budget:
            break
    seconds = time.perf_counter() - t0
    drops = [e["stress_drop"] for e in events]
    energy = [e["energy_drop"] for e in events]
    strains = [e["strain"] for e in events]
    return {
        "n": n,
        "alpha": alpha,
        "method": method,
        "phi_c": jammed.phi_c,
        "strain_reached": states["strain"][-1],
        "events": len(events),
        "seconds": seconds,
        "events_per_minute": 60.0 * len(events) / seconds,
        "iterations_per_state": iterations / len(states["strain"]),
        "stress_drop_mean": statistics.fmean(drops) if drops else float("nan"),
        "energy_drop_mean": statistics.fmean(energy) if energy else float("nan"),
        "energy_drop_max": max(energy, default=float("nan")),
        "moved_mean": statistics.fmean(e["moved"] for e in events) if events else float("nan"),
        "saddle_node_fraction": (
            statistics.fmean(e["saddle_node"] for e in events) if events else float("nan")
        ),
        "strain_between_events": (
            statistics.fmean(np.diff(strains)) if len(strains) > 1 else float("nan")
        ),
        "states": states,
        "event_rows": events,
    }


def figure(runs: list[dict[str, Any]], path: Path) -> None:
    """Each run's stress-strain curve with its events, and the energy drops' distribution."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.0, 4.0), layout="constrained")
    curve, hist = fig.subplots(1, 2)
    for run in runs:
        if run["method"] != "lbfgs":
            continue
        label = f"N = {run['n']}, alpha = {run['alpha']:g}"
        (line,) = curve.plot(run["states"]["strain"], run["states"]["tau"], lw=0.8, label=label)
        at = [e["strain"] for e in run["event_rows"]]
        before = [e["tau_before"] for e in run["event_rows"]]
        curve.plot(at, before, "v", ms=3, color=line.get_color())
        drops = np.array([e["energy_drop"] for e in run["event_rows"]])
        drops = drops[drops > 0]
        if drops.size >= 5:
            edges = np.logspace(np.log10(drops.min()), np.log10(drops.max()), 12)
            counts, _ = np.histogram(drops, edges)
            density = counts / np.diff(edges) / drops.size
            centres = np.sqrt(edges[1:] * edges[:-1])
            keep = counts > 0
            hist.loglog(centres[keep], density[keep], "o-", ms=3, label=label)
    curve.set_xlabel(r"strain $\gamma$")
    curve.set_ylabel(r"$\tau = -\sigma_{xy}$")
    curve.set_title("simple shear, events located to 1e-9 (triangles)")
    curve.legend(fontsize=7)
    hist.set_xlabel(r"energy drop $\Delta E$")
    hist.set_ylabel(r"$P(\Delta E)$ (log bins)")
    if hist.get_lines():
        hist.legend(fontsize=7)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, nargs="+", default=[256, 1024])
    parser.add_argument("--alphas", type=float, nargs="+", default=[2.0, 2.5])
    parser.add_argument("--dphi", type=float, default=1e-2)
    parser.add_argument("--strain", type=float, default=0.2)
    parser.add_argument("--budget", type=float, default=600.0, help="seconds per run at most")
    parser.add_argument("--newton", action="store_true", help="also by Newton-CG (the first N)")
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--figure-dir", type=Path, default=ROOT / "docs" / "figures")
    args = parser.parse_args()
    pinned = pin(args.core)
    runs = []
    for alpha in args.alphas:
        for n in args.n:
            methods = ("lbfgs", "newton") if args.newton and n == args.n[0] else ("lbfgs",)
            for method in methods:
                runs.append(one(n, alpha, args.dphi, args.strain, args.budget, method))
                r = runs[-1]
                print(
                    f"N {n} alpha {alpha:g} {method}: {r['events']} events to strain "
                    f"{r['strain_reached']:.4f} in {r['seconds']:.0f} s",
                    flush=True,
                )
    columns = [
        ("N", "n", "d"),
        ("alpha", "alpha", "g"),
        ("method", "method", "s"),
        ("strain", "strain_reached", ".4f"),
        ("events", "events", "d"),
        ("events / min", "events_per_minute", ".1f"),
        ("iterations / state", "iterations_per_state", ".0f"),
        ("<d tau>", "stress_drop_mean", ".2e"),
        ("<d E>", "energy_drop_mean", ".2e"),
        ("max d E", "energy_drop_max", ".2e"),
        ("<moved>", "moved_mean", ".1f"),
        ("saddle-node", "saddle_node_fraction", ".2f"),
        ("<d gamma>", "strain_between_events", ".2e"),
    ]
    lines = [
        "# Plastic events of AQS simple shear (benchmarks/plasticity.py)",
        "",
        f"Packings jammed (defaults) and compressed to phi_c + {args.dphi:g}; events located to "
        "1e-9 in strain; one core. `saddle-node`: the fraction of events whose branch ended with "
        "lambda_min -> 0 (the rest lost stability at once, as where a harmonic contact opens).",
        "",
        "| " + " | ".join(c[0] for c in columns) + " |",
        "|" + "---|" * len(columns),
    ]
    for r in runs:
        lines.append("| " + " | ".join(format(r[key], f) for _, key, f in columns) + " |")
    figure(runs, args.figure_dir / "plasticity.png")
    lines += ["", "Figure: `docs/figures/plasticity.png`.", ""]
    save(args.output_dir, "plasticity", {"runs": runs, "pinned": pinned}, "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
