"""B3 and the paper's physics checks: jamming, compression scaling, moduli, iteration counts.

The experiments are the library's (:mod:`athermal.studies.experiments`: ``jam_packing``,
``compress``, ``iteration_counts``); this script runs them over realizations and writes the results.
Each experiment writes ``<output-dir>/<name>.json`` (raw numbers) and ``.md`` (summary), atomically
(default ``benchmarks/results/protocols``); jammed packings are cached as GSD files in
``--cache`` so later experiments reuse them.

    python -m benchmarks.physics phic --dim 2 --n 1024 --seeds 10       # phi_c and checks (2D)
    python -m benchmarks.physics phic --dim 2 --alpha 2.5 --seeds 5     # ... Hertzian
    python -m benchmarks.physics phic --dim 3 --n 1024 --seeds 3        # ... 3D
    python -m benchmarks.physics phic --n 4096 --solver direct          # ... exact factor
    python -m benchmarks.physics scaling --alpha 2 --n 1024 --seeds 5   # exponents, events
    python -m benchmarks.physics scaling --alpha 2 --n 1024 --refit     # ... its fits again
    python -m benchmarks.physics iterations --n 1024 --seeds 10   # the paper's iteration figure
    python -m benchmarks.physics iterations --n 4096 --seeds 2 --steps 3  # ... larger, shorter
    python -m benchmarks.physics timing --n 4096                        # per minimizer

Seeding, the library's one rule: realization ``k`` of a run with ``--root-seed S`` (default 0)
is the packing of seed ``child_seeds(S, count)[k]``; ``--seeds M`` runs realizations
``0 .. M-1``, ``timing --seed K`` realization ``K``. A root seed other than 0 adds ``_r<S>`` to
the results' names.

``--core K`` pins the run to core K (default: the lowest allowed), so two experiments can run
side by side on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from athermal.analysis.fitting import fit_power_law
from athermal.analysis.moduli import linear_response
from athermal.io import read_gsd, write_gsd
from athermal.linalg import SOLVERS
from athermal.model.packing import Packing
from athermal.protocols import (
    EVENTS,
    JAMMING_MINIMIZER,
    JAMMING_SCHEME,
    PHI_INIT,
    finite_strain_shear,
    isostatic_z,
)
from athermal.protocols.compress import pooled_fit
from athermal.protocols.jamming import isostatic_allowance
from athermal.relaxation import Minimizer
from athermal.studies import plot
from athermal.studies.experiments import (
    CompressSpec,
    IterationSpec,
    JamSpec,
    child_seeds,
    compress,
    iteration_counts,
    jam_packing,
)
from benchmarks.machine import ROOT, describe, line, pin, save

RESULTS = ROOT / "benchmarks" / "results" / "protocols"
TIMING_METHODS = (
    Minimizer("lbfgs"),
    Minimizer("lbfgs", "exp"),
    Minimizer("lbfgs", "contact"),
    Minimizer("cg"),
    Minimizer("fire"),
    Minimizer("newton"),
)
EPSILON = 1e-6
GROWTH = 1e-3


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def result_name(args: argparse.Namespace, name: str) -> str:
    """A result's file name: ``name``, with ``_r<S>`` for a root seed S other than 0."""
    return name + (f"_r{args.root_seed}" if args.root_seed else "")


def write(
    args: argparse.Namespace,
    name: str,
    data: dict[str, Any],
    markdown: str,
    meta: dict[str, str] | str | None = None,
) -> None:
    """Save one experiment's results (:func:`result_name`), run on ``meta``'s machine (default
    this one)."""
    data = {"root_seed": args.root_seed, **data}
    save(args.output_dir, result_name(args, name), data, markdown, meta)
    log(markdown)


def solver_suffix(solver: str) -> str:
    """What a preconditioner solver other than ``auto`` adds to a result's or packing's name."""
    return "" if solver == "auto" else f"_{solver}"


def jammed(cache: Path, spec: JamSpec, seed: int) -> tuple[Packing, float, dict[str, Any]]:
    """The jammed packing of ``spec`` and ``seed``
    (:func:`athermal.studies.experiments.jam_packing`)
    and its checks, from the cache or run."""
    solver = solver_suffix(spec.minimizer.solver)
    path = cache / f"jam{JAMMING_SCHEME}_n{spec.n}_d{spec.dim}_a{spec.alpha:g}_s{seed}{solver}.gsd"
    if path.exists():
        frame = read_gsd(path)
        info = {k: float(v) for k, v in frame.log.items() if np.size(v) == 1}
        return frame.packing, info["phi_c"], info
    result = jam_packing(spec, seed)
    obs, check = result.observables, result.check
    grid = (result.phi_c - PHI_INIT[spec.dim]) / spec.dphi
    info = {
        "phi_c": result.phi_c,
        "phi_low": result.phi_low,
        "on_grid": float(abs(grid - round(grid)) < 1e-6),
        "z": obs.z,
        "z_iso": isostatic_z(obs.n - obs.n_rattlers, spec.dim),
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
        "seconds": result.seconds,
    }
    cache.mkdir(parents=True, exist_ok=True)
    write_gsd(path, result.packing, model=spec.model, seed=seed, observables=info)
    return result.packing, result.phi_c, info


def realizations(args: argparse.Namespace) -> list[int]:
    """The seeds of realizations ``0 .. args.seeds-1`` of ``args.root_seed``."""
    return child_seeds(args.root_seed, args.seeds)


def checks_passed(infos: list[dict[str, Any]], n: int, dim: int) -> str:
    """One sentence: how many packings of ``n`` particles in ``dim`` dimensions (infos of
    :func:`jammed`) pass the jamming checks, with each one's isostaticity excess and allowance."""
    allowed = [isostatic_allowance(n - int(i["n_rattlers"]), dim, i["overlap_dphi"]) for i in infos]
    ok = [0 <= i["excess_contacts"] <= a for i, a in zip(infos, allowed, strict=True)]
    passed = sum(int(i["unjams"] and i["stable"] and o) for i, o in zip(infos, ok, strict=True))
    excess = ", ".join(
        f"{i['excess_contacts']:.0f} (<= {a:.1f})" for i, a in zip(infos, allowed, strict=True)
    )
    return (
        f"Every check passed: {passed} of {len(infos)} (unjams when decompressed: "
        f"{sum(int(i['unjams']) for i in infos)}, local minimum: "
        f"{sum(int(i['stable']) for i in infos)}, isostatic at the packing's overlap, "
        f"N_c - N_iso: {excess})."
    )


def finite(values: list[float]) -> list[float]:
    """``values`` without NaN (a realization unjammed at that Delta phi, ``IterationCounts``)."""
    return [v for v in values if np.isfinite(v)]


def mean_sd(values: list[float], digits: int = 5) -> str:
    """``mean ± sd`` of the finite ``values``, with ``(n of m)`` when some are not; ``-`` when
    none is."""
    kept = finite(values)
    if not kept:
        return "-"
    sd = statistics.stdev(kept) if len(kept) > 1 else 0.0
    count = "" if len(kept) == len(values) else f" ({len(kept)} of {len(values)})"
    return f"{statistics.fmean(kept):.{digits}f} ± {sd:.{digits}f}{count}"


def run_phic(args: argparse.Namespace) -> None:
    minimizer = replace(JAMMING_MINIMIZER, solver=args.solver)
    spec = JamSpec(args.n, args.dim, args.alpha, dphi=GROWTH, epsilon=EPSILON, minimizer=minimizer)
    rows = []
    for k, seed in enumerate(realizations(args)):
        _, _, info = jammed(args.cache, spec, seed)
        rows.append({"realization": k, "seed": seed, **info})
        log(f"realization {k} (seed {seed}): {info}")
    phis = [r["phi_c"] for r in rows]
    p_eps = [r["pressure"] / EPSILON ** (args.alpha - 1.0) for r in rows]
    lines = [
        f"# Jamming: {args.dim}D, N = {args.n}, alpha = {args.alpha:g}, epsilon = {EPSILON:g}, "
        f"growth {GROWTH:g}, {args.seeds} realizations of root seed {args.root_seed}, the "
        f"protocol's defaults ({minimizer.name})",
        "",
        f"phi_c = {mean_sd(phis)} (mean ± sd), standard error "
        f"{statistics.stdev(phis) / np.sqrt(len(phis)) if len(phis) > 1 else 0:.5f}; "
        f"range [{min(phis):.5f}, {max(phis):.5f}]. On the growth grid phi_init + k x {GROWTH:g}: "
        f"{sum(int(r['on_grid']) for r in rows)} of {len(rows)}. "
        f"{checks_passed(rows, args.n, args.dim)}",
        "",
        f"p / epsilon^(alpha-1) = {mean_sd(p_eps, 3)} (range {min(p_eps):.3f} ... "
        f"{max(p_eps):.3f}); mean overlap as a packing-fraction distance / epsilon: "
        f"{mean_sd([r['overlap_dphi'] / EPSILON for r in rows], 3)}.",
        "",
        "Columns: k, the realization, and its seed (child k of the root seed); N_c - N_iso among "
        "non-rattlers; 'unjams': decompressed by 3 epsilon and relaxed, E/N (in k<r>^alpha) "
        "falls to the jamming threshold; 'reopened': how often the bracket reopened because a "
        "jammed bound belonged to another basin.",
        "",
        "| k | seed | phi_c | phi_c - phi_low | p | N_c - N_iso | z | rattlers "
        "| unjams (E/N after) | minimum | reopened | steps | iterations | seconds |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---|---|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r['realization']} | {r['seed']} | {r['phi_c']:.7f} | {r['phi_c'] - r['phi_low']:.1e} "
        f"| {r['pressure']:.2e} | {r['excess_contacts']:.0f} | {r['z']:.4f} | "
        f"{r['n_rattlers']:.0f} | {'yes' if r['unjams'] else 'NO'} "
        f"({r['decompressed_energy']:.1e}) | {'yes' if r['stable'] else 'NO'} | "
        f"{r['reopened']:.0f} | {r['steps']:.0f} | {r['iterations']:.0f} | {r['seconds']:.1f} |"
        for r in rows
    ]
    name = f"phic_{args.dim}d_n{args.n}_a{args.alpha:g}{solver_suffix(args.solver)}"
    write(args, name, {"rows": rows}, "\n".join(lines) + "\n")


SCALING_COLUMNS = (("p", "pressure"), ("G", "shear_modulus"), ("z", "z_excess"))
"""The fitted quantities of ``scaling``: the results' key and the compression rows' column."""


def run_scaling(args: argparse.Namespace) -> None:
    name = f"scaling_n{args.n}_a{args.alpha:g}"
    if args.refit:
        stored = json.loads((args.output_dir / f"{result_name(args, name)}.json").read_text())
        for k, record in enumerate(stored["per_seed"]):  # older results numbered none
            record.setdefault("realization", k)
            for step in record["steps"]:  # nor did their steps give N (the finite-size rule)
                step.setdefault("n", args.n)
            for entry in stored["agreement"]:
                if entry["seed"] == record["seed"]:
                    entry.setdefault("realization", k)
        report = scaling_report(args, stored["per_seed"], stored["agreement"])
        refitted = (
            "\nThe pooled fits recomputed from the stored steps (`scaling --refit`): "
            f"{line(describe())}."
        )
        write(args, name, report[0], report[1] + refitted, stored["machine"])
        return
    jam_spec = JamSpec(args.n, 2, args.alpha, dphi=GROWTH, epsilon=EPSILON)
    spec = CompressSpec(fit_lower=args.lower)
    model = jam_spec.model
    per_seed, agreement = [], []
    for k, seed in enumerate(realizations(args)):
        packing, phi_c, _ = jammed(args.cache, jam_spec, seed)
        compression = compress(packing, model, phi_c, spec)
        steps, fits = compression.steps, compression.fits
        per_seed.append(
            {
                "realization": k,
                "seed": seed,
                "phi_c_protocol": phi_c,
                "phi_c_fitted": fits.phi_c_fitted,
                "events": fits.events,
                "saddles": sum(s.saddles for s in steps),
                "p": asdict(fits.pressure) if fits.pressure else None,
                "G": asdict(fits.shear_modulus) if fits.shear_modulus else None,
                "z": asdict(fits.z_excess) if fits.z_excess else None,
                "steps": [s.row() for s in steps],
            }
        )
        for target in (1e-2, 1e-1):
            near = compression.nearest(target)
            fs = finite_strain_shear(near.packing, model)
            lr = linear_response(near.packing, model)
            agreement.append(
                {
                    "realization": k,
                    "seed": seed,
                    "delta_phi": near.delta_phi,
                    "G_finite": fs.modulus,
                    "G_finite_stderr": fs.stderr,
                    "G_linear": lr.shear,
                    "relative_difference": (  # NaN where the state unjammed (G = 0)
                        (fs.modulus - lr.shear) / lr.shear if lr.shear else float("nan")
                    ),
                    "contacts_changed": bool(np.any(fs.contacts != fs.contacts_initial)),
                }
            )
        log(f"realization {k}: p {fits.pressure} G {fits.shear_modulus} z {fits.z_excess}")
    data, markdown = scaling_report(args, per_seed, agreement)
    write(args, name, data, markdown)


def scaling_report(
    args: argparse.Namespace, per_seed: list[dict[str, Any]], agreement: list[dict[str, Any]]
) -> tuple[dict[str, Any], str]:
    """The results of ``scaling`` (data and markdown) from its realizations' records, the pooled
    fits made here over all their steps (:func:`~athermal.protocols.compress.pooled_fit`)."""
    spec = CompressSpec(fit_lower=args.lower)
    compressions = [r["steps"] for r in per_seed]
    pooled = {key: pooled_fit(compressions, column, args.lower) for key, column in SCALING_COLUMNS}
    expect = {"p": args.alpha - 1.0, "G": args.alpha - 1.5, "z": 0.5}
    lines = [
        f"# Compression scaling: 2D, N = {args.n}, alpha = {args.alpha:g}, {len(per_seed)} "
        f"realizations of root seed {args.root_seed}",
        "",
        f"Delta phi from {spec.delta_min:g} to {spec.delta_max:g} above the protocol's own phi_c "
        f"(the jammed packings of `phic`, epsilon = {EPSILON:g}), {spec.per_decade} per decade, "
        f"each step relaxed from the previous one ({spec.minimizer.name}, {spec.rtol:g} of the "
        "mean contact force) and checked to be a minimum. Fits: y = a Delta phi^b over Delta phi "
        f"in [{args.lower:g}, {spec.delta_max:g}], over the steps "
        "`athermal.protocols.compress.fit_points` takes (no unjammed step nor any after it, no "
        "G < 0, z - z_iso of at least 10 contacts, p and G with Delta phi N^2 >= 1), per "
        "realization and pooled (all realizations' points in one fit).",
        "",
        "| quantity | expected | pooled fit (points) | per realization (exponent ± stderr) | "
        "per-realization spread (sd) |",
        "|---|---:|---:|---|---:|",
    ]
    for key, fit in pooled.items():
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
        f"Events per realization (steps of {spec.delta_phis().size}): "
        + ", ".join(EVENTS)
        + "; saddles left along their negative mode.",
        "",
        "| k | seed | phi_c (protocol) | phi_c (free fit, diagnostic) | "
        + " | ".join(EVENTS)
        + " | saddles |",
        "|---:|---:|---:|---:|" + "---:|" * len(EVENTS) + "---:|",
    ]
    lines += [
        f"| {r['realization']} | {r['seed']} | {r['phi_c_protocol']:.7f} | "
        f"{r['phi_c_fitted']:.7f} | "
        + " | ".join(str(r["events"][e]) for e in EVENTS)
        + f" | {r['saddles']} |"
        for r in per_seed
    ]
    lines += [
        "",
        "Shear modulus two ways (finite strain 1e-6 ... 1e-5 in 10 steps vs linear response):",
        "",
        "| k | Delta phi | G finite strain | G linear response | relative difference "
        "| contacts changed |",
        "|---:|---:|---:|---:|---:|---|",
    ]
    lines += [
        f"| {a['realization']} | {a['delta_phi']:.2e} | {a['G_finite']:.6e} | "
        f"{a['G_linear']:.6e} | {a['relative_difference']:+.2e} | "
        f"{'yes' if a['contacts_changed'] else 'no'} |"
        for a in agreement
    ]
    data = {
        "pooled": {key: asdict(fit) for key, fit in pooled.items()},
        "per_seed": per_seed,
        "agreement": agreement,
    }
    return data, "\n".join(lines) + "\n"


def run_iterations(args: argparse.Namespace) -> None:
    jam_spec = JamSpec(args.n, 2, 2.0, dphi=GROWTH, epsilon=EPSILON)
    base = IterationSpec()
    methods = tuple(m for m in base.methods if args.methods is None or m.label in args.methods)
    spec = IterationSpec(methods=methods, strains=base.strains[: args.steps], start=args.start)
    result = f"iterations_n{args.n}" + ("" if args.start == "affine" else f"_{args.start}")
    names = [m.name for m in spec.methods]
    deltas = spec.delta_phis
    # per method name, per Delta phi of the spec: one value per realization
    iterations: dict[str, list[list[float]]] = {name: [[] for _ in deltas] for name in names}
    seconds: dict[str, list[list[float]]] = {name: [[] for _ in deltas] for name in names}
    reached: list[list[float]] = []
    infos: list[dict[str, Any]] = []
    seeds = realizations(args)
    for k, seed in enumerate(seeds):
        packing, phi_c, info = jammed(args.cache, jam_spec, seed)
        infos.append(info)
        counts = iteration_counts(packing, jam_spec.model, phi_c, spec)
        reached.append(list(counts.delta_phi))
        for name in names:
            for i, (its, sec) in enumerate(
                zip(counts.iterations[name], counts.seconds[name], strict=True)
            ):
                iterations[name][i].append(its)
                seconds[name][i].append(sec)
        for i, d in enumerate(counts.delta_phi):
            log(
                f"realization {k} delta phi {d:.0e}: "
                + ", ".join(
                    f"{n} {counts.iterations[n][i]:.0f} it {1e3 * counts.seconds[n][i]:.1f} ms"
                    for n in names
                )
            )
    header = " | ".join(f"{name} (mean ± sd)" for name in names)
    rule = "|---:|" + "---:|" * len(names)

    def table(values: dict[str, list[list[float]]], scale: float, digits: int) -> list[str]:
        out = [f"| Delta phi | {header} |", rule]
        for i, d in enumerate(deltas):
            cells = " | ".join(mean_sd([scale * v for v in values[n][i]], digits) for n in names)
            out.append(f"| {d:.0e} | {cells} |")
        return out

    lines = [
        f"# Iterations per quasi-static shear step vs Delta phi: 2D, N = {args.n}, alpha = 2, "
        f"{args.seeds} realizations of root seed {args.root_seed}",
        "",
        f"Each entry: mean ± sd over realizations of the mean over the {len(spec.strains)} "
        f"simple-shear steps {min(spec.strains):g} ... {max(spec.strains):g} (the paper's "
        "protocol, `athermal.studies.experiments.iteration_counts`), tolerance 1e-9 of the "
        "mean contact "
        f"force (floored at round-off); each relaxation starts {START_TEXT[spec.start]}.",
        "",
        f"Packings: jammed by the protocol's defaults (epsilon {EPSILON:g}), phi_c "
        f"{mean_sd([i['phi_c'] for i in infos])}. {checks_passed(infos, args.n, 2)}",
        "",
        "Iterations per step:",
        "",
        *table(iterations, 1.0, 0),
        "",
        "Wall milliseconds per step (one core):",
        "",
        *table(seconds, 1e3, 1),
        "",
        *fits(deltas, iterations, seconds),
    ]
    data = {
        "seeds": seeds,
        "start": spec.start,
        "steps": len(spec.strains),
        "delta_phi": list(deltas),
        "reached": reached,
        "iterations": {
            n: {f"{d:.0e}": v for d, v in zip(deltas, per, strict=True)}
            for n, per in iterations.items()
        },
        "seconds": {
            n: {f"{d:.0e}": v for d, v in zip(deltas, per, strict=True)}
            for n, per in seconds.items()
        },
    }
    write(args, result, data, "\n".join(lines) + "\n")
    iterations_png(
        args.output_dir / f"{result_name(args, result)}.json",
        f"N = {args.n}: {args.seeds} realizations x {len(spec.strains)} steps, {spec.start} start",
    )


def iterations_png(results: Path, title: str) -> Path:
    """The paper-style figure of an iterations result file: ``<same name>.png`` beside it."""
    data = json.loads(results.read_text())
    deltas = data["delta_phi"]
    counts = {name: [per[f"{d:.0e}"] for d in deltas] for name, per in data["iterations"].items()}
    figure = plot.iterations_figure(deltas, counts, title=title, error="sd")
    return plot.save(figure, results.with_suffix(".png"))


START_TEXT = {
    "affine": "from the affinely sheared state (the paper's)",
    "linear": "from the affinely sheared state moved by the linear-response displacement "
    "(`start='linear'`; its solve counts in the wall time, not in the iterations)",
}


def fits(
    deltas: tuple[float, ...],
    iterations: dict[str, list[list[float]]],
    seconds: dict[str, list[list[float]]],
) -> list[str]:
    """Per method: the power law of the mean iterations against Delta phi (every point of the
    spec), and the wall time per step at 1e-6 over that at 1e-1 (issue 12's flatness test)."""
    out = [
        "Fitted `iterations ~ Delta phi^b` (least squares in log-log through the mean of every "
        f"Delta phi with iterations > 0, {min(deltas):.0e} ... {max(deltas):.0e}), and wall "
        "time per step at "
        "1e-6 over that at 1e-1:",
        "",
        "| method | b | prefactor | time(1e-6) / time(1e-1) |",
        "|---|---:|---:|---:|",
    ]
    keys = [f"{d:.0e}" for d in deltas]
    for name, per in iterations.items():
        means = [statistics.fmean(finite(v)) if finite(v) else 0.0 for v in per]
        spent = zip(keys, seconds[name], strict=True)
        times = {k: statistics.fmean(finite(v)) for k, v in spent if finite(v)}
        ratio = times["1e-06"] / times["1e-01"] if {"1e-06", "1e-01"} <= times.keys() else None
        shown = f"{ratio:.1f}" if ratio is not None else "-"
        if sum(m > 0.0 for m in means) < 3:  # e.g. no iteration at all from the linear start
            out.append(f"| {name} | - | - | {shown} |")
            continue
        fit = fit_power_law(deltas, means)
        out.append(f"| {name} | {fit.exponent:.3f} | {fit.prefactor:.3g} | {shown} |")
    return out


def run_timing(args: argparse.Namespace) -> None:
    seed = child_seeds(args.root_seed, args.seed + 1)[args.seed]
    name = f"timing_n{args.n}_s{args.seed}"
    order = [m.name for m in TIMING_METHODS]
    rows: list[dict[str, Any]] = []
    for minimizer in TIMING_METHODS:
        label = minimizer.name
        if args.methods and label not in args.methods:
            continue
        spec = JamSpec(args.n, 2, 2.0, dphi=GROWTH, epsilon=EPSILON, minimizer=minimizer)
        t0 = time.perf_counter()
        try:
            result = jam_packing(spec, seed)
        except RuntimeError as exc:  # ConvergenceError: report, go on
            rows.append(
                {
                    "method": label,
                    "seed": seed,
                    "error": str(exc),
                    "seconds": time.perf_counter() - t0,
                }
            )
            log(f"{label}: {exc}")
            continue
        rows.append(
            {
                "method": label,
                "seed": seed,
                "phi_c": result.phi_c,
                "steps": result.steps,
                "iterations": result.iterations,
                "evaluations": result.evaluations,
                "seconds": time.perf_counter() - t0,
                "z": result.observables.z,
            }
        )
        log(f"{label}: {rows[-1]}")
    previous = args.output_dir / f"{result_name(args, name)}.json"  # keep rows not rerun
    if previous.exists():
        rerun = {r["method"] for r in rows}
        kept = [
            r
            for r in json.loads(previous.read_text())["rows"]
            if r["method"] in order and r["method"] not in rerun and r.get("seed") == seed
        ]
        rows = sorted(kept + rows, key=lambda r: order.index(r["method"]))
    lines = [
        f"# Jamming run timing: 2D, N = {args.n}, alpha = 2, realization {args.seed} of root "
        f"seed {args.root_seed} (seed {seed}), phi_init {PHI_INIT[2]:g}, dphi {GROWTH:g}, "
        f"epsilon = {EPSILON:g}, one core",
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
    write(args, name, {"rows": rows}, "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--core", type=int, default=None, help="pin to this core")
    parser.add_argument("--cache", type=Path, default=ROOT / "benchmarks" / "cache")
    parser.add_argument(
        "--output-dir", type=Path, default=RESULTS, help="where results go (%(default)s)"
    )
    parser.add_argument(
        "--root-seed",
        type=int,
        default=0,
        help="realization k has seed child_seeds(root, count)[k] (default 0)",
    )
    sub = parser.add_subparsers(dest="experiment", required=True)
    phic = sub.add_parser("phic")
    phic.add_argument("--dim", type=int, default=2, choices=(2, 3))
    phic.add_argument("--n", type=int, default=1024)
    phic.add_argument("--alpha", type=float, default=2.0)
    phic.add_argument("--seeds", type=int, default=10, help="realizations")
    phic.add_argument(
        "--solver",
        default="auto",
        choices=SOLVERS,
        help="the preconditioner's solver (results and cached packings get _<solver>)",
    )
    scaling = sub.add_parser("scaling")
    scaling.add_argument("--n", type=int, default=1024)
    scaling.add_argument("--alpha", type=float, default=2.0)
    scaling.add_argument("--seeds", type=int, default=5, help="realizations")
    scaling.add_argument("--lower", type=float, default=1e-6)
    scaling.add_argument(
        "--refit",
        action="store_true",
        help="recompute the fits and results from the stored steps (no relaxation)",
    )
    iters = sub.add_parser("iterations")
    iters.add_argument("--n", type=int, default=1024)
    iters.add_argument("--seeds", type=int, default=10, help="realizations")
    iters.add_argument(
        "--steps", type=int, default=None, help="only the first STEPS shear steps (default all)"
    )
    iters.add_argument(
        "--methods",
        nargs="*",
        default=None,
        choices=[m.label for m in IterationSpec().methods],
        help="a subset of the minimizers (labels; default all)",
    )
    iters.add_argument(
        "--start",
        default="affine",
        choices=("affine", "linear"),
        help="where each relaxation starts (default affine, the paper's; results get _linear)",
    )
    timing = sub.add_parser("timing")
    timing.add_argument("--n", type=int, default=4096)
    timing.add_argument("--seed", type=int, default=0, help="the realization to time")
    timing.add_argument(
        "--methods", nargs="*", default=None, choices=[m.name for m in TIMING_METHODS]
    )
    args = parser.parse_args(argv)
    if getattr(args, "seeds", 1) < 1 or getattr(args, "seed", 0) < 0:
        parser.error("--seeds: need >= 1 realization; --seed: a realization index >= 0")
    pin(args.core)
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
