"""B5: the JAX engine on whatever device JAX finds (an accelerator when a session is lent one).

One command, sized to finish within 8 minutes on one accelerator, that writes its results with
the device model:

1. the Table's six cases (N = 4096, alpha = 2 and 2.5, to 1e-9 F0) by the JAX engine's FIRE:
   iterations, seconds (the second of two runs, the first compiles), and its energy against the
   CPU engine's L-BFGS minimum;
2. the JAX energy+gradient on :mod:`benchmarks.scale`'s start (the Table packing tiled k x k,
   N = 4096 k^2) at k = 1, 4, 8, 16: median ms of ``--calls`` calls after a compiling one;
3. one relaxation of that start to 1e-9 F0 by the JAX engine's FIRE at each N, while the time
   budget ``--budget`` lasts (sizes after it are listed as not run).

jax-md's FIRE, the peer of ``docs/benchmarks.md`` (B5), and batched jamming are not in it yet
(issue 37): until they are, compare with the jax-md figures measured on an H200 in the issue.
``--quick`` (k = 1, 2; case 1 only) checks the script on a CPU (4 minutes on one core of the
AMD EPYC VM, JAX's CPU build).

    python -m benchmarks.gpu                       # on the device
    python -m benchmarks.gpu --quick --output-dir "$(mktemp -d)"

Results: ``benchmarks/results/gpu_<platform>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from athermal import jaxengine
from athermal.bench import ALPHAS, CASES, make_case, reference_packing
from athermal.contact import ContactModel
from athermal.relaxation import Minimizer, relax
from benchmarks.machine import ROOT, save
from benchmarks.scale import start_packing


def device() -> dict[str, str]:
    """JAX's first device: platform and model."""
    first = jaxengine.jax.devices()[0]
    return {"platform": first.platform, "device": str(getattr(first, "device_kind", first))}


def table(cases: tuple[int, ...], alphas: tuple[float, ...]) -> list[dict[str, Any]]:
    """Each case by the JAX engine's FIRE (the second of two runs) against the CPU minimum."""
    rows = []
    for alpha in alphas:
        model, base = ContactModel(alpha), reference_packing(alpha)
        for case in cases:
            start = make_case(base, case)
            jaxengine.relax_fire(start, model)  # compiles
            t0 = time.perf_counter()
            run = jaxengine.relax_fire(start, model)
            seconds = time.perf_counter() - t0
            cpu = relax(start, model, Minimizer("lbfgs"), rtol=1e-12)
            rows.append(
                {
                    "alpha": alpha,
                    "case": case,
                    "iterations": run.iterations,
                    "seconds": seconds,
                    "converged": run.converged,
                    "energy_vs_cpu": abs(run.energy - cpu.energy) / cpu.energy,
                }
            )
            print(rows[-1], flush=True)
    return rows


def kernel_ms(k: int, calls: int) -> dict[str, Any]:
    """Median ms of the JAX energy+gradient on the tiled start of ``k`` (alpha = 2)."""
    packing, model = start_packing(2.0, k), ContactModel(2.0)
    typeid = np.asarray(model.typeid(packing), dtype=np.int64)
    skin = 0.2 * float(np.mean(packing.radii))
    pairs = jaxengine.device_pairs(packing.positions, packing, model, typeid, skin)
    x = jaxengine.jnp.asarray(packing.positions)
    arrays = (pairs.first, pairs.second, pairs.shift, pairs.radius_sum, pairs.stiffness)
    function = jaxengine.jax.jit(jaxengine.energy_gradient, static_argnums=6)
    function(x, *arrays, 2.0)[1].block_until_ready()
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        function(x, *arrays, 2.0)[1].block_until_ready()
        times.append(time.perf_counter() - t0)
    return {"n": packing.n, "pairs": pairs.count, "ms": 1e3 * statistics.median(times)}


def relaxation(k: int) -> dict[str, Any]:
    """One relaxation of the tiled start of ``k`` to 1e-9 F0 by the JAX engine's FIRE."""
    packing, model = start_packing(2.0, k), ContactModel(2.0)
    t0 = time.perf_counter()
    run = jaxengine.relax_fire(packing, model)
    seconds = time.perf_counter() - t0
    return {
        "n": packing.n,
        "iterations": run.iterations,
        "seconds": seconds,
        "converged": run.converged,
        "rebuilds": run.neighbor_rebuilds,
    }


def report(data: dict[str, Any]) -> str:
    """Markdown of the three parts."""
    lines = [f"# B5 on {data['device']['device']} ({data['device']['platform']})", ""]
    lines += ["| alpha | case | JAX FIRE iterations | s | converged | energy vs CPU |"]
    lines += ["|---|---|---:|---:|---|---:|"]
    for r in data["table"]:
        lines.append(
            f"| {r['alpha']:g} | {r['case']} | {r['iterations']} | {r['seconds']:.3f} | "
            f"{r['converged']} | {r['energy_vs_cpu']:.1e} |"
        )
    lines += ["", "| N | pairs | energy+gradient ms |", "|---:|---:|---:|"]
    lines += [f"| {r['n']} | {r['pairs']} | {r['ms']:.3f} |" for r in data["kernel"]]
    lines += [
        "",
        "| N | FIRE iterations | s | converged | list builds |",
        "|---:|---:|---:|---|---:|",
    ]
    lines += [
        f"| {r['n']} | {r['iterations']} | {r['seconds']:.2f} | {r['converged']} | "
        f"{r['rebuilds']} |"
        for r in data["relaxation"]
    ]
    if data["not_run"]:
        lines += ["", f"Not run (time budget): N = {', '.join(map(str, data['not_run']))}."]
    lines += ["", "jax-md's FIRE and batched jamming: not in this script yet (issue 37)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="k = 1, 2; case 1 only")
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--budget", type=float, default=300.0, help="seconds for part 3")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    tiles = (1, 2) if args.quick else (1, 4, 8, 16)
    cases = (1,) if args.quick else CASES
    alphas = (2.0,) if args.quick else ALPHAS
    data: dict[str, Any] = {"device": device(), "table": table(cases, alphas)}
    data["kernel"] = [kernel_ms(k, args.calls) for k in tiles]
    data["relaxation"], data["not_run"] = [], []
    started = time.perf_counter()
    for k in tiles:
        if time.perf_counter() - started > args.budget:
            data["not_run"].append(4096 * k * k)
            continue
        data["relaxation"].append(relaxation(k))
        print(data["relaxation"][-1], flush=True)
    markdown = report(data)
    save(args.output_dir, f"gpu_{data['device']['platform']}", data, markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
