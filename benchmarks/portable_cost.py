"""The cost of same input, same bits: the paper's Table and ``jam`` with this tree's portable build
against the native build it replaced, in one run on one machine (issue 50, item 3).

The native build is a commit before the change (``--native``, default ``74effeb``: numba kernels
with ``fastmath`` — contraction into fused multiply-adds, reductions reordered to the CPU's vector
width — and BLAS dot products), checked out into a temporary git worktree. Each build runs in its
own subprocess with its own fresh numba cache (compiled once, untimed, by a warm-up), pinned to
one core:

1. the Table (:func:`athermal.studies.bench.table1`, alpha 2 and 2.5, cases 1-3, the methods below),
   median of ``--repeats``;
2. ``jam`` of ``random_packing(N, 0.8, seed)`` at N = 1024 and 4096 (harmonic, the defaults).

The two builds take different trajectories (their rounding differs), so their iteration counts
differ; the table gives each build's seconds and iterations and the ratio of seconds per
evaluation (the cost of the arithmetic) besides the ratio of seconds.

Run from the repository root::

    python -m benchmarks.portable_cost            # about 10 minutes
    python -m benchmarks.portable_cost --quick    # smoke test: case 3, alpha 2, N = 256

Results: ``benchmarks/results/portable_cost.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
"""The repository (as :data:`benchmarks.machine.ROOT`, which this module imports only once the
build it measures is loaded: :mod:`benchmarks.machine` imports athermal)."""
NATIVE = "74effeb"
"""The last commit whose kernels ran with ``fastmath`` and whose dot products were BLAS's."""
METHODS = ("L-BFGS", "P-L-BFGS", "FR-CG", "P-FR-CG", "FIRE")


def load_tree(src: Path) -> None:
    """Make ``import athermal`` load the package in ``src`` (a worktree's ``src/``), before any
    module of it is imported: the subprocess measures that build, not the installed one."""
    init = src / "athermal" / "__init__.py"
    spec = importlib.util.spec_from_file_location(
        "athermal", init, submodule_search_locations=[str(init.parent)]
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["athermal"] = module
    spec.loader.exec_module(module)


def child(src: Path, quick: bool, repeats: int) -> dict[str, Any]:
    """The measurements of the build in ``src`` (run in the subprocess)."""
    load_tree(src)
    import athermal as at
    from athermal.studies.bench import table1
    from benchmarks.machine import pin

    pin(0)
    cases, alphas = ((3,), (2.0,)) if quick else ((1, 2, 3), (2.0, 2.5))
    methods = ("L-BFGS", "P-L-BFGS") if quick else METHODS
    sizes = (256,) if quick else (1024, 4096)
    table1(cases[:1], alphas[:1], methods[:1], repeats=1)  # compiles, untimed
    rows = [
        {
            "case": r.case,
            "alpha": r.alpha,
            "method": r.method,
            "iterations": r.iterations,
            "evaluations": r.evaluations,
            "seconds": r.seconds,
        }
        for r in table1(cases, alphas, methods, repeats=repeats)
    ]
    model = at.ContactModel(2.0)
    at.jam(at.random_packing(64, 0.8, seed=1), model)  # compiles, untimed
    jams = []
    for n in sizes:
        start = at.random_packing(n, 0.8, seed=1)
        t0 = time.perf_counter()
        result = at.jam(start, model)
        seconds = time.perf_counter() - t0
        jams.append(
            {
                "n": n,
                "phi_c": result.phi_c,
                "iterations": result.iterations,
                "evaluations": result.evaluations,
                "seconds": seconds,
            }
        )
    return {"table": rows, "jam": jams}


def measure(src: Path, quick: bool, repeats: int) -> dict[str, Any]:
    """Run :func:`child` on the tree whose package lies in ``src``, in a subprocess."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        argv = [sys.executable, "-m", "benchmarks.portable_cost", "--child", str(src)]
        argv += ["--repeats", str(repeats)]
        if quick:
            argv.append("--quick")
        done = subprocess.run(argv, env=env, cwd=ROOT, capture_output=True, text=True, check=True)
    return dict(json.loads(done.stdout.splitlines()[-1]))


def _row(label: str, a: dict[str, Any], b: dict[str, Any], digits: int) -> str:
    """One markdown row: ``label``, the native run ``a`` against the portable run ``b``."""
    per = (b["seconds"] / b["evaluations"]) / (a["seconds"] / a["evaluations"])
    return (
        f"| {label} | {a['iterations']} | {a['seconds']:.{digits}f} | {b['iterations']} | "
        f"{b['seconds']:.{digits}f} | {b['seconds'] / a['seconds']:.2f} | {per:.2f} |"
    )


def ratio_rows(native: dict[str, Any], portable: dict[str, Any]) -> list[str]:
    """Markdown rows: each Table row and jam, native against portable."""
    table = [
        _row(f"Table alpha {a['alpha']:g} case {a['case']} {a['method']}", a, b, 3)
        for a, b in zip(native["table"], portable["table"], strict=True)
    ]
    jams = [
        _row(f"jam N = {a['n']} seed 1", a, b, 2)
        for a, b in zip(native["jam"], portable["jam"], strict=True)
    ]
    return table + jams


def summary(native: dict[str, Any], portable: dict[str, Any]) -> str:
    """The Table's totals: seconds, and seconds per evaluation, portable over native."""

    def total(run: dict[str, Any], key: str) -> float:
        return float(sum(r[key] for r in run["table"]))

    seconds = total(portable, "seconds") / total(native, "seconds")
    per = seconds * total(native, "evaluations") / total(portable, "evaluations")
    return (
        f"The Table in all: portable / native = {seconds:.2f} in seconds, {per:.2f} in seconds "
        "per evaluation."
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--native", default=NATIVE, help=f"the native build's commit ({NATIVE})")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="smoke test (a minute)")
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--output-dir", type=Path, help="default: benchmarks/results")
    args = parser.parse_args(argv)
    if args.child is not None:
        print(json.dumps(child(args.child, args.quick, args.repeats)))
        return 0
    from benchmarks.machine import save

    output = args.output_dir or ROOT / "benchmarks" / "results"
    with tempfile.TemporaryDirectory() as tree:
        subprocess.run(
            ["git", "worktree", "add", "--detach", tree, args.native],
            cwd=ROOT,
            check=True,
            capture_output=True,
        )
        try:
            native = measure(Path(tree) / "src", args.quick, args.repeats)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", tree], cwd=ROOT, check=False)
    portable = measure(ROOT / "src", args.quick, args.repeats)
    head = (
        "| run | native iterations | native s | portable iterations | portable s | "
        "s portable / native | s per evaluation portable / native |\n"
        "|---|---:|---:|---:|---:|---:|---:|"
    )
    text = "\n".join(
        [
            f"# The cost of portable arithmetic (native build: {args.native})",
            "",
            head,
            *ratio_rows(native, portable),
            "",
            summary(native, portable),
        ]
    )
    print(text)
    name = "portable_cost_quick" if args.quick else "portable_cost"
    save(output, name, {"native": native, "portable": portable}, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
