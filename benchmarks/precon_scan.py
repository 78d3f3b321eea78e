"""B1 (supplement): how far the Exp preconditioner's parameters move P-L-BFGS's iteration count.

On the paper's Table Cases 1 and 2 (N = 4096, alpha = 2 and 2.5, criterion 1e-9 F0), P-L-BFGS
runs with one parameter changed at a time from the paper's defaults (sine-test ``mu``,
``C_stab = 0.1``, ``r_cut = 2.2 r_max``, ``A = 0``, memory 10): ``mu`` scaled, the paper's
literal, non-periodic perturbation ``M sin(x / L)`` for ``mu``, ``C_stab``, ``r_cut``, ``A``,
the memory, and the contact-stiffness preconditioner with its Exp stabilization scaled down.
Iteration counts are deterministic; the ratio is against plain L-BFGS with the same memory.
Seconds are one run each (noisy: compare evaluations).

    python -m benchmarks.precon_scan            # about 5 minutes
    python -m benchmarks.precon_scan --quick    # Case 1, alpha 2, four variants

Results: ``benchmarks/results/precon_scan.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from athermal.engines.precon import (
    R_CUT_FACTOR,
    SINE_AMPLITUDE,
    ContactPreconditioner,
    ExpPreconditioner,
)
from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.model.packing import Packing
from athermal.relaxation import minimize_objective
from athermal.studies.bench import RTOL, make_case, reference_packing
from benchmarks.machine import ROOT, pin, save


@dataclass(frozen=True)
class Variant:
    """One change from the paper's defaults (``mu_scale`` multiplies the sine-test ``mu``)."""

    label: str
    precon: str = "exp"
    mu_scale: float = 1.0
    literal_mu: bool = False
    c_stab: float = 0.1
    r_cut: float = R_CUT_FACTOR
    A: float = 0.0
    memory: int = 10


VARIANTS = (
    Variant("L-BFGS (m = 10)", precon="none"),
    Variant("P-L-BFGS, seed's defaults"),
    Variant("mu x 1/3", mu_scale=1 / 3),
    Variant("mu x 3", mu_scale=3.0),
    Variant("mu x 10", mu_scale=10.0),
    Variant("mu from M sin(x/L) (non-periodic)", literal_mu=True),
    Variant("C_stab = 0.01", c_stab=0.01),
    Variant("C_stab = 0.03", c_stab=0.03),
    Variant("C_stab = 0.3", c_stab=0.3),
    Variant("r_cut = 2.05 r_max", r_cut=2.05),
    Variant("r_cut = 3 r_max", r_cut=3.0),
    Variant("A = 3", A=3.0),
    Variant("L-BFGS (m = 20)", precon="none", memory=20),
    Variant("P-L-BFGS, m = 20", memory=20),
    Variant("contact, Exp part x 1", precon="contact"),
    Variant("contact, Exp part x 0.1", precon="contact", mu_scale=0.1),
    Variant("contact, Exp part x 0.01", precon="contact", mu_scale=0.01),
)
QUICK = ("L-BFGS (m = 10)", "P-L-BFGS, seed's defaults", "mu x 3", "C_stab = 0.01")


def sine_mu(start: Packing, model: ContactModel, variant: Variant) -> float:
    """The sine-test ``mu`` of ``variant``'s matrix: periodic ``M sin(2 pi s)`` (athermal's),
    or with ``literal_mu`` the paper's ``M sin(x / L)`` on wrapped positions."""
    objective = Objective(start, model)
    r_cut = variant.r_cut * float(start.radii.max())
    precon = ExpPreconditioner(objective, A=variant.A, r_cut=r_cut, c_stab=variant.c_stab)
    precon.update(objective.x0)
    if not variant.literal_mu:
        return precon.mu
    assert precon.matrix is not None
    unit = precon.matrix / precon.mu
    positions = objective.x0.reshape(objective.n, objective.dim)
    v = SINE_AMPLITUDE * r_cut * np.sin(objective.cell.fractional(positions))
    _, g0 = objective(objective.x0)
    _, g1 = objective(objective.x0 + v.ravel())
    return float(v.ravel() @ (g1 - g0)) / float(np.einsum("ia,ia->", v, unit @ v))


def run(start: Packing, model: ContactModel, variant: Variant) -> dict[str, float | int | bool]:
    mu = None if variant.precon == "none" else sine_mu(start, model, variant) * variant.mu_scale
    objective = Objective(start, model)
    r_cut = variant.r_cut * float(start.radii.max())
    kind = {"exp": ExpPreconditioner, "contact": ContactPreconditioner}.get(variant.precon)
    precon = (
        None
        if kind is None
        else kind(objective, A=variant.A, r_cut=r_cut, c_stab=variant.c_stab, mu=mu)
    )
    t0 = time.perf_counter()
    res = minimize_objective(
        objective,
        "lbfgs",
        precon=precon if precon is not None else "none",
        rtol=RTOL,
        maxiter=50_000,
        memory=variant.memory,
    )
    return {
        "iterations": res.iterations,
        "evaluations": res.evaluations,
        "seconds": time.perf_counter() - t0,
        "converged": res.converged,
        "mu": float("nan") if mu is None else mu,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    pin()
    problems = [(2.0, 1)] if args.quick else [(2.0, 1), (2.0, 2), (2.5, 1), (2.5, 2)]
    variants = [v for v in VARIANTS if not args.quick or v.label in QUICK]
    rows: list[dict[str, object]] = []
    for alpha, case in problems:
        model = ContactModel(alpha)
        start = make_case(reference_packing(alpha), case)
        reference: dict[int, int] = {}
        for variant in variants:
            result = run(start, model, variant)
            iterations = int(result["iterations"])
            if variant.precon == "none":
                reference[variant.memory] = iterations
            ratio = iterations / reference[variant.memory]
            row = {"alpha": alpha, "case": case, "variant": variant.label, **result, "ratio": ratio}
            rows.append(row)
            print(
                f"alpha {alpha:g} case {case} {variant.label:36s} it {row['iterations']:6d} "
                f"ev {row['evaluations']:6d} ratio {row['ratio']:.2f}",
                file=sys.stderr,
                flush=True,
            )
    criterion = f"max_i |grad_i| <= {RTOL:g} F0 (F0: mean contact force at the start)"
    lines = ["# B1 supplement — P-L-BFGS iterations against the Exp parameters", ""]
    lines += [
        f"- criterion: {criterion}",
        "- ratio: iterations / L-BFGS iterations with the same memory (target <= 0.35)",
        "- seconds: one run each",
        "",
        "| alpha | case | variant | mu | iterations | evaluations | ratio | seconds | converged |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---|",
    ]
    lines += [
        f"| {r['alpha']:g} | {r['case']} | {r['variant']} | {r['mu']:.4g} | {r['iterations']} "
        f"| {r['evaluations']} | {r['ratio']:.2f} | {r['seconds']:.2f} "
        f"| {'yes' if r['converged'] else 'no'} |"
        for r in rows
    ]
    text = "\n".join(lines) + "\n"
    save(args.output_dir, "precon_scan", {"meta": {"criterion": criterion}, "rows": rows}, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
