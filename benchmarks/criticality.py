"""The critical exponents of weak forces and small gaps at jamming, over certified packings.

For each N, packings of seeds ``0 .. K-1`` are jammed
(:func:`athermal.studies.experiments.jam_packing`: ``--dim`` 2 or 3, one for all N or one
per N, bidisperse, alpha = 2, ``ohern``, to ``--epsilon`` or, below float64's resolution, to
1e-7 as ``jam --certify`` does: ``float64_epsilon``; packings cached before 2026-12-07 were
jammed to 1e-6 first, the same float64 trials stopped earlier) and certified
(:func:`athermal.certify.certify`); each certified packing is kept as a GSD file in the cache
directory, each refusal as a text file (a rerun reuses both). Their forces and gaps are pooled
(:func:`athermal.certify.criticality.weak_forces_and_gaps`) and ``theta_e``, ``theta_l`` and
``gamma`` fitted over the default windows and over a scan of others, so that the dependence
on the window is shown beside the value; ``gamma`` also a decade at a time along the gaps
(:func:`~athermal.certify.criticality.local_exponents`), and every error also by resampling
the packings (:func:`~athermal.certify.criticality.packing_bootstrap`). With ``--epsilon E``
below 1e-9 each jamming point is bracketed to E in double-double (``bisect_jamming_point``)
and the certified packing at its jammed bound is taken. Run from the repository root::

    python -m benchmarks.criticality --n 1024 --packings 120
    python -m benchmarks.criticality --n 1024 4096 --packings 120 30
    python -m benchmarks.criticality --n 1024 --packings 120 --epsilon 1e-12
    python -m benchmarks.criticality --dim 3 --n 1024 4096 --packings 150 8 --epsilon 1e-12
    python -m benchmarks.criticality --dim 2 3 --n 1024 1024 --packings 300 150 --epsilon 1e-12

Results: ``benchmarks/results/criticality<tag>.md`` and ``.json``, the figures
``docs/figures/criticality_n<N><tag>.png`` and ``gap_exponent<tag>.png``, where the tag is
``_d3`` when every N is 3D, ``_d2d3`` when both dimensions run, and ends in ``_epsE`` with
``--epsilon E``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from athermal.atomic import write_text
from athermal.certify import certify
from athermal.certify.bisection import bisect_jamming_point, float64_epsilon
from athermal.certify.criticality import (
    FORCE_WINDOW,
    GAMMA,
    GAP_WINDOW,
    THETA_E,
    critical_exponents,
    fit_truncated_power_law,
    local_exponents,
    packing_bootstrap,
    weak_forces_and_gaps,
)
from athermal.errors import ConvergenceError, InputError
from athermal.io import read_gsd, write_gsd
from athermal.protocols import EPSILON, RESOLUTION
from athermal.studies.experiments import JamSpec, jam_packing
from athermal.studies.plot import criticality_figure, gap_exponent_figure, save
from benchmarks.machine import ROOT, pin
from benchmarks.machine import save as save_results

FORCE_SCAN = ((1e-3, 1e-1), (3e-3, 1e-1), (1e-2, 1e-1), (1e-3, 3e-2), (1e-4, 1e-1))
GAP_SCAN = ((1e-5, 1e-2), (1e-4, 1e-2), (1e-3, 1e-2), (1e-4, 1e-3), (1e-3, 3e-2))
LOCAL_WINDOW = (1e-6, 1e-1)
"""The range of ``h`` over which the local gap exponent is fitted, a decade at a time."""
BOOTSTRAP_DRAWS = 200


def packings(
    n: int, count: int, cache: Path, epsilon: float = EPSILON, dim: int = 2
) -> tuple[list[Path], list[str]]:
    """The certified packings of ``n`` particles in ``dim`` dimensions of seeds
    ``0 .. count-1``, made where missing (bracketed to ``epsilon`` in double-double below
    float64's resolution); the refusals, each kept beside the packings as ``pNNNN.refused``
    so that a rerun does not make it again."""
    cache.mkdir(parents=True, exist_ok=True)
    spec, files, refused = JamSpec(n=n, dim=dim, epsilon=float64_epsilon(epsilon)), [], []
    for seed in range(count):
        path, refusal = cache / f"p{seed:04d}.gsd", cache / f"p{seed:04d}.refused"
        if refusal.exists():
            refused.append(refusal.read_text())
            continue
        if not path.exists():
            jammed = jam_packing(spec, seed)
            phi_c = jammed.phi_c
            reason = None
            try:
                if epsilon < RESOLUTION:
                    point = bisect_jamming_point(jammed.packing, spec.model, epsilon)
                    done, phi_c = point.jammed, point.phi_high
                else:
                    done = certify(jammed.packing, spec.model)
                if not done.certificate.converged:
                    balance = done.certificate.relative_force_balance
                    reason = f"not certified (force balance {balance:.1e})"
            except (InputError, ConvergenceError) as exc:
                reason = str(exc)
            if reason is not None:
                refused.append(f"seed {seed}: {reason}")
                write_text(refusal, refused[-1])
                continue
            write_gsd(
                path,
                done.packing,
                model=spec.model,
                seed=seed,
                position_lo=done.position_lo,
                observables={**done.certificate.log(), "phi_c": phi_c},
            )
            print(f"N {n} seed {seed}: {done.certificate.relative_force_balance:.1e}", flush=True)
        files.append(path)
    return files, refused


def study(n: int, files: list[Path], figure: Path) -> tuple[dict[str, Any], list[Any]]:
    """The exponents of one N at the default windows, over the scans and a decade at a
    time along the gaps, with errors from resampling the packings; the samples."""
    samples, balances, below = [], [], []
    for path in files:
        frame = read_gsd(path)
        samples.append(weak_forces_and_gaps(frame.packing, frame.model, frame.position_lo))
        balances.append(float(frame.log["certificate_relative_force_balance"][()]))
        linear = float(frame.log["certificate_linear_phi_c"][()])
        below.append(float(frame.log["phi_c"][()]) - linear)
    found = critical_exponents(samples)
    save(criticality_figure(samples, found, title=f"N = {n}, {len(samples)} packings"), figure)
    f = np.concatenate([s.forces for s in samples])
    loc = np.concatenate([s.localized for s in samples])
    gaps = np.concatenate([s.gaps for s in samples])
    near = np.concatenate([s.gap_localized for s in samples])
    scan = {
        "theta_e": [_fit(f[~loc], w, +1) for w in FORCE_SCAN],
        "theta_l": [_fit(f[loc], w, +1) for w in FORCE_SCAN],
        "gamma": [_fit(gaps, w, -1) for w in GAP_SCAN],
        "gamma, gaps of no buckler": [_fit(gaps[~near], w, -1) for w in GAP_SCAN[:1]],
    }
    local = [
        [*f.window, 1.0 - f.a, f.stderr, f.points] for f in local_exponents(gaps, LOCAL_WINDOW, 1)
    ]
    draws = BOOTSTRAP_DRAWS
    resampled = {
        "theta_e": packing_bootstrap(samples, lambda s: critical_exponents(s).theta_e, draws),
        "gamma": packing_bootstrap(samples, lambda s: critical_exponents(s).gamma, draws),
        "local": [
            packing_bootstrap(samples, lambda s, w=(low, high): _pooled_gamma(s, w), draws)
            for low, high, *_ in local
        ],
    }
    return {
        "n": n,
        "packings": len(samples),
        "relative_force_balance_max": max(balances),
        "theta_e": [found.theta_e, found.theta_e_err, found.extended.points],
        "theta_l": [found.theta_l, found.theta_l_err, found.localized.points],
        "gamma": [found.gamma, found.gamma_err, found.gap.points],
        "all_forces": _fit(f, FORCE_WINDOW, +1)[2:],
        "localized_fraction": float(loc.mean()),
        "touching": sum(s.touching for s in samples),
        "gaps_below_1e-8": int(np.sum(gaps < 1e-8)),
        "phi_c_minus_linear": [min(below), max(below)],
        "scan": scan,
        "local_gamma": [[*row, err] for row, err in zip(local, resampled["local"], strict=True)],
        "bootstrap": {"theta_e": resampled["theta_e"], "gamma": resampled["gamma"]},
        "non_rattlers": sum(s.n_live for s in samples),
        "figure": figure.name,
    }, samples


def _pooled_gamma(samples: Any, window: tuple[float, float]) -> float:
    return 1.0 - fit_truncated_power_law(np.concatenate([s.gaps for s in samples]), window).a


def _fit(values: Any, window: tuple[float, float], sign: int) -> list[float]:
    fit = fit_truncated_power_law(values, window)
    return [*window, sign * (fit.a - 1.0), fit.stderr, fit.points]


def report(results: list[dict[str, Any]], refused: list[str], epsilon: float = EPSILON) -> str:
    """The markdown: per N the exponents at the default windows, then the window scans and the
    local gap exponent."""
    lines = [
        "# Weak forces and small gaps at jamming (bidisperse, alpha = 2, certified packings)",
        "",
        f"Jamming points bracketed to epsilon = {epsilon:g}"
        + (" in double-double." if epsilon < RESOLUTION else " in float64."),
        "",
        f"Default windows: f / <f> in {FORCE_WINDOW}, h in {GAP_WINDOW}. Mean field: theta_e "
        f"= {THETA_E}, gamma = {GAMMA}.",
        "",
        "| d | N | packings | worst force balance / <f> | theta_e | theta_l | gamma | all forces "
        "together: theta | contacts of bucklers |",
        "|---|---:|---:|---:|---|---|---|---|---:|",
    ]
    for r in results:
        fits = (r[k] for k in ("theta_e", "theta_l", "gamma"))
        cells = [f"{v:.3f} ± {e:.3f} ({p})" for v, e, p in fits]
        lines.append(
            f"| {r['dim']} | {r['n']} | {r['packings']} | {r['relative_force_balance_max']:.1e} | "
            + " | ".join(cells)
            + f" | {r['all_forces'][0]:.3f} ± {r['all_forces'][1]:.3f} ({r['all_forces'][2]:.0f})"
            + f" | {100 * r['localized_fraction']:.0f}% |"
        )
    lines += [
        "",
        "Gaps are taken at each packing's jamming point (the packing expanded to it by its linear"
        " response); pairs that touch there (the pressure made their gap) are counted apart.",
        "",
        "| d | N | pairs touching at phi_c (per packing) | gaps below 1e-8 at phi_c | phi_c - "
        "linear-response phi_c |",
        "|---|---:|---:|---:|---|",
    ]
    for r in results:
        low, high = r["phi_c_minus_linear"]
        lines.append(
            f"| {r['dim']} | {r['n']} | {r['touching']} ({r['touching'] / r['packings']:.2f}) | "
            f"{r['gaps_below_1e-8']} | {low:.1e} ... {high:.1e} |"
        )
    lines += [
        "",
        "Errors above: the Fisher information of the pooled fit. Resampling the packings "
        f"({BOOTSTRAP_DRAWS} draws with replacement), which counts the values of one packing as "
        "correlated:",
        "",
        "| d | N | theta_e | gamma |",
        "|---|---:|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r['dim']} | {r['n']} | {r['theta_e'][0]:.3f} ± {r['bootstrap']['theta_e']:.3f} | "
            f"{r['gamma'][0]:.3f} ± {r['bootstrap']['gamma']:.3f} |"
        )
    lines += [
        "",
        "## The gap exponent along the gaps",
        "",
        "gamma fitted over a decade at a time: value ± Fisher error / resampled error "
        "(gaps in the window, per packing).",
        "",
        "| h | " + " | ".join(f"{r['dim']}D, N = {r['n']}" for r in results) + " |",
        "|---|" + "---|" * len(results),
    ]
    windows = sorted({(row[0], row[1]) for r in results for row in r["local_gamma"]})
    for low, high in windows:
        cells = []
        for r in results:
            row = next((x for x in r["local_gamma"] if (x[0], x[1]) == (low, high)), None)
            cells.append(
                "-"
                if row is None
                else f"{row[2]:.3f} ± {row[3]:.3f} / {row[5]:.3f} ({row[4] / r['packings']:.1f})"
            )
        lines.append(f"| {low:.1e} ... {high:.1e} | " + " | ".join(cells) + " |")
    lines += ["", "## The exponents against the window", ""]
    lines += [
        "| d | N | exponent | window | value ± stderr (points) |",
        "|---|---:|---|---|---|",
    ]
    for r in results:
        for name, rows in r["scan"].items():
            for low, high, value, err, points in rows:
                lines.append(
                    f"| {r['dim']} | {r['n']} | {name} | {low:g} ... {high:g} | "
                    f"{value:.3f} ± {err:.3f} ({points:.0f}) |"
                )
    if refused:
        lines += ["", "Refused by certify:", "", *[f"- {r}" for r in refused]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[1024])
    parser.add_argument("--packings", type=int, nargs="+", default=[120])
    parser.add_argument("--dim", type=int, nargs="+", default=[2], help="one for all, or per N")
    parser.add_argument("--cache", type=str, nargs="+", default=None, help="one folder per N")
    parser.add_argument("--output-dir", type=str, default=str(ROOT / "benchmarks" / "results"))
    parser.add_argument("--figure-dir", type=str, default=str(ROOT / "docs" / "figures"))
    parser.add_argument("--epsilon", type=float, default=EPSILON)
    args = parser.parse_args(argv)
    dims = args.dim * len(args.n) if len(args.dim) == 1 else args.dim
    if len(dims) != len(args.n) or not set(dims) <= {2, 3}:
        parser.error(f"--dim: 2 or 3, one for all or one per N, got {args.dim}")
    pin()
    output = Path(args.output_dir)
    Path(args.figure_dir).mkdir(parents=True, exist_ok=True)
    eps = "" if args.epsilon == EPSILON else f"_eps{args.epsilon:g}"
    tags = [("" if d == 2 else f"_d{d}") + eps for d in dims]
    tag = {(2,): "", (3,): "_d3"}.get(tuple(sorted(set(dims))), "_d2d3") + eps
    caches = args.cache or [
        str(ROOT / "benchmarks" / "cache" / f"criticality_n{n}{t}")
        for n, t in zip(args.n, tags, strict=True)
    ]
    results, refused, series = [], [], {}
    for n, d, count, cache, t in zip(args.n, dims, args.packings, caches, tags, strict=True):
        files, no = packings(n, count, Path(cache), args.epsilon, d)
        refused += [f"{d}D N {n}, {r}" for r in no]
        found, samples = study(n, files, Path(args.figure_dir) / f"criticality_n{n}{t}.png")
        results.append({"dim": d, **found})
        series[f"{d}D, N = {n} ({len(samples)} packings)"] = samples
    figure = gap_exponent_figure(
        series, LOCAL_WINDOW, per_decade=1, title="The gap exponent a decade at a time"
    )
    save(figure, Path(args.figure_dir) / f"gap_exponent{tag}.png")
    markdown = report(results, refused, args.epsilon) + "\n"
    data = {"epsilon": args.epsilon, "results": results, "refused": refused}
    save_results(output, f"criticality{tag}", data, markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
