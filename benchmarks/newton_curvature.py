"""Newton-CG near jamming: what following the direction of negative curvature buys, and where
Newton pays among the protocols.

``ab``: for jammed packings of the iteration experiment (``--cache``, realizations 0 .. K-1 of
root seed 0) compressed to each Delta phi, the paper's first ``--steps`` simple-shear steps of
1e-6, each started from its linear-response prediction; every step is relaxed twice from the
same start, by Newton-CG as it is (``follow``) and with
:func:`athermal.minimize.newton.follow_negative_curvature` replaced by "stay" (``plain``, the
method before it), and the next step starts from the ``plain`` result, so both see the same
starts. Iterations, evaluations, CG iterations, factorizations and seconds per step.

``shear``: ``shear_steps`` (pure shear to 0.02 in steps of 1e-3, the README's example) from
N = 1024 packings compressed to each Delta phi, relaxed by L-BFGS (the default), P-L-BFGS and
Newton-CG: seconds and iterations per run.

    python -m benchmarks.newton_curvature --core 1 ab --n 4096 --seeds 4
    python -m benchmarks.newton_curvature --core 1 shear --n 1024 --seeds 3
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from collections.abc import Iterator
from contextlib import nullcontext
from importlib import import_module
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
from numpy.typing import NDArray

from athermal.analysis.moduli import nonaffine_displacement
from athermal.model.cell import simple_shear
from athermal.model.contact import ContactModel
from athermal.model.objective import MAX_STEP_FACTOR, Objective
from athermal.model.packing import Packing
from athermal.protocols import CompressionStep, shear_steps
from athermal.relaxation import Minimizer, Relaxer, force_tolerance
from athermal.studies.experiments import JamSpec, child_seeds, compression_steps
from benchmarks.machine import pin, save
from benchmarks.physics import EPSILON, GROWTH, RESULTS, jammed

OUTPUT = RESULTS / "negative_curvature"
# the module, not the function athermal.minimize.newton that the package exports
NEWTON = import_module("athermal.minimize.newton")
SHEAR_METHODS = (Minimizer("lbfgs"), Minimizer("lbfgs", "exp"), Minimizer("newton"))


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def linear_start(
    relaxed: Packing, deformation: NDArray[np.float64], model: ContactModel
) -> Packing:
    """``relaxed`` deformed affinely by ``deformation`` ``(d, d)`` and moved by the
    linear-response displacement (:func:`athermal.analysis.moduli.nonaffine_displacement`); the
    affine start alone where that displacement is not finite or moves a particle more than
    ``MAX_STEP_FACTOR`` mean radii. The same start as ``finite_strain_shear(start="linear")``."""
    deformed = relaxed.deform(deformation)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a poor solve is caught below
        u = nonaffine_displacement(relaxed, model, deformation - np.eye(relaxed.dim))
    longest = float(np.sqrt(np.max(np.einsum("ij,ij->i", u, u)))) if u.size else 0.0
    if not np.isfinite(longest) or longest > MAX_STEP_FACTOR * float(np.mean(relaxed.radii)):
        return deformed
    return deformed.with_positions(deformed.positions + u)


def stay(
    problem: Any, x: NDArray[np.float64], energy: float, grad: NDArray[np.float64], *_: Any
) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """``follow_negative_curvature`` that does not move: Newton-CG before it followed."""
    return x, energy, grad


def relax_step(
    start: Packing, model: ContactModel, gtol: float, follow: bool
) -> tuple[Packing, dict[str, float]]:
    """Relax one step start with Newton-CG, following negative curvature or not.

    Newton has no switch for it (the A/B of an algorithm's part is no user's need), so
    ``plain`` patches :func:`athermal.minimize.newton.follow_negative_curvature` for the call.
    """
    plain = mock.patch.object(NEWTON, "follow_negative_curvature", stay)
    with nullcontext() if follow else plain:
        objective = Objective(start, model)
        t0 = time.perf_counter()
        result = Relaxer(objective, Minimizer("newton")).relax(objective.x0, gtol=gtol)
        seconds = time.perf_counter() - t0
    return result.packing, {
        "iterations": result.iterations,
        "evaluations": result.evaluations,
        "cg": result.linear_iterations,
        "factorizations": result.precon_builds,
        "seconds": seconds,
    }


def compressed(args: argparse.Namespace, spec: JamSpec) -> Iterator[tuple[int, CompressionStep]]:
    """``(realization, compression step)`` for realizations 0 .. ``args.seeds``-1 (jammed from
    the cache) at each ``args.dphi``."""
    for k, seed in enumerate(child_seeds(0, args.seeds)):
        packing, phi_c, _ = jammed(args.cache, spec, seed)
        for state in compression_steps(packing, spec.model, phi_c=phi_c, delta_phis=args.dphi):
            yield k, state


def run_ab(args: argparse.Namespace) -> None:
    spec = JamSpec(args.n, 2, 2.0, dphi=GROWTH, epsilon=EPSILON)
    rows: list[dict[str, Any]] = []
    for k, state in compressed(args, spec):
        current = state.packing
        for step in range(args.steps):
            shear = simple_shear(1e-6, 2)
            start = linear_start(current, shear, spec.model)
            gtol = force_tolerance(start, spec.model, 1e-9)
            row: dict[str, Any] = {"realization": k, "delta_phi": state.delta_phi}
            row["step"] = step
            for variant in ("plain", "follow"):
                relaxed, numbers = relax_step(start, spec.model, gtol, variant == "follow")
                row[variant] = numbers
                if variant == "plain":
                    current = relaxed
            rows.append(row)
            log(
                f"realization {k} dphi {state.delta_phi:.0e} step {step}: "
                f"plain {row['plain']['iterations']} it, follow {row['follow']['iterations']}"
            )
    lines = [
        f"# Newton-CG with and without following negative curvature: 2D, N = {args.n}, "
        f"alpha = 2, realizations 0-{args.seeds - 1} of root seed 0",
        "",
        f"The paper's first {args.steps} simple-shear steps of 1e-6 at each Delta phi, each "
        "started from its linear-response prediction and relaxed to 1e-9 of the mean contact "
        "force twice from the same start: `plain` (Newton-CG before "
        "`follow_negative_curvature`, whose result the next step starts from) and `follow` "
        "(as it is). Per Delta phi: mean (median, max) over the steps; totals over all.",
        "",
        "| Delta phi | steps | iterations plain | iterations follow | seconds plain | "
        "seconds follow |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for d in args.dphi:
        sel = [r for r in rows if abs(r["delta_phi"] / d - 1.0) < 1e-6]
        if not sel:
            continue
        cells = []
        for key in ("iterations", "seconds"):
            for variant in ("plain", "follow"):
                v = [r[variant][key] for r in sel]
                fmt = "{:.0f}" if key == "iterations" else "{:.2f}"
                cells.append(
                    f"{fmt.format(statistics.fmean(v))} ({fmt.format(statistics.median(v))}, "
                    f"{fmt.format(max(v))})"
                )
        lines.append(f"| {d:.0e} | {len(sel)} | " + " | ".join(cells) + " |")
    lines += ["", "| total | plain | follow |", "|---|---:|---:|"]
    for key in ("iterations", "evaluations", "cg", "factorizations", "seconds"):
        a, b = (sum(r[v][key] for r in rows) for v in ("plain", "follow"))
        shown = (f"{a:.1f}", f"{b:.1f}") if key == "seconds" else (str(a), str(b))
        lines.append(f"| {key} | {shown[0]} | {shown[1]} |")
    save(args.output_dir, f"ab_n{args.n}", {"rows": rows}, "\n".join(lines) + "\n")
    log("\n".join(lines))


def run_shear(args: argparse.Namespace) -> None:
    spec = JamSpec(args.n, 2, 2.0, dphi=GROWTH, epsilon=EPSILON)
    rows: list[dict[str, Any]] = []
    for k, state in compressed(args, spec):
        for minimizer in SHEAR_METHODS:
            t0 = time.perf_counter()
            steps = list(
                shear_steps(
                    state.packing,
                    spec.model,
                    mode="pure",
                    strain=0.02,
                    step=1e-3,
                    minimizer=minimizer,
                )
            )
            rows.append(
                {
                    "realization": k,
                    "delta_phi": state.delta_phi,
                    "method": minimizer.name,
                    "seconds": time.perf_counter() - t0,
                    "iterations": sum(s.iterations for s in steps),
                }
            )
            log(str(rows[-1]))
    names = [m.name for m in SHEAR_METHODS]
    lines = [
        f"# shear_steps by minimizer: 2D, N = {args.n}, alpha = 2, realizations 0-"
        f"{args.seeds - 1} of root seed 0",
        "",
        "Pure shear to 0.02 in steps of 1e-3 (20 steps, each checked to be a minimum) from the "
        "jammed packing compressed to Delta phi; seconds (iterations) of the whole run.",
        "",
        "| realization | Delta phi | " + " | ".join(names) + " |",
        "|---:|---:|" + "---:|" * len(names),
    ]
    keys = sorted({(r["realization"], r["delta_phi"]) for r in rows})
    for k, d in keys:
        cells = [
            next(
                f"{r['seconds']:.2f} ({r['iterations']})"
                for r in rows
                if (r["realization"], r["delta_phi"], r["method"]) == (k, d, name)
            )
            for name in names
        ]
        lines.append(f"| {k} | {d:.0e} | " + " | ".join(cells) + " |")
    save(args.output_dir, f"shear_n{args.n}", {"rows": rows}, "\n".join(lines) + "\n")
    log("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--core", type=int, default=None, help="pin to this core")
    parser.add_argument("--cache", type=Path, default=RESULTS.parents[1] / "cache")
    parser.add_argument("--output-dir", type=Path, default=OUTPUT)
    sub = parser.add_subparsers(dest="experiment", required=True)
    ab = sub.add_parser("ab")
    ab.add_argument("--n", type=int, default=4096)
    ab.add_argument("--seeds", type=int, default=4, help="realizations")
    ab.add_argument("--steps", type=int, default=3)
    ab.add_argument("--dphi", type=float, nargs="+", default=[1e-7, 1e-6, 1e-5])
    shear = sub.add_parser("shear")
    shear.add_argument("--n", type=int, default=1024)
    shear.add_argument("--seeds", type=int, default=3, help="realizations")
    shear.add_argument("--dphi", type=float, nargs="+", default=[1e-4, 1e-2])
    args = parser.parse_args(argv)
    log(f"pinned to cores {pin(args.core)}")
    {"ab": run_ab, "shear": run_shear}[args.experiment](args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
