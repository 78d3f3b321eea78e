"""B1: the seed's Table — minimizers and preconditioners on the three benchmark cases.

Start configurations: ``shared/benchmarks/table1_N4096_alpha{2,2.5}.npz`` (copied into
``tests/data``): N = 4096 bidisperse disks at phi = 0.8438, relaxed. Cases (BENCHMARKS.md):
1. radii x (1 + 5e-5); 2. simple shear gamma = 1e-4 of positions and cell; 3. every coordinate
displaced by U[-a, a], a = 1e-4 x mean diameter, ``default_rng(20240601)``. Criterion for every
method: ``max_i |grad_i| <= 1e-9 F0``, F0 = mean contact force at the start of the case.
scipy's L-BFGS-B (m = 10) on the same compiled energy is the in-run reference.

Run from the repository root::

    python benchmarks/table1.py            # full table, median of 3 (tens of minutes)
    python benchmarks/table1.py --quick    # smoke test: case 3, alpha 2, three methods, 1 repeat

Results: ``benchmarks/results/table1.md`` and ``table1.json`` (written atomically).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import scipy
import scipy.optimize

from athermal.cell import Cell, simple_shear
from athermal.contact import ContactModel
from athermal.minimize import minimize
from athermal.objective import Objective
from athermal.packing import Packing

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
RTOL = 1e-9
# (label, method, precon, A)
METHODS = [
    ("L-BFGS", "lbfgs", "none", 0.0),
    ("P-L-BFGS (A=0)", "lbfgs", "exp", 0.0),
    ("P-L-BFGS (A=3)", "lbfgs", "exp", 3.0),
    ("FR-CG", "cg", "none", 0.0),
    ("P-FR-CG", "cg", "exp", 0.0),
    ("FIRE", "fire", "none", 0.0),
    ("contact P-L-BFGS", "lbfgs", "contact", 0.0),
    ("scipy L-BFGS-B", "scipy", "none", 0.0),
]
SEED_ITERATIONS = {  # the seed's own Table (alpha = 2.5, its hardware): cases 1 / 2 / 3
    "L-BFGS": (2003, 2749, 602),
    "P-L-BFGS (A=0)": (705, 986, 380),
    "P-L-BFGS (A=3)": (813, 1351, 432),
    "FR-CG": (4574, 7306, 940),
    "P-FR-CG": (1101, 2013, 528),
}


@dataclass
class Row:
    case: int
    alpha: float
    method: str
    iterations: int
    evaluations: int
    seconds: float
    energy: float
    grad_over_f0: float
    converged: bool


def load(alpha: float) -> Packing:
    ref = np.load(DATA / f"table1_N4096_alpha{alpha:g}.npz")
    return Packing(ref["positions"], ref["radii"], Cell.box(ref["box"]))


def make_case(packing: Packing, case: int) -> Packing:
    if case == 1:
        return packing.scale_radii(1.0 + 5e-5)
    if case == 2:
        return packing.deform(simple_shear(1e-4))
    a = 1e-4 * 2.0 * float(packing.radii.mean())
    rng = np.random.default_rng(20240601)
    return packing.with_positions(packing.positions + rng.uniform(-a, a, packing.positions.shape))


def run_scipy(objective: Objective, f0: float) -> tuple[int, int, float, float]:
    """scipy L-BFGS-B (m = 10) to the same criterion; returns iterations, evals, E, max|g|."""
    gtol = RTOL * f0 / np.sqrt(objective.dim)  # scipy's gtol bounds single components
    res = scipy.optimize.minimize(
        objective,
        objective.x0,
        jac=True,
        method="L-BFGS-B",
        options={"maxcor": 10, "gtol": gtol, "ftol": 0.0, "maxiter": 50_000, "maxfun": 100_000},
    )
    energy, grad = objective(res.x)
    return int(res.nit), int(res.nfev), energy, objective.max_gradient(grad)


def run_one(start: Packing, model: ContactModel, method: str, precon: str, a_param: float) -> Row:
    objective = Objective(start, model)
    f0 = objective.mean_contact_force(objective.x0)
    t0 = time.perf_counter()
    if method == "scipy":
        nit, nfev, energy, gmax = run_scipy(objective, f0)
        seconds = time.perf_counter() - t0
        return Row(0, model.alpha, "", nit, nfev, seconds, energy, gmax / f0, gmax <= RTOL * f0)
    res = minimize(objective, method, precon=precon, A=a_param, rtol=RTOL, maxiter=50_000)  # type: ignore[arg-type]
    seconds = time.perf_counter() - t0
    return Row(
        0,
        model.alpha,
        "",
        res.iterations,
        res.evaluations,
        seconds,
        res.energy,
        res.max_gradient / f0,
        res.converged,
    )


def bench(cases: list[int], alphas: list[float], labels: list[str], repeats: int) -> list[Row]:
    rows = []
    for alpha in alphas:
        base = load(alpha)
        model = ContactModel(alpha)
        for case in cases:
            start = make_case(base, case)
            for label, method, precon, a_param in METHODS:
                if label not in labels:
                    continue
                runs = [run_one(start, model, method, precon, a_param) for _ in range(repeats)]
                row = runs[0]
                row.case, row.method = case, label
                row.seconds = statistics.median(r.seconds for r in runs)
                rows.append(row)
                print(
                    f"alpha {alpha:g} case {case} {label:18s} it {row.iterations:6d} "
                    f"ev {row.evaluations:6d} {row.seconds:7.3f}s |g|/F0 {row.grad_over_f0:.2e} "
                    f"{'ok' if row.converged else 'NOT CONVERGED'}",
                    file=sys.stderr,
                    flush=True,
                )
    return rows


def markdown(rows: list[Row], meta: dict[str, str]) -> str:
    lines = ["# B1 — the seed's Table (N = 4096, phi = 0.8438)", ""]
    lines += [f"- {key}: {value}" for key, value in meta.items()]
    lines += [
        "",
        "| alpha | case | method | iterations | evaluations | seconds | s / scipy "
        "| final energy | max\\|grad\\| / F0 | converged | seed's iterations (alpha 2.5) |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    ref = {(r.alpha, r.case): r.seconds for r in rows if r.method == "scipy L-BFGS-B"}
    for r in rows:
        ratio = f"{r.seconds / ref[(r.alpha, r.case)]:.2f}" if (r.alpha, r.case) in ref else "-"
        seed = SEED_ITERATIONS.get(r.method, ("-",) * 3)[r.case - 1]
        lines.append(
            f"| {r.alpha:g} | {r.case} | {r.method} | {r.iterations} | {r.evaluations} | "
            f"{r.seconds:.3f} | {ratio} | {r.energy:.10e} | {r.grad_over_f0:.2e} | "
            f"{'yes' if r.converged else 'no'} | {seed} |"
        )
    return "\n".join(lines) + "\n"


def write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as handle:
        handle.write(text)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def machine() -> dict[str, str]:
    cpu = "unknown"
    if Path("/proc/cpuinfo").exists():
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            cwd=ROOT,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    pinned = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else "n/a"
    return {
        "date (UTC)": datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S"),
        "commit": commit,
        "machine": f"{cpu}, {os.cpu_count()} cores, process pinned to {pinned}",
        "software": f"python {platform.python_version()}, numpy {np.__version__}, "
        f"scipy {scipy.__version__}",
        "criterion": f"max_i |grad_i| <= {RTOL:g} F0 (F0: mean contact force at the start)",
        "timing": "median wall time of the repeats; iterations/evaluations of the first",
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", type=int, nargs="+", default=[1, 2, 3], choices=(1, 2, 3))
    parser.add_argument("--alphas", type=float, nargs="+", default=[2.0, 2.5])
    parser.add_argument(
        "--methods", nargs="+", default=[m[0] for m in METHODS], help="labels of the methods to run"
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="smoke test (seconds)")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    if args.quick:
        args.cases, args.alphas, args.repeats = [3], [2.0], 1
        args.methods = ["L-BFGS", "P-L-BFGS (A=0)", "scipy L-BFGS-B"]
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    rows = bench(args.cases, args.alphas, args.methods, args.repeats)
    meta = machine()
    text = markdown(rows, meta)
    write_atomic(args.output_dir / "table1.md", text)
    write_atomic(
        args.output_dir / "table1.json",
        json.dumps({"meta": meta, "rows": [asdict(r) for r in rows]}, indent=1),
    )
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
