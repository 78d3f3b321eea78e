"""B6: an ensemble of jamming realizations on 2 Dask workers against 1 (wall time ratio).

M realizations (default 8) of ``athermal ensemble jam`` at N = 1024 (``JamSpec`` defaults:
epsilon = 1e-6, P-L-BFGS), root seed 0, run twice into fresh directories: on a local cluster of
1 worker process, then 2. Reports both wall times, their ratio (ideal 0.5 on a 2-core machine),
whether the realizations are identical, and phi_c's mean, standard deviation and standard error.

    python -m benchmarks.ensemble              # M = 8, N = 1024 (about 10 minutes)
    python -m benchmarks.ensemble --m 4 --n 256

Results: ``benchmarks/results/ensemble.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from athermal.studies.ensemble import EnsembleSpec, run_ensemble
from athermal.studies.experiments import JamSpec
from benchmarks.machine import ROOT, save


def timeless(record: dict[str, Any]) -> dict[str, Any]:
    """A realization's record without its wall time (the part that must not change)."""
    return {k: v for k, v in record.items() if k != "seconds"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--m", type=int, default=8)
    parser.add_argument("--n", type=int, default=1024)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    spec = EnsembleSpec("jam", jam=JamSpec(n=args.n))
    runs = {}
    with tempfile.TemporaryDirectory() as scratch:
        for workers in (1, 2):
            t0 = time.perf_counter()
            result = run_ensemble(spec, Path(scratch) / f"w{workers}", args.m, workers=workers)
            runs[workers] = (time.perf_counter() - t0, result)
            print(f"{workers} worker(s): {runs[workers][0]:.1f} s", file=sys.stderr)
    one, two = runs[1][1], runs[2][1]
    same = [timeless(r.to_json()) for r in one.realizations] == [
        timeless(r.to_json()) for r in two.realizations
    ]
    phi = one.summary["phi_c"]
    data = {
        "m": args.m,
        "n": args.n,
        "seconds_1_worker": runs[1][0],
        "seconds_2_workers": runs[2][0],
        "ratio": runs[2][0] / runs[1][0],
        "identical": same,
        "phi_c": phi,
        "phi_c_values": [r.phi_c for r in one.realizations],
    }
    lines = [
        f"# Ensemble: {args.m} jamming realizations, N = {args.n}, on Dask workers",
        "",
        "| workers | wall seconds |",
        "|---:|---:|",
        f"| 1 | {runs[1][0]:.1f} |",
        f"| 2 | {runs[2][0]:.1f} |",
        "",
        f"Ratio 2 / 1 workers: {data['ratio']:.3f} (ideal 0.5 on this 2-core machine). "
        f"Realizations identical with 1 and 2 workers: {'yes' if same else 'NO'}.",
        "",
        f"phi_c = {phi['mean']:.5f} ± {phi['sd']:.5f} (sd), standard error {phi['stderr']:.5f}, "
        f"over {phi['n']} realizations.",
    ]
    text = "\n".join(lines) + "\n"
    save(args.output_dir, "ensemble", data, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
