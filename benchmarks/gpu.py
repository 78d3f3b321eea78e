"""B5: the JAX engine on whatever device JAX finds (an accelerator when a session is lent one).

One command, sized to finish within 8 minutes on one accelerator, that writes its results with
the device model:

1. the Table's six cases (N = 4096, alpha = 2 and 2.5, to 1e-9 F0) by the JAX engine's FIRE
   and P-L-BFGS: iterations, seconds (the second of two runs, the first compiles), and the
   energy against the CPU engine's L-BFGS minimum; with jax-md's FIRE in the same run when
   ``jax_md`` is importable (its defaults, ``soft_sphere_neighbor_list`` with ``dr_threshold``
   = 0.2 r_max updated every step, one jitted ``while_loop``, in the Table's own units: a unit
   cell, k = 1) and the ratio of the fastest athermal time to its time;
2. the JAX energy+gradient on :mod:`benchmarks.scale`'s start (the Table packing tiled k x k,
   N = 4096 k^2) at k = 1, 4, 8, 16: median ms of ``--calls`` calls after a compiling one;
3. one relaxation of that start to 1e-9 F0 by the JAX engine's P-L-BFGS and FIRE at each N,
   while the time budget ``--budget`` lasts (runs after it are listed as not run).

4. batched jamming: ``--realizations`` packings of N = 1024 (epsilon 1e-6, P-L-BFGS) by
   ``ensemble jam --batch``, realizations a minute and the jamming checks passed.

``--quick`` (k = 1, 2; case 1 only; 4 packings of N = 64) checks the script on a CPU (minutes,
JAX's CPU build).

    python -m benchmarks.gpu                       # on the device
    python -m benchmarks.gpu --quick --output-dir "$(mktemp -d)"

Results: ``benchmarks/results/gpu_<platform>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from athermal.engines.jax import device as jaxengine
from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.model.packing import Packing
from athermal.relaxation import Minimizer, relax
from athermal.studies.bench import ALPHAS, CASES, make_case, reference_packing
from athermal.studies.ensemble import EnsembleSpec, run_ensemble
from athermal.studies.experiments import JamSpec
from benchmarks.machine import ROOT, save
from benchmarks.scale import start_packing


def device() -> dict[str, str]:
    """JAX's first device: platform and model."""
    first = jaxengine.jax.devices()[0]
    return {"platform": first.platform, "device": str(getattr(first, "device_kind", first))}


def jaxmd_fire(start: Packing, model: ContactModel, gtol: float) -> dict[str, Any]:
    """jax-md's FIRE on ``start`` (a bidisperse packing of uniform stiffness) to a largest
    force ``gtol``: iterations, seconds of the second of two runs, and the largest gradient of
    the end by the CPU engine's count over ``gtol``."""
    space = importlib.import_module("jax_md.space")
    energy = importlib.import_module("jax_md.energy")
    descent = importlib.import_module("jax_md.minimize").fire_descent
    jax, jnp = jaxengine.jax, jaxengine.jnp
    alpha = float(model.alpha)
    h = jnp.asarray(np.asarray(start.cell.h))
    sizes, species = np.unique(start.radii, return_inverse=True)
    sigma = sizes[:, None] + sizes[None, :]
    fractional = start.cell.fractional(start.positions)
    s0 = jnp.asarray(fractional - np.floor(fractional))
    displacement, shift = space.periodic_general(h, fractional_coordinates=True)
    neighbor_fn, energy_fn = energy.soft_sphere_neighbor_list(
        displacement,
        h,
        species=jnp.asarray(species),
        sigma=jnp.asarray(sigma),
        epsilon=jnp.asarray(float(np.max(model.kmat)) * sigma**alpha),
        alpha=alpha,
        dr_threshold=float(0.2 * sizes.max()),
        fractional_coordinates=True,
    )
    init, apply = descent(energy_fn, shift)

    def run(state: Any, neighbors: Any) -> Any:
        def cond(c: Any) -> Any:
            return (jnp.max(jnp.sum(c[0].force ** 2, 1)) > gtol**2) & (c[2] < 1_000_000)

        def body(c: Any) -> Any:
            neighbors = c[1].update(c[0].position)
            return apply(c[0], neighbor=neighbors), neighbors, c[2] + 1

        return jax.lax.while_loop(cond, body, (state, neighbors, 0))

    neighbors = neighbor_fn.allocate(s0)
    state = init(s0, neighbor=neighbors)
    loop = jax.jit(run)
    jax.block_until_ready(loop(state, neighbors)[0].position)  # compiles
    t0 = time.perf_counter()
    out = loop(state, neighbors)
    jax.block_until_ready(out[0].position)
    seconds = time.perf_counter() - t0
    end = start.with_positions(np.asarray(out[0].position) @ np.asarray(start.cell.h).T)
    check = Objective(end, model, sort=False)
    grad = check(check.x0)[1]
    return {
        "iterations": int(out[2]),
        "seconds": seconds,
        "overflow": bool(out[1].did_buffer_overflow),
        "max_gradient_over_gtol": check.max_gradient(grad) / gtol,
    }


JAX_METHODS = ("fire", "plbfgs")
"""The JAX engine's methods this benchmark times: FIRE (jax-md's method) and P-L-BFGS (the
paper's, with the V-cycle preconditioner on the device)."""


def timed(start: Packing, model: ContactModel, method: str) -> tuple[Any, float]:
    """A relaxation of ``start`` to 1e-9 F0 by ``method`` on the JAX engine and its seconds:
    the second of two runs (the first compiles the loops)."""
    how = Minimizer(method, backend="jax")  # type: ignore[arg-type]
    relax(start, model, how)
    t0 = time.perf_counter()
    run = relax(start, model, how)
    return run, time.perf_counter() - t0


def table(cases: tuple[int, ...], alphas: tuple[float, ...]) -> list[dict[str, Any]]:
    """Each case by the JAX engine's methods against the CPU minimum, and jax-md's FIRE."""
    rows = []
    for alpha in alphas:
        model, base = ContactModel(alpha), reference_packing(alpha)
        for case in cases:
            start = make_case(base, case)
            cpu = relax(start, model, Minimizer("lbfgs"), rtol=1e-12)
            row: dict[str, Any] = {"alpha": alpha, "case": case}
            for method in JAX_METHODS:
                run, seconds = timed(start, model, method)
                row[method] = {
                    "iterations": run.iterations,
                    "seconds": seconds,
                    "converged": run.converged,
                    "energy_vs_cpu": abs(run.energy - cpu.energy) / cpu.energy,
                }
                gtol = run.gtol
            row["jax_md"] = (
                jaxmd_fire(start, model, gtol) if importlib.util.find_spec("jax_md") else None
            )
            rows.append(row)
            print(rows[-1], flush=True)
    return rows


def kernel_ms(k: int, calls: int) -> dict[str, Any]:
    """Median ms of the JAX energy+gradient on the tiled start of ``k`` (alpha = 2)."""
    packing, model = start_packing(2.0, k), ContactModel(2.0)
    typeid = np.asarray(model.typeid(packing), dtype=np.int64)
    skin = 0.2 * float(np.mean(packing.radii))
    pairs = jaxengine.device_pairs(
        packing.positions, packing.radii, packing.cell, model, typeid, skin
    )
    x = jaxengine.jnp.asarray(packing.positions)
    function = jaxengine.jax.jit(jaxengine.energy_gradient, static_argnums=2)
    function(x, pairs.arrays, model.law)[1].block_until_ready()
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        function(x, pairs.arrays, model.law)[1].block_until_ready()
        times.append(time.perf_counter() - t0)
    return {"n": packing.n, "pairs": pairs.count, "ms": 1e3 * statistics.median(times)}


def relaxation(k: int, method: str) -> dict[str, Any]:
    """One relaxation of the tiled start of ``k`` to 1e-9 F0 by ``method`` on the JAX engine
    (compiling included: one run per size)."""
    packing, model = start_packing(2.0, k), ContactModel(2.0)
    t0 = time.perf_counter()
    run = relax(packing, model, Minimizer(method, backend="jax"))  # type: ignore[arg-type]
    seconds = time.perf_counter() - t0
    return {
        "n": packing.n,
        "method": method,
        "iterations": run.iterations,
        "seconds": seconds,
        "converged": run.converged,
        "rebuilds": run.neighbor_rebuilds,
    }


def batched_jamming(n: int, realizations: int, batch: int) -> dict[str, Any]:
    """``realizations`` jammed packings of ``n`` (epsilon 1e-6, P-L-BFGS on the JAX engine)
    by ``ensemble jam --batch batch``: seconds, realizations per minute, checks passed."""
    spec = EnsembleSpec("jam", jam=JamSpec(n=n, minimizer=Minimizer("plbfgs", backend="jax")))
    with tempfile.TemporaryDirectory() as directory:
        t0 = time.perf_counter()
        result = run_ensemble(spec, directory, realizations, batch=batch)
        seconds = time.perf_counter() - t0
    return {
        "n": n,
        "realizations": realizations,
        "batch": batch,
        "seconds": seconds,
        "per_minute": 60.0 * realizations / seconds,
        "checks_passed": int(result.summary["checks_passed"]),
        "phi_c": result.summary["phi_c"],
        "engine": result.engine,
    }


def report(data: dict[str, Any]) -> str:
    """Markdown of the three parts."""
    lines = [f"# B5 on {data['device']['device']} ({data['device']['platform']})", ""]
    lines += [
        "| alpha | case | JAX FIRE iterations | s | JAX P-L-BFGS iterations | s | energy vs "
        "CPU (worst) | jax-md FIRE iterations | s | its max force / gtol (CPU count) | "
        "fastest athermal / jax-md |"
    ]
    lines += ["|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in data["table"]:
        fire, plbfgs, peer = r["fire"], r["plbfgs"], r["jax_md"]
        fastest = min(fire["seconds"], plbfgs["seconds"])
        theirs = (
            f"{peer['iterations']} | {peer['seconds']:.3f} | "
            f"{peer['max_gradient_over_gtol']:.2f} | {fastest / peer['seconds']:.2f}"
            if peer
            else "not installed | - | - | -"
        )
        worst = max(fire["energy_vs_cpu"], plbfgs["energy_vs_cpu"])
        converged = "" if fire["converged"] and plbfgs["converged"] else " (not converged)"
        lines.append(
            f"| {r['alpha']:g} | {r['case']} | {fire['iterations']} | {fire['seconds']:.3f} | "
            f"{plbfgs['iterations']} | {plbfgs['seconds']:.3f} | {worst:.1e}{converged} | "
            f"{theirs} |"
        )
    lines += ["", "| N | pairs | energy+gradient ms |", "|---:|---:|---:|"]
    lines += [f"| {r['n']} | {r['pairs']} | {r['ms']:.3f} |" for r in data["kernel"]]
    lines += [
        "",
        "| N | method | iterations | s (compiling included) | converged | list builds |",
        "|---:|---|---:|---:|---|---:|",
    ]
    lines += [
        f"| {r['n']} | {r['method']} | {r['iterations']} | {r['seconds']:.2f} | "
        f"{r['converged']} | {r['rebuilds']} |"
        for r in data["relaxation"]
    ]
    if data["not_run"]:
        lines += ["", f"Not run (time budget): {', '.join(data['not_run'])}."]
    b = data["batched"]
    lines += [
        "",
        f"Batched jamming: {b['realizations']} packings of N = {b['n']} in batches of "
        f"{b['batch']}: {b['seconds']:.1f} s ({b['per_minute']:.1f} a minute, compiling "
        f"included), {b['checks_passed']} passed every jamming check; phi_c "
        f"{b['phi_c']['mean']:.5f} ± {b['phi_c']['stderr']:.5f}; {b['engine']}.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="k = 1, 2; case 1 only")
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--budget", type=float, default=240.0, help="seconds for part 3")
    parser.add_argument("--realizations", type=int, default=64, help="part 4 (N = 1024)")
    parser.add_argument("--batch", type=int, default=64, help="part 4's batch")
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
        for method in ("plbfgs", "fire"):
            if time.perf_counter() - started > args.budget:
                data["not_run"].append(f"N = {4096 * k * k} {method}")
                continue
            data["relaxation"].append(relaxation(k, method))
            print(data["relaxation"][-1], flush=True)
    n, count, batch = (64, 4, 4) if args.quick else (1024, args.realizations, args.batch)
    data["batched"] = batched_jamming(n, count, batch)
    print(data["batched"], flush=True)
    markdown = report(data)
    save(args.output_dir, f"gpu_{data['device']['platform']}", data, markdown)
    print(markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
