"""Plane shear between rough walls: stress-strain curves, the walls' balance and the
macroscopic friction of frictionless disks.

For each seed a bidisperse packing of N disks is jammed between walls normal to y in the unit
cell (:func:`athermal.studies.experiments.jam_packing`, epsilon = 1e-6), compressed to
``phi_c + --delta-phi`` and relaxed, then sheared by moving the upper wall along x
(:func:`athermal.protocols.shear.shear_steps`, ``mode="plane"``: the particles within one
largest diameter of each wall glued to it) in steps of ``--step`` to ``--strain``, each step
relaxed by P-L-BFGS to 1e-9 of the mean contact force. Reported:

* the shear stress ``tau`` and the normal stress ``sigma_n`` on the walls against the strain
  (mean over the seeds), their ratio ``mu = tau / sigma_n`` (the macroscopic friction
  coefficient), its mean over the steady state (strain >= ``--steady``) per seed, and the
  initial modulus ``tau / gamma`` after the first step;
* the checks: the worst ``|t_lower + t_upper| / sigma_n`` over all steps (the free particles'
  force balance as the walls see it), plastic events per unit strain;
* time per step.

Run from the repository root::

    python -m benchmarks.plane_shear             # N = 1024, 8 seeds, strain 0.5
    python -m benchmarks.plane_shear --quick     # N = 256, 2 seeds, strain 0.05
    python -m benchmarks.plane_shear --seeds 4 --strain 0.4 --step 1e-3 --tag step1e-3
    python -m benchmarks.plane_shear --seeds 4 --strain 0.4 --layer 1.5 --tag layer1.5

Results: ``benchmarks/results/plane_shear.md`` and ``plane_shear.json`` (a variant's under
``plane_shear-TAG``, the numerical parameters varied); figure ``docs/figures/plane_shear.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from athermal.protocols.shear import plane_tractions, rough_walls, shear_steps
from athermal.relaxation import Minimizer, relax
from athermal.studies.experiments import JamSpec, jam_packing
from benchmarks.machine import ROOT, pin, save


def one(
    n: int, seed: int, delta_phi: float, strain: float, step: float, layer: float
) -> dict[str, Any]:
    """Jam, compress and plane-shear one packing (glued layers ``layer`` largest diameters
    thick); its curves and checks."""
    spec = JamSpec(n=n, walls="y")
    jammed = jam_packing(spec, seed)
    start = relax(
        jammed.packing.at_phi(jammed.phi_c + delta_phi), spec.model, Minimizer("newton"), gtol=1e-13
    ).packing
    wall_layer = layer * 2.0 * float(start.radii.max())
    lower, upper = rough_walls(start, wall_layer)
    frozen = lower | upper
    rows: dict[str, list[float]] = {"strain": [], "tau": [], "normal": [], "pressure": []}
    worst, plastic, seconds = 0.0, 0, []
    for s in shear_steps(
        start,
        spec.model,
        mode="plane",
        strain=strain,
        step=step,
        minimizer=Minimizer("plbfgs"),
        wall_layer=wall_layer,
    ):
        t = plane_tractions(s.packing, spec.model, lower, upper)
        normal = float(t[1, 1])
        worst = max(worst, float(np.abs(t[0] + t[1]).max()) / normal)
        rows["strain"].append(s.strain)
        rows["tau"].append(s.tau)
        rows["normal"].append(normal)
        rows["pressure"].append(s.observables.pressure)
        plastic += int(s.plastic)
        if s.index:
            seconds.append(s.seconds)
    return {
        "seed": seed,
        "phi_c": jammed.phi_c,
        "jam_passed": jammed.check.passed,
        "frozen": [int(lower.sum()), int(upper.sum())],
        "free": int((~frozen).sum()),
        "worst_balance": worst,
        "plastic_events": plastic,
        "seconds_per_step": float(np.median(seconds)),
        **rows,
    }


def figure(strain: NDArray[np.float64], rows: list[dict[str, Any]], path: Any) -> None:
    """``tau / sigma_n`` and ``tau`` against the strain, each seed and the mean."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(8.0, 3.4), constrained_layout=True)
    for r in rows:
        tau, normal = np.asarray(r["tau"]), np.asarray(r["normal"])
        left.plot(strain, tau, linewidth=0.7, alpha=0.6)
        right.plot(strain, tau / normal, linewidth=0.7, alpha=0.6)
    mu = np.mean([np.asarray(r["tau"]) / np.asarray(r["normal"]) for r in rows], axis=0)
    right.plot(strain, mu, color="k", linewidth=1.4, label="mean")
    left.set_xlabel("wall strain $\\gamma$ (displacement / gap)")
    left.set_ylabel("shear stress on the walls $\\tau$")
    right.set_xlabel("wall strain $\\gamma$")
    right.set_ylabel("$\\mu = \\tau / \\sigma_n$")
    right.legend(loc="lower right", frameon=False)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1024)
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--delta-phi", type=float, default=1e-2)
    parser.add_argument("--strain", type=float, default=0.5)
    parser.add_argument("--step", type=float, default=2e-3)
    parser.add_argument("--steady", type=float, default=0.15, help="steady state from here")
    parser.add_argument("--layer", type=float, default=1.0, help="in largest diameters")
    parser.add_argument("--tag", default="", help="results under plane_shear-TAG (a variant)")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--figure-dir", type=Path, default=ROOT / "docs" / "figures")
    args = parser.parse_args()
    n, seeds, strain = (256, 2, 0.05) if args.quick else (args.n, args.seeds, args.strain)
    steady = min(args.steady, 0.5 * strain)
    pinned = pin(args.core)
    t0 = time.perf_counter()
    rows = [
        one(n, seed, args.delta_phi, strain, args.step, args.layer) for seed in range(1, seeds + 1)
    ]
    total = time.perf_counter() - t0
    gamma = np.asarray(rows[0]["strain"])
    late = gamma >= steady
    mu = np.array(
        [np.mean(np.asarray(r["tau"])[late] / np.asarray(r["normal"])[late]) for r in rows]
    )
    modulus = np.array([r["tau"][1] / gamma[1] for r in rows])
    error = np.sqrt(len(rows))
    summary = {
        "n": n,
        "seeds": len(rows),
        "delta_phi": args.delta_phi,
        "strain": strain,
        "step": args.step,
        "layer": args.layer,
        "steady_from": steady,
        "mu_steady": [float(mu.mean()), float(mu.std(ddof=1) / error) if len(rows) > 1 else 0.0],
        "mu_per_seed": mu.tolist(),
        "initial_modulus": [
            float(modulus.mean()),
            float(modulus.std(ddof=1) / error) if len(rows) > 1 else 0.0,
        ],
        "normal_start": float(np.mean([r["normal"][0] for r in rows])),
        "pressure_start": float(np.mean([r["pressure"][0] for r in rows])),
        "worst_balance": max(r["worst_balance"] for r in rows),
        "plastic_per_strain": float(np.mean([r["plastic_events"] for r in rows]) / strain),
        "all_jams_passed": all(r["jam_passed"] for r in rows),
        "seconds_per_step": float(np.median([r["seconds_per_step"] for r in rows])),
        "seconds": total,
    }
    name = f"plane_shear-{args.tag}" if args.tag else "plane_shear"
    if not args.tag:
        figure(gamma, rows, args.figure_dir / "plane_shear.png")
    lines = [
        "# Plane shear between rough walls (benchmarks/plane_shear.py)",
        "",
        f"N = {n} bidisperse disks, alpha = 2, {len(rows)} seeds; jammed between walls normal to "
        f"y (epsilon = 1e-6), compressed to phi_c + {args.delta_phi:g}, then sheared by the upper "
        f"wall to strain {strain:g} in steps of {args.step:g} (P-L-BFGS, rtol 1e-9); the "
        f"particles within {args.layer:g} largest diameter(s) of each wall glued to it.",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| glued particles (lower, upper) per seed | {[r['frozen'] for r in rows]} |",
        f"| every jamming passed its checks | {summary['all_jams_passed']} |",
        f"| normal stress on the walls at the start / pressure | {summary['normal_start']:.4e} / "
        f"{summary['pressure_start']:.4e} |",
        f"| initial modulus tau / gamma after one step (mean ± s.e.) | "
        f"{summary['initial_modulus'][0]:.4f} ± {summary['initial_modulus'][1]:.4f} |",
        f"| mu = tau / sigma_n, strain >= {steady:g} (mean ± s.e. over seeds) | "
        f"{summary['mu_steady'][0]:.4f} ± {summary['mu_steady'][1]:.4f} |",
        f"| mu per seed | {', '.join(f'{m:.4f}' for m in mu)} |",
        f"| plastic events per unit strain (mean per packing) | "
        f"{summary['plastic_per_strain']:.0f} |",
        "| worst abs(t_lower + t_upper) / sigma_n over all steps | "
        f"{summary['worst_balance']:.1e} |",
        f"| time per step, median (s) | {summary['seconds_per_step']:.3f} |",
        f"| total (s) | {total:.0f} |",
        "",
        "Mean over the seeds (every tenth step):",
        "",
        "| strain | tau | sigma_n | mu |",
        "|---|---|---|---|",
    ]
    tau = np.mean([r["tau"] for r in rows], axis=0)
    normal = np.mean([r["normal"] for r in rows], axis=0)
    mu_curve = np.mean([np.asarray(r["tau"]) / np.asarray(r["normal"]) for r in rows], axis=0)
    for k in range(0, gamma.size, 10):
        lines.append(f"| {gamma[k]:.3f} | {tau[k]:.4e} | {normal[k]:.4e} | {mu_curve[k]:.4f} |")
    lines += ["", "Figure: `docs/figures/plane_shear.png`.", ""]
    save(
        args.output_dir,
        name,
        {"summary": summary, "rows": rows, "pinned": pinned},
        "\n".join(lines),
    )


if __name__ == "__main__":
    main()
