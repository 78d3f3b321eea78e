"""Certified jamming at scale (issue 54): ``athermal jam --certify --epsilon 1e-12`` from a
random start, each (d, N, seed) in its own process: its wall time, its peak resident memory, the
bracket's width, the force balance of the certificate and the same recomputed independently
from the written file in 40-digit decimal arithmetic, ``N_c - N_iso`` and the march's trials,
beside the record for exactly balanced jammed packings: CALiPPSO (Artiaco, Diaz, Parisi &
Ricci-Tersenghi), N = 16384 monodisperse spheres in 3D, isostatic, force mismatch 2.35e-13, in
299.5 minutes and 293 GB with a commercial LP solver (its documentation, "basic usage").
Run from the repository root::

    python -m benchmarks.certified_scale --run 3 1024 1 --run 3 4096 1
    python -m benchmarks.certified_scale --run 2 64 1 --run 3 64 1   # smoke test (seconds)

Rows already in the results (same d, N and seed) are kept unless run again. Results:
``benchmarks/results/certified_scale.md`` and ``certified_scale.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from decimal import Decimal, localcontext
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from athermal import read_gsd
from benchmarks.machine import ROOT, commit, cpu_model, pin, save

EPSILON = 1e-12
DIGITS = 40
"""The decimal arithmetic of the independent force balance."""
CHILD = """
import json, resource, sys
from athermal.cli import main
code = main(json.loads(sys.argv[1]))
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"code": code, "peak_kb": peak}), file=sys.stderr)
"""


def decimal_balance(path: Path) -> dict[str, float]:
    """The largest net contact force on a particle over the mean contact force, recomputed from
    the file's positions (``hi + lo``, exactly) in :data:`DIGITS`-digit decimal arithmetic
    (harmonic contacts, ``k = 1``), and the contacts and the particles that carry them."""
    frame = read_gsd(str(path))
    packing = frame.packing
    h = packing.cell.h
    if np.count_nonzero(h - np.diag(np.diag(h))):
        raise ValueError("decimal_balance: an orthorhombic cell only")
    lo = np.zeros_like(packing.positions) if frame.position_lo is None else frame.position_lo
    widths = np.diag(h)
    tree = cKDTree(np.mod(packing.positions, widths), boxsize=widths)
    near = tree.query_pairs(2.0 * float(packing.radii.max()) + 1e-9, output_type="ndarray")
    first, second = near[:, 0], near[:, 1]
    with localcontext() as context:
        context.prec = DIGITS
        width = [Decimal(float(w)) for w in widths]
        x = [
            [Decimal(float(a)) + Decimal(float(b)) for a, b in zip(p, q, strict=True)]
            for p, q in zip(packing.positions, lo, strict=True)
        ]
        radius = [Decimal(float(r)) for r in packing.radii]
        net = [[Decimal(0)] * packing.dim for _ in range(packing.n)]
        forces: list[Decimal] = []
        for i, j in zip(first.tolist(), second.tolist(), strict=True):
            sep = [x[i][a] - x[j][a] for a in range(packing.dim)]
            sep = [s - w * round(s / w) for s, w in zip(sep, width, strict=True)]
            distance = sum(s * s for s in sep).sqrt()
            overlap = radius[i] + radius[j] - distance
            if overlap <= 0:
                continue
            forces.append(overlap)
            for a in range(packing.dim):
                push = overlap * sep[a] / distance
                net[i][a] += push
                net[j][a] -= push
        largest = max(sum(f * f for f in row).sqrt() for row in net)
        mean = sum(forces) / len(forces)
        loaded = sum(1 for row in net if any(row)) if forces else 0
        return {
            "decimal_balance": float(largest / mean),
            "decimal_contacts": len(forces),
            "decimal_loaded": loaded,
        }


def one(dim: int, n: int, seed: int, folder: Path) -> dict[str, Any]:
    """Jam and certify one packing in a process of its own; its row."""
    out = folder / f"d{dim}_n{n}_s{seed}.gsd"
    args = ["jam", "--dim", str(dim), "--n", str(n), "--seed", str(seed), "--certify"]
    args += ["--epsilon", str(EPSILON), "--picture", "none", "--json", "-o", str(out)]
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(args)], capture_output=True, text=True, check=False
    )
    seconds = time.perf_counter() - start
    lines = done.stderr.strip().splitlines()
    if done.returncode != 0 or not lines:
        raise SystemExit(
            f"certified_scale: the run of d = {dim}, N = {n}, seed {seed} ended with code "
            f"{done.returncode} after {seconds:.0f} s (stopped?): {lines[-1] if lines else ''}"
        )
    child = json.loads(lines[-1])
    row: dict[str, Any] = {"dim": dim, "n": n, "seed": seed, "seconds": seconds}
    row["cpu"] = cpu_model()
    row["commit"] = commit()
    row["peak_gb"] = child["peak_kb"] / 1e6
    if child["code"] != 0:
        row["refused"] = done.stderr.strip().splitlines()[0]
        return row
    result = json.loads(done.stdout)
    cert = result["certificate"]
    row.update(
        width=result["phi_high"] - result["phi_low"],
        phi_c=result["phi_high"],
        balance=cert["relative_force_balance"],
        excess=cert["excess_contacts"],
        contacts=cert["contacts"],
        rattlers=cert["n_rattlers"],
        pressure=cert["pressure"],
        lowest_eigenvalue=cert["lowest_eigenvalue"],
        trials=result["bisected_in_double_double"]["trials"],
        cli_seconds=result["seconds"],
    )
    row.update(decimal_balance(out))
    return row


def report(rows: list[dict[str, Any]]) -> str:
    """The scale table, CALiPPSO's record beside it."""
    lines = [
        "# Certified jamming at scale (benchmarks/certified_scale.py)",
        "",
        f"`athermal jam --certify --epsilon {EPSILON:g}` from a random start (bidisperse 1:1.4, "
        "harmonic), each run a process of its own on one core: wall seconds (imports and "
        "compilation from the cache included), peak resident memory, the bracket's width, the "
        "certificate's force balance (largest net force over the mean contact force, "
        f"double-double) and the same recomputed from the written file in {DIGITS}-digit "
        "decimal arithmetic, N_c - N_iso (contacts above isostatic), trials of the march.",
        "",
        "| d | N | seed | seconds | peak GB | width | balance / <f> | decimal | contacts | "
        "N_c - N_iso | rattlers | pressure | trials | CPU | commit |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (r["dim"], r["n"], r["seed"])):
        head = f"| {r['dim']} | {r['n']} | {r['seed']} | {r['seconds']:.0f} | {r['peak_gb']:.2f}"
        if "refused" in r:
            lines.append(f"{head} | refused: {r['refused']} |||||||| {r['cpu']} | {r['commit']} |")
            continue
        lines.append(
            f"{head} | {r['width']:.1e} | {r['balance']:.1e} | {r['decimal_balance']:.1e} | "
            f"{r['contacts']} | {r['excess']} | {r['rattlers']} | {r['pressure']:.1e} | "
            f"{r['trials']} | {r['cpu']} | {r['commit']} |"
        )
    lines += [
        "| 3 | 16384 | CALiPPSO | 17970 | 293 | | 2.35e-13 (force mismatch) | | | 0 | | | | "
        "its documentation | |",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--run", nargs=3, type=int, action="append", metavar=("DIM", "N", "SEED"), required=True
    )
    parser.add_argument("--core", type=int, default=None, help="the core to pin to")
    parser.add_argument("--output-dir", type=str, default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    pin(args.core)
    folder = Path(args.output_dir)
    known = folder / "certified_scale.json"
    rows = json.loads(known.read_text())["rows"] if known.is_file() else []
    with tempfile.TemporaryDirectory() as scratch:
        for dim, n, seed in args.run:
            row = one(dim, n, seed, Path(scratch))
            rows = [r for r in rows if (r["dim"], r["n"], r["seed"]) != (dim, n, seed)]
            rows.append(row)
            print(json.dumps(row), flush=True)
            save(folder, "certified_scale", {"epsilon": EPSILON, "rows": rows}, report(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
