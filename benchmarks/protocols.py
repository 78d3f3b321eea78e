"""B3 and the seed's physics checks: jamming, compression scaling, moduli, iteration counts.

Each experiment writes ``benchmarks/results/protocols/<name>.json`` (raw numbers) and ``.md``
(summary), atomically; jammed packings are cached as GSD files in ``--cache`` so later
experiments reuse them.

    python benchmarks/protocols.py phic --dim 2 --n 1024 --seeds 10       # phi_c and checks (2D)
    python benchmarks/protocols.py phic --dim 2 --alpha 2.5 --seeds 5     # ... Hertzian
    python benchmarks/protocols.py phic --dim 3 --n 1024 --seeds 3        # ... 3D
    python benchmarks/protocols.py scaling --alpha 2 --n 1024 --seeds 5   # exponents, events
    python benchmarks/protocols.py iterations --n 1024 --seeds 10         # seed's iteration figure
    python benchmarks/protocols.py timing --n 4096                        # per minimizer

``--core K`` pins the run to core K (default: the lowest allowed), so two experiments can run
side by side on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from athermal.contact import ContactModel
from athermal.fitting import fit_power_law
from athermal.io import read_gsd, write_gsd
from athermal.moduli import linear_response
from athermal.packing import Packing, random_packing
from athermal.protocols import (
    EVENTS,
    ITERATION_METHODS,
    JAMMING_SCHEME,
    PHI_INIT,
    Minimizer,
    compression_steps,
    finite_strain_shear,
    isostatic_z,
    jam,
    log_spaced,
    scaling_exponents,
)

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "protocols"
TIMING_METHODS = {
    "L-BFGS": Minimizer("lbfgs"),
    "P-L-BFGS (Exp, A=0)": Minimizer("lbfgs", "exp"),
    "contact P-L-BFGS": Minimizer("lbfgs", "contact"),
    "FR-CG": Minimizer("cg"),
    "FIRE": Minimizer("fire"),
}


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as handle:
        handle.write(text)
    os.replace(tmp, path)


def save(name: str, data: dict[str, Any], markdown: str) -> None:
    data["machine"] = machine()
    markdown += f"\nRun: {data['machine']}.\n"
    write_atomic(RESULTS / f"{name}.json", json.dumps(data, indent=1) + "\n")
    write_atomic(RESULTS / f"{name}.md", markdown)
    log(markdown)


def cpu_model() -> str:
    """The CPU's model name, as /proc/cpuinfo gives it."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def machine() -> str:
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else "n/a"
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip()
    except OSError:
        commit = "unknown"
    return f"{stamp}; commit {commit}; {cpu_model()}, {os.cpu_count()} cores, pinned to {cores}"


EPSILON = 1e-6
GROWTH = 1e-3


def jammed(
    cache: Path, n: int, dim: int, alpha: float, seed: int
) -> tuple[Packing, float, dict[str, Any]]:
    """The jammed packing of (n, dim, alpha, seed) at epsilon = 1e-6 with the jamming
    protocol's defaults (P-L-BFGS) and its checks, from the cache or run."""
    path = cache / f"jam{JAMMING_SCHEME}_n{n}_d{dim}_a{alpha:g}_s{seed}.gsd"
    if path.exists():
        frame = read_gsd(path)
        info = {k: float(v) for k, v in frame.log.items() if np.size(v) == 1}
        return frame.packing, info["phi_c"], info
    t0 = time.perf_counter()
    model = ContactModel(alpha)
    phi_init = PHI_INIT[dim]
    start = random_packing(n, phi_init, dim=dim, seed=seed)
    result = jam(start, model, epsilon=EPSILON, dphi=GROWTH)
    obs, check = result.observables, result.check
    grid = (result.phi_c - phi_init) / GROWTH
    info = {
        "phi_c": result.phi_c,
        "phi_low": result.phi_low,
        "on_grid": float(abs(grid - round(grid)) < 1e-6),
        "z": obs.z,
        "z_iso": isostatic_z(obs.n - obs.n_rattlers, dim),
        "n_rattlers": obs.n_rattlers,
        "energy": obs.energy,
        "pressure": obs.pressure,
        "excess_contacts": check.excess_contacts,
        "unjams": float(check.unjams),
        "decompressed_energy": check.decompressed_energy,
        "overlap_dphi": check.overlap_dphi,
        "stable": float(check.stable),
        "reopened": float(
            sum(
                np.isinf(s.phi_high) and np.isfinite(result.history[s.index - 1].phi_high)
                for s in result.history[1:]
            )
        ),
        "steps": result.steps,
        "iterations": result.iterations,
        "seconds": time.perf_counter() - t0,
    }
    cache.mkdir(parents=True, exist_ok=True)
    write_gsd(path, result.packing, model=model, seed=seed, observables=info)
    return result.packing, result.phi_c, info


def mean_sd(values: list[float], digits: int = 5) -> str:
    sd = statistics.stdev(values) if len(values) > 1 else 0.0
    return f"{statistics.fmean(values):.{digits}f} ± {sd:.{digits}f}"


def run_phic(args: argparse.Namespace) -> None:
    rows = []
    for seed in range(args.seeds):
        _, _, info = jammed(args.cache, args.n, args.dim, args.alpha, seed)
        rows.append({"seed": seed, **info})
        log(f"seed {seed}: {info}")
    phis = [r["phi_c"] for r in rows]
    p_eps = [r["pressure"] / EPSILON ** (args.alpha - 1.0) for r in rows]
    lines = [
        f"# Jamming: {args.dim}D, N = {args.n}, alpha = {args.alpha:g}, epsilon = {EPSILON:g}, "
        f"growth {GROWTH:g}, {args.seeds} seeds, the protocol's defaults (P-L-BFGS)",
        "",
        f"phi_c = {mean_sd(phis)} (mean ± sd), standard error "
        f"{statistics.stdev(phis) / np.sqrt(len(phis)) if len(phis) > 1 else 0:.5f}; "
        f"range [{min(phis):.5f}, {max(phis):.5f}]. On the growth grid phi_init + k x {GROWTH:g}: "
        f"{sum(int(r['on_grid']) for r in rows)} of {len(rows)}. Every check passed: "
        f"{sum(int(r['unjams'] and r['stable'] and 0 <= r['excess_contacts'] <= 4) for r in rows)}"
        f" of {len(rows)}.",
        "",
        f"p / epsilon^(alpha-1) = {mean_sd(p_eps, 3)} (range {min(p_eps):.3f} ... "
        f"{max(p_eps):.3f}); mean overlap as a packing-fraction distance / epsilon: "
        f"{mean_sd([r['overlap_dphi'] / EPSILON for r in rows], 3)}.",
        "",
        "Columns: N_c - N_iso among non-rattlers; 'unjams': decompressed by 3 epsilon and "
        "relaxed, E/N (in k<r>^alpha) falls to the jamming threshold; 'reopened': how often the "
        "bracket reopened because a jammed bound belonged to another basin.",
        "",
        "| seed | phi_c | phi_c - phi_low | p | N_c - N_iso | z | rattlers | unjams (E/N after) "
        "| minimum | reopened | steps | iterations | seconds |",
        "|---:|---:|---:|---:|---:|---:|---:|---|---|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r['seed']} | {r['phi_c']:.7f} | {r['phi_c'] - r['phi_low']:.1e} | "
        f"{r['pressure']:.2e} | {r['excess_contacts']:.0f} | {r['z']:.4f} | "
        f"{r['n_rattlers']:.0f} | {'yes' if r['unjams'] else 'NO'} "
        f"({r['decompressed_energy']:.1e}) | {'yes' if r['stable'] else 'NO'} | "
        f"{r['reopened']:.0f} | {r['steps']:.0f} | {r['iterations']:.0f} | {r['seconds']:.1f} |"
        for r in rows
    ]
    name = f"phic_{args.dim}d_n{args.n}_a{args.alpha:g}"
    save(name, {"rows": rows}, "\n".join(lines) + "\n")


def run_scaling(args: argparse.Namespace) -> None:
    model = ContactModel(args.alpha)
    deltas = log_spaced(1e-7, 1e-1, 4)
    per_seed, agreement = [], []
    pooled: dict[str, list[float]] = {"dphi": [], "pressure": [], "shear": [], "z_excess": []}
    for seed in range(args.seeds):
        packing, phi_c, _ = jammed(args.cache, args.n, 2, args.alpha, seed)
        steps = list(compression_steps(packing, model, phi_c=phi_c, delta_phis=deltas))
        fits = scaling_exponents(steps, lower=args.lower)
        per_seed.append(
            {
                "seed": seed,
                "phi_c_protocol": phi_c,
                "phi_c_fitted": fits.phi_c_fitted,
                "events": fits.events,
                "saddles": sum(s.saddles for s in steps),
                "p": fits.pressure.__dict__ if fits.pressure else None,
                "G": fits.shear_modulus.__dict__ if fits.shear_modulus else None,
                "z": fits.z_excess.__dict__ if fits.z_excess else None,
                "steps": [s.row() for s in steps],
            }
        )
        for s in steps:
            pooled["dphi"].append(s.delta_phi)
            pooled["pressure"].append(s.pressure)
            pooled["shear"].append(s.shear_modulus)
            pooled["z_excess"].append(s.z_excess)
        for target in (1e-2, 1e-1):
            near = min(steps, key=lambda s: abs(np.log(s.delta_phi / target)))
            fs = finite_strain_shear(near.packing, model)
            lr = linear_response(near.packing, model)
            agreement.append(
                {
                    "seed": seed,
                    "delta_phi": near.delta_phi,
                    "G_finite": fs.modulus,
                    "G_finite_stderr": fs.stderr,
                    "G_linear": lr.shear,
                    "relative_difference": (fs.modulus - lr.shear) / lr.shear,
                    "contacts_changed": bool(np.any(fs.contacts != fs.contacts_initial)),
                }
            )
        log(f"seed {seed}: p {fits.pressure} G {fits.shear_modulus} z {fits.z_excess}")
    x = pooled["dphi"]
    p_all = fit_power_law(x, pooled["pressure"], lower=args.lower)
    g_all = fit_power_law(x, pooled["shear"], lower=args.lower)
    z_all = fit_power_law(x, pooled["z_excess"], lower=args.lower)
    expect = {"p": args.alpha - 1.0, "G": args.alpha - 1.5, "z": 0.5}
    lines = [
        f"# Compression scaling: 2D, N = {args.n}, alpha = {args.alpha:g}, {args.seeds} seeds",
        "",
        "Delta phi from 1e-7 to 1e-1 above the protocol's own phi_c (the jammed packings of "
        f"`phic`, epsilon = {EPSILON:g}), 4 per decade, each step relaxed from the previous one "
        "(L-BFGS, 1e-9 of the mean contact force) and checked to be a minimum. Fits: "
        f"y = a Delta phi^b over Delta phi in [{args.lower:g}, 1e-1], every step with y > 0 "
        "(G < 0 steps, unstable to shear, and unjammed steps drop out), per seed and pooled "
        "(all seeds' points in one fit).",
        "",
        "| quantity | expected | pooled fit (points) | per seed (exponent ± stderr) | "
        "per-seed spread (sd) |",
        "|---|---:|---:|---|---:|",
    ]
    for key, fit in (("p", p_all), ("G", g_all), ("z", z_all)):
        values = [r[key]["exponent"] for r in per_seed if r[key]]
        seeds = ", ".join(
            f"{r[key]['exponent']:.3f} ± {r[key]['stderr']:.3f}" if r[key] else "-"
            for r in per_seed
        )
        spread = statistics.stdev(values) if len(values) > 1 else 0.0
        lines.append(
            f"| {key} | {expect[key]:g} | {fit.exponent:.3f} ± {fit.stderr:.3f} ({fit.points}) "
            f"| {seeds} | {spread:.3f} |"
        )
    lines += [
        "",
        "Events per seed (steps of "
        + str(deltas.size)
        + "): "
        + ", ".join(EVENTS)
        + "; saddles left along their negative mode.",
        "",
        "| seed | phi_c (protocol) | phi_c (free fit, diagnostic) | "
        + " | ".join(EVENTS)
        + " | saddles |",
        "|---:|---:|---:|" + "---:|" * len(EVENTS) + "---:|",
    ]
    lines += [
        f"| {r['seed']} | {r['phi_c_protocol']:.7f} | {r['phi_c_fitted']:.7f} | "
        + " | ".join(str(r["events"][e]) for e in EVENTS)
        + f" | {r['saddles']} |"
        for r in per_seed
    ]
    lines += [
        "",
        "Shear modulus two ways (finite strain 1e-6 ... 1e-5 in 10 steps vs linear response):",
        "",
        "| seed | Delta phi | G finite strain | G linear response | relative difference "
        "| contacts changed |",
        "|---:|---:|---:|---:|---:|---|",
    ]
    lines += [
        f"| {a['seed']} | {a['delta_phi']:.2e} | {a['G_finite']:.6e} | {a['G_linear']:.6e} | "
        f"{a['relative_difference']:+.2e} | {'yes' if a['contacts_changed'] else 'no'} |"
        for a in agreement
    ]
    data = {
        "pooled": {"p": p_all.__dict__, "G": g_all.__dict__, "z": z_all.__dict__},
        "per_seed": per_seed,
        "agreement": agreement,
    }
    save(f"scaling_n{args.n}_a{args.alpha:g}", data, "\n".join(lines) + "\n")


def run_iterations(args: argparse.Namespace) -> None:
    model = ContactModel(2.0)
    deltas = log_spaced(1e-6, 1e-1, 1)
    counts: dict[str, dict[float, list[float]]] = {
        label: {float(d): [] for d in deltas} for label in ITERATION_METHODS
    }
    for seed in range(args.seeds):
        packing, phi_c, _ = jammed(args.cache, args.n, 2, 2.0, seed)
        for step in compression_steps(packing, model, phi_c=phi_c, delta_phis=deltas):
            for label, minimizer in ITERATION_METHODS.items():
                fs = finite_strain_shear(step.packing, model, minimizer=minimizer)
                counts[label][step.delta_phi].append(float(np.mean(fs.iterations)))
            log(
                f"seed {seed} delta phi {step.delta_phi:.0e}: "
                + ", ".join(f"{k} {v[step.delta_phi][-1]:.0f}" for k, v in counts.items())
            )
    header = " | ".join(f"{label} (mean ± sd)" for label in ITERATION_METHODS)
    lines = [
        f"# Iterations per quasi-static shear step vs Delta phi: 2D, N = {args.n}, alpha = 2, "
        f"{args.seeds} realizations",
        "",
        "Each entry: mean over realizations (± standard deviation) of the mean iterations of the "
        "10 simple-shear steps 1e-6 ... 1e-5 (the seed's protocol), tolerance 1e-9 of the mean "
        "contact force.",
        "",
        f"| Delta phi | {header} |",
        "|---:|" + "---:|" * len(ITERATION_METHODS),
    ]
    for d in deltas:
        cells = " | ".join(mean_sd(counts[label][float(d)], 0) for label in ITERATION_METHODS)
        lines.append(f"| {d:.0e} | {cells} |")
    data = {label: {f"{d:.0e}": v for d, v in per.items()} for label, per in counts.items()}
    save(f"iterations_n{args.n}", {"iterations": data}, "\n".join(lines) + "\n")


def run_timing(args: argparse.Namespace) -> None:
    model = ContactModel(2.0)
    name = f"timing_n{args.n}_s{args.seed}"
    rows: list[dict[str, Any]] = []
    for label, minimizer in TIMING_METHODS.items():
        if args.methods and label not in args.methods:
            continue
        start = random_packing(args.n, PHI_INIT[2], seed=args.seed)
        t0 = time.perf_counter()
        try:
            result = jam(start, model, minimizer=minimizer)
        except RuntimeError as exc:  # ConvergenceError: report, go on
            rows.append({"method": label, "error": str(exc), "seconds": time.perf_counter() - t0})
            log(f"{label}: {exc}")
            continue
        rows.append(
            {
                "method": label,
                "phi_c": result.phi_c,
                "steps": result.steps,
                "iterations": result.iterations,
                "evaluations": result.evaluations,
                "seconds": time.perf_counter() - t0,
                "z": result.observables.z,
            }
        )
        log(f"{label}: {rows[-1]}")
    previous = RESULTS / f"{name}.json"  # keep the rows of methods not rerun
    if previous.exists():
        rerun = {r["method"] for r in rows}
        kept = [r for r in json.loads(previous.read_text())["rows"] if r["method"] not in rerun]
        order = list(TIMING_METHODS)
        rows = sorted(kept + rows, key=lambda r: order.index(r["method"]))
    lines = [
        f"# Jamming run timing: 2D, N = {args.n}, alpha = 2, seed {args.seed}, phi_init 0.8, "
        "dphi 1e-3, epsilon = 1e-6, one core",
        "",
        "Rows may come from different runs of this script (methods rerun replace their row); "
        "the machine line is the latest run's.",
        "",
        "| minimizer | phi_c | steps | iterations | evaluations | seconds |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['method']} | failed: {r['error']} | | | | {r['seconds']:.1f} |")
        else:
            lines.append(
                f"| {r['method']} | {r['phi_c']:.7f} | {r['steps']} | {r['iterations']} | "
                f"{r['evaluations']} | {r['seconds']:.1f} |"
            )
    save(name, {"rows": rows}, "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--core", type=int, default=None, help="pin to this core")
    parser.add_argument("--cache", type=Path, default=ROOT / "benchmarks" / "cache")
    sub = parser.add_subparsers(dest="experiment", required=True)
    phic = sub.add_parser("phic")
    phic.add_argument("--dim", type=int, default=2, choices=(2, 3))
    phic.add_argument("--n", type=int, default=1024)
    phic.add_argument("--alpha", type=float, default=2.0)
    phic.add_argument("--seeds", type=int, default=10)
    scaling = sub.add_parser("scaling")
    scaling.add_argument("--n", type=int, default=1024)
    scaling.add_argument("--alpha", type=float, default=2.0)
    scaling.add_argument("--seeds", type=int, default=5)
    scaling.add_argument("--lower", type=float, default=1e-6)
    iters = sub.add_parser("iterations")
    iters.add_argument("--n", type=int, default=1024)
    iters.add_argument("--seeds", type=int, default=10)
    timing = sub.add_parser("timing")
    timing.add_argument("--n", type=int, default=4096)
    timing.add_argument("--seed", type=int, default=0)
    timing.add_argument("--methods", nargs="*", default=None)
    args = parser.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        allowed = os.sched_getaffinity(0)
        os.sched_setaffinity(0, {args.core if args.core is not None else min(allowed)})
    runners: dict[str, Callable[[argparse.Namespace], None]] = {
        "phic": run_phic,
        "scaling": run_scaling,
        "iterations": run_iterations,
        "timing": run_timing,
    }
    runners[args.experiment](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
