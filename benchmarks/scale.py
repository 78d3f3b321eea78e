"""B4: scale — a Case 1+3 analogue on a tiled packing, N = 4096 to 1,048,576, four minimizers.

The start is made quickly, without relaxing a random packing: the relaxed N = 4096 Table
packing (:func:`athermal.studies.bench.reference_packing`) is tiled k x k into a box k times wider
(k = 1, 4, 8, 16: N = 4096, 65536, 262144, 1048576), which is a relaxed packing of the big box.
Its copies are identical, so the Table's Case 3 perturbation breaks the symmetry (every
coordinate displaced by U[-a, a], a = 1e-4 mean diameters, ``default_rng(20240601)``) and Case
1's radii growth x (1 + 5e-5) follows (both by :func:`athermal.studies.bench.make_case`). k = 1
uses the same recipe, so the growth with N is measured on one definition.

L-BFGS, P-L-BFGS (Exp) with the direct, the AMG and the incomplete-Cholesky (``ic0``) solver, and
FIRE relax each start to ``max_i |grad_i| <= 1e-9 F0`` (``RTOL``; F0: mean contact force at the
start). Each (N, method) runs in its own subprocess (``--one K METHOD``), so the peak RSS is that
run's own; a warm-up on the N = 4096 start (3 iterations) compiles the kernels first. Reported:
iterations, evaluations, seconds, ms per iteration, final max|grad| / F0, peak RSS, preconditioner
builds, the setup time (tiling + Objective), and the exponent b of iterations ~ N^b (least squares
in log-log over the N that converged), checked against the issue's targets (P-L-BFGS: b <= 0.25
from 4096 to 10^6; <= 0.5 s per iteration and <= 4 GB at 10^6 on one core).

    python -m benchmarks.scale              # k = 1 4 8 16, all methods (about 1 hour 50
                                            # minutes; the N = 10^6 rows take 13-30 each)
    python -m benchmarks.scale --quick      # smoke test: k = 1 and 4 (about 3 minutes)
    python -m benchmarks.scale --limit 16 amg 600 --reuse old.json   # one row capped at 600
                                            # iterations; rows already in old.json not rerun

Results: ``benchmarks/results/scale.md`` and ``scale.json`` (rewritten after every row).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from datetime import UTC, datetime
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from athermal.engines.precon import make_preconditioner
from athermal.model.cell import Cell
from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.model.packing import Packing
from athermal.relaxation import RTOL, Minimizer, minimize_objective
from athermal.studies.bench import make_case, reference_packing
from benchmarks.machine import ROOT, pin, save

METHODS = {
    "lbfgs": Minimizer("lbfgs"),
    "direct": Minimizer("lbfgs", "exp", solver="direct"),
    "amg": Minimizer("lbfgs", "exp", solver="amg"),
    "ic0": Minimizer("lbfgs", "exp", solver="ic0"),
    "fire": Minimizer("fire"),
}
"""``--methods`` keys and the minimizers they run."""
PRECONDITIONED = ("direct", "amg", "ic0")
SIZES = (1, 4, 8, 16)
"""Tiling factors k (N = 4096 k^2)."""
TARGET_EXPONENT, TARGET_MS, TARGET_MB, TARGET_N = 0.25, 500.0, 4096.0, 1_048_576


def tiled(alpha: float, k: int) -> Packing:
    """The relaxed N = 4096 Table packing tiled k x k into a box k times wider."""
    base = reference_packing(alpha)
    s = base.cell.fractional(base.positions)
    inside = base.cell.cartesian(s - np.floor(s))
    grid = np.stack(np.meshgrid(np.arange(k), np.arange(k), indexing="ij"), -1).reshape(-1, 2)
    shifts = grid @ base.cell.h.T
    positions = (shifts[:, None, :] + inside[None, :, :]).reshape(-1, 2)
    return Packing(positions, np.tile(base.radii, k * k), Cell.box(k * base.cell.widths))


def start_packing(alpha: float, k: int) -> Packing:
    """Case 1+3 analogue: ``tiled`` with Case 3's displacements, then Case 1's growth."""
    return make_case(make_case(tiled(alpha, k), 3), 1)


def peak_mb() -> float:
    """Peak resident set size of this process so far (MB; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_one(k: int, key: str, alpha: float, maxiter: int) -> dict[str, Any]:
    """One (k, method) relaxation in this process: its row."""
    how, model = METHODS[key], ContactModel(alpha)

    def relax(objective: Objective, limit: int) -> tuple[Any, Any]:
        # as athermal.relaxation.relax_objective, keeping the preconditioner for its counters
        pre = make_preconditioner(how.precon, objective, A=how.A, solver=how.solver)
        res = minimize_objective(
            objective, how.method, precon=pre or "none", rtol=RTOL, maxiter=limit, A=how.A
        )
        return res, pre

    relax(Objective(start_packing(alpha, 1), model), 3)  # warm-up: compile, import solvers
    t0 = time.perf_counter()
    objective = Objective(start_packing(alpha, k), model)
    setup = time.perf_counter() - t0
    setup_mb = peak_mb()
    f0 = objective.mean_contact_force(objective.x0)
    g0 = objective.max_gradient(objective(objective.x0)[1])
    contacts = objective.count_contacts(objective.x0)
    t0, c0 = time.perf_counter(), time.process_time()
    res, pre = relax(objective, maxiter)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {
        "k": k,
        "n": objective.n,
        "key": key,
        "method": how.name,
        "iterations": res.iterations,
        "evaluations": res.evaluations,
        "seconds": seconds,
        "ms_per_iteration": 1e3 * seconds / max(res.iterations, 1),
        "cpu_seconds": cpu,
        "cpu_ms_per_iteration": 1e3 * cpu / max(res.iterations, 1),
        "converged": bool(res.converged),
        "status": str(res.status),
        "grad_over_f0": res.max_gradient / f0,
        "peak_rss_mb": peak_mb(),
        "setup_rss_mb": setup_mb,
        "setup_seconds": setup,
        "f0": f0,
        "start_grad_over_f0": g0 / f0,
        "contacts": contacts,
        "phi": objective.packing(objective.x0).phi,
        "neighbor_rebuilds": res.neighbor_rebuilds,
        "precon_builds": res.precon_builds,
        "precon_seconds": getattr(pre, "build_seconds", None),
        "factorize_seconds": getattr(pre, "factorize_seconds", None),
        "backend": getattr(pre, "backend", None),
        "maxiter": maxiter,
        "date_utc": datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S"),
    }


def child(k: int, key: str, alpha: float, maxiter: int) -> dict[str, Any]:
    """Run ``--one k key`` in a fresh interpreter (same core) and return its JSON row."""
    cmd = [sys.executable, "-m", "benchmarks.scale", "--one", str(k), key, "--alpha", f"{alpha!r}"]
    proc = subprocess.run(
        [*cmd, "--maxiter", str(maxiter)],
        stdout=subprocess.PIPE,
        text=True,
        check=False,
        cwd=ROOT,  # where the benchmarks package is
    )
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        error = f"exit status {proc.returncode}"
        return {"k": k, "n": 4096 * k * k, "key": key, "method": METHODS[key].name, "error": error}
    return json.loads(lines[-1])


def exponent(rows: list[dict[str, Any]], key: str) -> tuple[float | None, list[int]]:
    """Least-squares slope of log(iterations) vs log(N) over the converged rows of ``key``."""
    pts = sorted((r["n"], r["iterations"]) for r in rows if r["key"] == key and r.get("converged"))
    if len(pts) < 2:
        return None, [n for n, _ in pts]
    n, it = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(n, it, 1)[0]), [p[0] for p in pts]


def verdicts(rows: list[dict[str, Any]], fits: dict[str, Any]) -> list[str]:
    """The issue's targets, one line each, for the preconditioned rows."""
    out = []
    for key in (key for key in PRECONDITIONED if key in fits):
        name = METHODS[key].name
        mine = {r["n"]: r for r in rows if r["key"] == key and "error" not in r}
        b, used = fits.get(key, (None, []))
        if b is not None and 4096 in used and TARGET_N in used:
            ratio = mine[TARGET_N]["iterations"] / mine[4096]["iterations"]
            ok = b <= TARGET_EXPONENT and ratio <= (TARGET_N / 4096) ** TARGET_EXPONENT
            out.append(
                f"- {name}: iterations ~ N^{b:.3f} (4096 to {TARGET_N}: x{ratio:.2f}, "
                f"target N^{TARGET_EXPONENT} = x{(TARGET_N / 4096) ** TARGET_EXPONENT:.2f}): "
                f"{'PASS' if ok else 'FAIL'}"
            )
        else:
            out.append(f"- {name}: exponent target not judged (needs converged 4096 and 10^6)")
        if TARGET_N in mine:
            r = mine[TARGET_N]
            ms_ok, mb_ok = r["ms_per_iteration"] <= TARGET_MS, r["peak_rss_mb"] <= TARGET_MB
            out.append(
                f"- {name} at N = {TARGET_N}: {r['ms_per_iteration']:.0f} ms / iteration "
                f"(target <= {TARGET_MS:.0f}): {'PASS' if ms_ok else 'FAIL'}; peak RSS "
                f"{r['peak_rss_mb']:.0f} MB (target <= {TARGET_MB:.0f}): "
                f"{'PASS' if mb_ok else 'FAIL'}"
                + ("" if r["converged"] else " (run not converged)")
            )
    return out


def report(rows: list[dict[str, Any]], args: argparse.Namespace, todo: int) -> str:
    """The markdown of the rows done so far."""
    ok = [r for r in rows if "error" not in r]
    fits = {key: exponent(ok, key) for key in args.methods}
    lines = [
        f"# B4 — scale: Case 1+3 analogue on a tiled packing (alpha = {args.alpha:g})",
        "",
        "- start: the relaxed N = 4096 Table packing tiled k x k (box k x wider), every "
        "coordinate + U[-a, a] (a = 1e-4 mean diameters, default_rng(20240601)), radii "
        "x (1 + 5e-5); criterion max_i |grad_i| <= 1e-9 F0 (F0 at the start)",
        f"- each row in its own process, pinned to one core; maxiter {args.maxiter} unless "
        "the row says otherwise; peak RSS = ru_maxrss of that process (the interpreter and "
        "its imports alone: about 190 MB); ms / iteration = seconds / iterations (preconditioner "
        "builds included); P build s: preconditioner builds and factorizations",
    ]
    dates = sorted(r["date_utc"] for r in ok)
    if dates:
        lines.append(f"- rows run from {dates[0]} to {dates[-1]} UTC (each row's date: json)")
    if len(rows) < todo:
        lines.append(f"- PARTIAL: {len(rows)} of {todo} rows done")
    lines += [
        "",
        "| N | method | iterations | evaluations | seconds | ms / iteration | CPU ms / iteration "
        "| converged | max\\|grad\\| / F0 | peak RSS (MB) | P builds | P build s |",
        "|---:|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|",
    ]
    for r in sorted(rows, key=lambda r: (r["n"], list(METHODS).index(r["key"]))):
        if "error" in r:
            lines.append(f"| {r['n']} | {r['method']} | failed: {r['error']} ||||||||||")
            continue
        conv = "yes" if r["converged"] else f"no ({r['status']}, maxiter {r['maxiter']})"
        pre = r["precon_seconds"]
        lines.append(
            f"| {r['n']} | {r['method']} | {r['iterations']} | {r['evaluations']} | "
            f"{r['seconds']:.1f} | {r['ms_per_iteration']:.2f} | "
            f"{r['cpu_ms_per_iteration']:.2f} | {conv} | "
            f"{r['grad_over_f0']:.2e} | {r['peak_rss_mb']:.0f} | "
            f"{r['precon_builds'] if pre is not None else '-'} | "
            f"{f'{pre:.2f}' if pre is not None else '-'} |"
        )
    lines += [
        "",
        "| N | k | phi | contacts | F0 | start max\\|grad\\| / F0 | setup s "
        "| RSS after setup (MB) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in sorted({r["n"] for r in ok}):
        r = next(r for r in ok if r["n"] == n)  # the first child at this N
        lines.append(
            f"| {n} | {r['k']} | {r['phi']:.6f} | {r['contacts']} | {r['f0']:.4e} | "
            f"{r['start_grad_over_f0']:.3f} | {r['setup_seconds']:.3f} | "
            f"{r['setup_rss_mb']:.0f} |"
        )
    lines += ["", "Iterations ~ N^b (least squares in log-log over the converged N):", ""]
    for key in args.methods:
        b, used = fits[key]
        text = f"b = {b:.3f}" if b is not None else "not fitted (fewer than 2 converged N)"
        its = {r["n"]: r["iterations"] for r in ok if r["key"] == key and r["converged"]}
        local = [np.log(its[m] / its[n]) / np.log(m / n) for n, m in pairwise(used)]
        if len(local) > 1:
            text += " (between successive N: " + ", ".join(f"{x:.3f}" for x in local) + ")"
        lines.append(f"- {METHODS[key].name}: {text}; N used: {', '.join(map(str, used)) or '-'}")
    lines += ["", "Targets (issue):", "", *verdicts(ok, fits)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), help="k: N = 4096 k^2")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--maxiter", type=int, default=200_000)
    parser.add_argument(
        "--limit",
        nargs=3,
        action="append",
        default=[],
        metavar=("K", "METHOD", "MAXITER"),
        help="a lower maxiter for one row (repeatable)",
    )
    parser.add_argument(
        "--reuse",
        type=Path,
        help="an earlier scale.json: its rows (same alpha, k, method and maxiter) are kept",
    )
    parser.add_argument("--alpha", type=float, default=2.0)
    parser.add_argument("--quick", action="store_true", help="smoke test: k = 1 and 4")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--one", nargs=2, metavar=("K", "METHOD"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    pin()
    if args.one:
        row = run_one(int(args.one[0]), args.one[1], args.alpha, args.maxiter)
        print(json.dumps(row), flush=True)
        return 0
    if args.quick:
        args.sizes = [1, 4]
    limits = {(int(k), m): int(it) for k, m, it in args.limit}
    todo = [(k, m) for k in args.sizes for m in args.methods]
    old: dict[tuple[int, str, int], dict[str, Any]] = {}
    if args.reuse is not None:
        earlier = json.loads(args.reuse.read_text(encoding="utf-8"))
        if earlier["alpha"] == args.alpha:
            old = {(r["k"], r["key"], r["maxiter"]): r for r in earlier["rows"] if "error" not in r}
    rows: list[dict[str, Any]] = []
    for k, key in todo:
        t0, maxiter = time.perf_counter(), limits.get((k, key), args.maxiter)
        rows.append(old.get((k, key, maxiter)) or child(k, key, args.alpha, maxiter))
        r = rows[-1]
        print(
            f"N {r['n']:8d} {r['method']:22s} "
            + (
                f"it {r['iterations']:6d} ev {r['evaluations']:6d} {r['seconds']:8.1f} s "
                f"{r['ms_per_iteration']:8.2f} ms/it {r['peak_rss_mb']:7.0f} MB "
                f"{'ok' if r['converged'] else 'NOT CONVERGED'}"
                if "error" not in r
                else f"FAILED ({r['error']})"
            )
            + f" [child {time.perf_counter() - t0:.0f} s]",
            file=sys.stderr,
            flush=True,
        )
        data = {"alpha": args.alpha, "maxiter": args.maxiter, "rtol": RTOL, "rows": rows}
        save(args.output_dir, "scale", data, report(rows, args, len(todo)))
    print(report(rows, args, len(todo)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
