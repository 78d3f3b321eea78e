"""Why a quasi-static shear step near jamming costs Newton-CG tens of iterations, and what
makes it cost one.

For a jammed packing of the iteration experiment (``--cache``) compressed to each Delta phi:

1. one simple-shear step of strain ``gamma`` from the relaxed state, started affinely and
   relaxed by Newton-CG: the contacts of the relaxed start, of the affinely sheared state and
   of the relaxed end, the contacts that differ between start and end, and Newton's outer
   iterations, factorizations and CG iterations; for the paper's step (1e-6) and for steps far
   below Delta phi, where the contact network holds;
2. ``finite_strain_shear`` over the paper's first ``--steps`` strains with each start
   (``affine``, the paper's, and ``linear``, the linear-response prediction) and each of
   Newton-CG and P-L-BFGS: iterations and wall milliseconds per step (the prediction's solve
   included), and G.

    python -m benchmarks.newton_diagnostics --n 1024 --seed-index 0
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from athermal.model.cell import simple_shear
from athermal.model.contact import ContactModel, find_contacts
from athermal.model.objective import Objective
from athermal.model.packing import Packing
from athermal.protocols import finite_strain_shear
from athermal.protocols.finite_strain import DEFAULT_STRAINS
from athermal.relaxation import Minimizer, force_tolerance, minimize_objective
from athermal.studies.experiments import JamSpec, child_seeds, compression_steps
from benchmarks.machine import pin, save
from benchmarks.physics import EPSILON, GROWTH, RESULTS, jammed

DELTA_PHIS = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
GAMMAS = (1e-6, 1e-8)
METHODS = (Minimizer("newton"), Minimizer("lbfgs", "exp"))


def pair_set(packing: Packing, model: ContactModel) -> set[tuple[int, int]]:
    contacts = find_contacts(packing, model)
    return set(zip(contacts.i.tolist(), contacts.j.tolist(), strict=True))


def one_step(packing: Packing, model: ContactModel, gamma: float) -> dict[str, float]:
    before = pair_set(packing, model)
    sheared = packing.deform(simple_shear(gamma, 2))
    res = minimize_objective(
        Objective(sheared, model), "newton", gtol=force_tolerance(sheared, model, 1e-9)
    )
    after = pair_set(res.packing, model)
    return {
        "gamma": gamma,
        "contacts": len(before),
        "contacts_affine": len(pair_set(sheared, model)),
        "contacts_relaxed": len(after),
        "changed": len(before ^ after),
        "iterations": res.iterations,
        "factorizations": res.precon_builds,
        "cg_iterations": res.linear_iterations,
        "converged": res.converged,
    }


def protocol(packing: Packing, model: ContactModel, steps: int) -> list[dict[str, object]]:
    out: list[dict[str, object]] = []
    for start in ("affine", "linear"):
        for method in METHODS:
            t0 = time.perf_counter()
            fs = finite_strain_shear(
                packing, model, DEFAULT_STRAINS[:steps], minimizer=method, start=start
            )
            out.append(
                {
                    "start": start,
                    "method": method.name,
                    "iterations": float(fs.iterations.mean()),
                    "ms_per_step": 1e3 * (time.perf_counter() - t0) / steps,
                    "G": fs.modulus,
                    "G_stderr": fs.stderr,
                }
            )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=1024)
    parser.add_argument("--seed-index", type=int, default=0, help="realization of root seed 0")
    parser.add_argument("--steps", type=int, default=3, help="shear steps of part 2")
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument("--cache", type=Path, default=Path(__file__).parent / "cache")
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    pin(args.core)
    spec = JamSpec(args.n, 2, 2.0, dphi=GROWTH, epsilon=EPSILON)
    seed = child_seeds(0, args.seed_index + 1)[args.seed_index]
    packing, phi_c, _ = jammed(args.cache, spec, seed)
    model = spec.model
    steps, runs = [], []
    for state in compression_steps(packing, model, phi_c=phi_c, delta_phis=DELTA_PHIS):
        for gamma in GAMMAS:
            steps.append({"delta_phi": state.delta_phi, **one_step(state.packing, model, gamma)})
            print(steps[-1], file=sys.stderr, flush=True)
        for row in protocol(state.packing, model, args.steps):
            runs.append({"delta_phi": state.delta_phi, **row})
            print(runs[-1], file=sys.stderr, flush=True)
    lines = [
        f"# Newton-CG on quasi-static shear steps near jamming: 2D, N = {args.n}, alpha = 2, "
        f"realization {args.seed_index} of root seed 0 (phi_c = {phi_c:.7f})",
        "",
        "## 1. One step from the relaxed state, started affinely",
        "",
        "contacts: of the relaxed start, right after the affine step, after relaxation; "
        "changed: contacts in the start or the end but not both.",
        "",
        "| Delta phi | gamma | contacts | affine | relaxed | changed | Newton its | "
        "factorizations | CG its |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        *(
            f"| {r['delta_phi']:.0e} | {r['gamma']:.0e} | {r['contacts']} | "
            f"{r['contacts_affine']} | {r['contacts_relaxed']} | {r['changed']} | "
            f"{r['iterations']} | {r['factorizations']} | {r['cg_iterations']} |"
            for r in steps
        ),
        "",
        f"## 2. `finite_strain_shear`, the paper's first {args.steps} steps (1e-6 each)",
        "",
        "Mean iterations and wall milliseconds per step (one core; the linear start's solve "
        "included), and the fitted G ± its standard error.",
        "",
        "| Delta phi | start | method | iterations | ms / step | G |",
        "|---:|---|---|---:|---:|---:|",
        *(
            f"| {r['delta_phi']:.0e} | {r['start']} | {r['method']} | {r['iterations']:.0f} | "
            f"{r['ms_per_step']:.1f} | {r['G']:.5e} ± {r['G_stderr']:.1e} |"
            for r in runs
        ),
    ]
    save(
        args.output_dir,
        f"newton_diagnostics_n{args.n}",
        {"phi_c": phi_c, "steps": steps, "protocol": runs},
        "\n".join(lines) + "\n",
    )
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
