"""omega*, the lower edge of the plateau of D(omega), against Delta phi: the table of
``docs/modes.md``.

For each N and start seed the packing is jammed by the defaults of
:class:`athermal.studies.experiments.JamSpec` (alpha = 2, the default protocol and epsilon),
compressed from its own phi_c through the Delta phi values (one :func:`athermal.compression_steps`
run, each state from the previous one), and at the jammed packing and every compressed state the
full spectrum is taken (:func:`athermal.analysis.modes.vibrational_modes`, as ``athermal modes``
does) and :func:`athermal.analysis.modes.plateau_edge` gives omega* ± its bootstrap error and the
modes below omega*. The table gives per N and Delta phi each seed's omega* ± err (modes below), the
mean and sample sd over seeds, the mean error, its ratio to the sd and the mean ``z - z_iso``.

omega* is *resolved* at a Delta phi when at least ``--min-modes`` (default 3) modes lie below
it on every seed and no seed's state unjammed; the exponent of omega* against Delta phi is
fitted per N (:func:`athermal.analysis.fitting.fit_power_law`) to the mean over seeds at the
resolved Delta phi (at least 3 of them), and to each seed alone over the same Delta phi.

Run from the repository root (each worker pinned to its own core)::

    python -m benchmarks.omega_star                     # N = 256, 1024; seeds 1-4; 2 workers
    python -m benchmarks.omega_star --n 256 --seeds 1 2 --workers 1

Results: ``benchmarks/results/omega_star.md`` and ``.json``, read in ``docs/modes.md``.
"""

from __future__ import annotations

import os

# One thread for every library, set before numpy is imported (as benchmarks/kernels.py): each
# worker is pinned to one core, and a second BLAS thread there made the dense eigh of N = 1024
# about 3x slower alone and far slower beside another loaded core.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import multiprocessing  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from athermal import ContactModel, Packing, compression_steps, measure  # noqa: E402
from athermal.analysis.fitting import fit_power_law  # noqa: E402
from athermal.analysis.modes import plateau_edge, vibrational_modes  # noqa: E402
from athermal.errors import ConvergenceError, InputError  # noqa: E402
from athermal.protocols import isostatic_z  # noqa: E402
from athermal.studies.experiments import JamSpec, jam_packing  # noqa: E402
from benchmarks.machine import ROOT, pin, save  # noqa: E402

DELTA_PHIS = [1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1]
"""The Delta phi of ``docs/modes.md``'s table (``athermal compress --from 1e-6 --to 1e-1
--per-decade 1``)."""
MIN_MODES = 3
"""omega* is resolved where at least this many modes lie below it on every seed."""


def _worker(cores: Any) -> None:
    """Pin this worker to a core of its own, taken from the queue ``cores``."""
    pin(cores.get())


def spectrum_row(packing: Packing, model: ContactModel) -> dict[str, Any]:
    """omega* and what goes with it, from the full spectrum of ``packing`` (``error`` where
    there is none: an unjammed state, every particle a rattler)."""
    try:
        found = vibrational_modes(packing, model)
    except InputError as exc:
        return {"error": str(exc)}
    omega = found.frequencies
    edge = plateau_edge(omega)
    return {
        "omega_star": edge.omega_star,
        "omega_star_err": edge.error,
        "omega_star_modes": edge.modes_below,
        "plateau_density": edge.plateau,
        "modes": edge.modes,
        "lowest_frequency": float(omega[0]),
        "zero_modes": found.zero_modes,
        "negative_modes": found.negative_modes,
        "n_rattlers": found.n_rattlers,
    }


def one_run(job: tuple[int, int, list[float], float | None]) -> list[dict[str, Any]]:
    """Jam start ``seed`` of ``n`` disks, compress it through ``delta_phis`` and return one row
    per state (the jammed packing first, ``delta_phi`` 0)."""
    n, seed, delta_phis, epsilon = job
    spec = JamSpec(n=n) if epsilon is None else JamSpec(n=n, epsilon=epsilon)
    model = spec.model
    t0 = time.perf_counter()
    head = {"n": n, "seed": seed}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            jammed = jam_packing(spec, seed)
        except ConvergenceError as exc:  # reported in the table, not a crash of the study
            return [{**head, "delta_phi": 0.0, "error": str(exc)}]
        obs = measure(jammed.packing, model)
        live = n - obs.n_rattlers
        rows = [
            {
                **head,
                "delta_phi": 0.0,
                "phi_c": jammed.phi_c,
                "phi": jammed.packing.phi,
                "z_excess": obs.z - isostatic_z(live, spec.dim) if live else float("nan"),
                "events": [],
                "seconds": jammed.seconds,
                **spectrum_row(jammed.packing, model),
            }
        ]
        try:
            for step in compression_steps(
                jammed.packing, model, phi_c=jammed.phi_c, delta_phis=delta_phis
            ):
                rows.append(
                    {
                        **head,
                        "delta_phi": step.delta_phi,
                        "phi_c": jammed.phi_c,
                        "phi": step.phi,
                        "z_excess": step.z_excess,
                        "events": list(step.events),
                        "seconds": step.seconds,
                        **spectrum_row(step.packing, model),
                    }
                )
        except ConvergenceError as exc:
            rows.append({**head, "delta_phi": delta_phis[len(rows) - 1], "error": str(exc)})
    rows[0]["warnings"] = [str(w.message) for w in caught]
    rows[0]["run_seconds"] = time.perf_counter() - t0
    return rows


def resolved(group: list[dict[str, Any]], seeds: list[int], min_modes: int) -> bool:
    """Whether omega* is resolved on every seed of ``group`` (one N and Delta phi > 0)."""
    return sorted(r["seed"] for r in group) == sorted(seeds) and all(
        "error" not in r and r["omega_star_modes"] >= min_modes and "unjammed" not in r["events"]
        for r in group
    )


def summarize(
    rows: list[dict[str, Any]], seeds: list[int], min_modes: int
) -> tuple[str, dict[str, Any]]:
    """The markdown tables of ``rows`` and the fits per N."""
    lines = [
        f"| N | Delta phi | seeds {', '.join(map(str, seeds))}: omega* ± err (modes below) | "
        "mean | sd | err | err / sd | Delta z | resolved |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    fits: dict[str, Any] = {}
    good = [r for r in rows if "error" not in r]
    for n in sorted({r["n"] for r in rows}):
        dphis = sorted({r["delta_phi"] for r in good if r["n"] == n})
        points: list[tuple[float, float, float]] = []  # (Delta phi, mean omega*, mean Delta z)
        for dphi in dphis:
            every = [r for r in rows if r["n"] == n and r["delta_phi"] == dphi]
            group = sorted((r for r in every if "error" not in r), key=lambda r: r["seed"])
            stars = np.array([r["omega_star"] for r in group])
            errs = np.array([r["omega_star_err"] for r in group])
            dz = np.array([r["z_excess"] for r in group])
            sd = float(stars.std(ddof=1)) if stars.size > 1 else float("nan")
            cells = ", ".join(
                f"{r['omega_star']:.3g} ± {r['omega_star_err']:.2g} ({r['omega_star_modes']})"
                + (" unjammed" if "unjammed" in r["events"] else "")
                for r in group
            ) + "".join(f", seed {r['seed']}: {r['error']}" for r in every if "error" in r)
            ok = dphi > 0 and resolved(every, seeds, min_modes)
            if ok:
                points.append((dphi, float(stars.mean()), float(dz.mean())))
            lines.append(
                f"| {n} | {'0 (jammed)' if dphi == 0 else f'{dphi:g}'} | {cells} | "
                f"{stars.mean():.3g} | {sd:.2g} | {errs.mean():.2g} | {errs.mean() / sd:.1f} | "
                f"{dz.mean():.3g} | {'yes' if ok else 'no'} |"
            )
        fit: dict[str, Any] = {"delta_phis": [p[0] for p in points]}
        if len(points) >= 3:
            x = np.array([p[0] for p in points])
            mean = fit_power_law(x, [p[1] for p in points])
            fit["mean"] = {"exponent": mean.exponent, "stderr": mean.stderr}
            per_seed = {}
            for seed in seeds:
                ys = [
                    r["omega_star"]
                    for r in good
                    if r["n"] == n and r["seed"] == seed and r["delta_phi"] in fit["delta_phis"]
                ]
                if len(ys) == len(x):
                    per_seed[seed] = fit_power_law(x, ys).exponent
            fit["per_seed"] = per_seed
            fit["z_excess_vs_delta_phi"] = fit_power_law(x, [p[2] for p in points]).exponent
            fit["omega_star_vs_z_excess"] = fit_power_law(
                [p[2] for p in points], [p[1] for p in points]
            ).exponent
        fits[str(n)] = fit
    out = ["\n".join(lines), ""]
    out.append(
        "| N | Delta phi fitted | omega* ~ Delta phi^b: b of the mean ± stderr | "
        "b per seed | Delta z ~ Delta phi^c: c | omega* ~ Delta z^b': b' |"
    )
    out.append("|---|---|---|---|---|---|")
    for n, fit in fits.items():
        span = (
            f"{min(fit['delta_phis']):g} ... {max(fit['delta_phis']):g} ({len(fit['delta_phis'])})"
            if fit["delta_phis"]
            else "-"
        )
        if "mean" not in fit:
            out.append(f"| {n} | {span} | - (fewer than 3 resolved) | - | - | - |")
            continue
        seeds_text = ", ".join(f"{s}: {b:.2f}" for s, b in fit["per_seed"].items())
        out.append(
            f"| {n} | {span} | {fit['mean']['exponent']:.3f} ± {fit['mean']['stderr']:.3f} | "
            f"{seeds_text} | {fit['z_excess_vs_delta_phi']:.2f} | "
            f"{fit['omega_star_vs_z_excess']:.2f} |"
        )
    return "\n".join(out), fits


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[256, 1024])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--delta-phis", type=float, nargs="+", default=DELTA_PHIS)
    parser.add_argument(
        "--epsilon", type=float, default=None, help="jamming's bracket (default JamSpec's)"
    )
    parser.add_argument(
        "--min-modes",
        type=int,
        default=MIN_MODES,
        help="modes below omega* on every seed for a Delta phi to enter the fit",
    )
    parser.add_argument("--workers", type=int, default=2, help="processes, one core each")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    delta_phis = sorted(args.delta_phis)
    jobs = [
        (n, seed, delta_phis, args.epsilon)
        for n in sorted(args.n, reverse=True)  # the largest first: the workers end together
        for seed in args.seeds
    ]
    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = []
    cores = sorted(os.sched_getaffinity(0))[: max(1, args.workers)]
    queue: Any = multiprocessing.Queue()
    for core in cores:
        queue.put(core)
    with multiprocessing.Pool(len(cores), initializer=_worker, initargs=(queue,)) as pool:
        for run in pool.imap_unordered(one_run, jobs):
            rows += run
            first = run[0]
            what = first.get("error") or (
                f"phi_c {first['phi_c']:.6f}, {len(run) - 1} states, "
                f"{first['run_seconds']:.1f} s; omega* "
                + ", ".join(f"{r.get('omega_star', float('nan')):.3g}" for r in run)
            )
            print(f"N {first['n']} seed {first['seed']}: {what}", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    table, fits = summarize(rows, args.seeds, args.min_modes)
    spec = JamSpec()
    epsilon = spec.epsilon if args.epsilon is None else args.epsilon
    markdown = (
        "# omega* against Delta phi (`athermal.analysis.modes.plateau_edge`)\n\n"
        f"{spec.dim}D bidisperse disks, alpha = {spec.alpha:g}, jammed by `JamSpec` defaults "
        f"(protocol {spec.protocol}, epsilon {epsilon:g}) from seeds "
        f"{', '.join(map(str, args.seeds))}, compressed from each packing's phi_c to Delta phi "
        f"= {', '.join(f'{d:g}' for d in delta_phis)}; omega* ± bootstrap error (modes below "
        "omega*) of each state's full spectrum. mean, sd: over seeds; err: mean bootstrap error; "
        "Delta z = z - z_iso (non-rattlers), mean over seeds. Resolved: at least "
        f"{args.min_modes} modes below omega* on every seed, no state unjammed; the exponents "
        "are fitted at the resolved Delta phi (at least 3).\n\n"
        f"{table}\n\n{len(jobs)} runs, {sum('error' not in r for r in rows)} spectra, "
        f"{wall:.0f} s wall on {len(cores)} worker(s).\n"
    )
    save(
        args.output_dir,
        "omega_star",
        {
            "arguments": {
                "n": args.n,
                "seeds": args.seeds,
                "delta_phis": delta_phis,
                "epsilon": epsilon,
                "min_modes": args.min_modes,
                "workers": len(cores),
            },
            "wall_seconds": wall,
            "fits": fits,
            "rows": rows,
        },
        markdown,
    )
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
