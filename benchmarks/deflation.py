"""What would make P-L-BFGS robust near jamming: the Exp preconditioner with its softest modes
deflated (issue 12, "say what would reach it"; ``spectrum.py`` counts those modes).

For jammed packings of the iteration experiment (``--cache``, realizations of root seed 0)
compressed to each Delta phi, the ``k`` softest generalized eigenvectors ``V`` of ``H v =
lambda P v`` at the relaxed state (dense; ``H`` the Hessian without its zero modes, ``P`` the Exp
matrix, ``V^T P V = I``) make the preconditioner

    ``M^-1 = P^-1 + V (Lambda^-1 - I) V^T``,

which acts as ``H^-1`` on those modes and as ``P^-1`` elsewhere (SPD: ``P^-1 - V V^T`` is
positive semidefinite). P-L-BFGS with ``M`` then relaxes one simple-shear step of 1e-6 from
the relaxed state (affine start, to 1e-9 of the mean contact force), the modes taken from the
state before the step, as a quasi-static protocol would reuse them. Reported: iterations per
step for each ``k`` (``k = 0`` is P-L-BFGS itself; median, range and the relaxations that did
not converge within :data:`MAXITER`), their power law in Delta phi, and the ratio 1e-6 / 1e-1.
The modes here come from a dense eigendecomposition (seconds at N = 1024, out of reach at N =
10^5): the table measures what deflation buys in iterations, not a method.

    python -m benchmarks.deflation --n 1024 --seeds 10
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray

from athermal.analysis.fitting import fit_power_law
from athermal.engines.precon import ExpPreconditioner
from athermal.model.cell import simple_shear
from athermal.model.objective import Objective
from athermal.relaxation import force_tolerance, minimize_objective
from benchmarks.machine import save
from benchmarks.spectrum import DELTA_PHIS, MODEL, ZERO, arguments, compressed_states, hessian

MODES = (0, 10, 40, 100)
"""Numbers ``k`` of soft modes deflated."""
GAMMA = 1e-6
"""The shear step."""
MAXITER = 100_000
"""Iteration limit of a relaxation (one that reaches it counts as not converged)."""


class Deflated:
    """``M^-1 = P^-1 + V (Lambda^-1 - I) V^T`` on top of an Exp preconditioner ``base``, for
    ``V`` ``(N d, k)`` P-orthonormal and ``Lambda`` ``(k,)`` its generalized eigenvalues."""

    name = "deflated exp"

    def __init__(
        self, base: ExpPreconditioner, modes: NDArray[np.float64], values: NDArray[np.float64]
    ) -> None:
        self.base, self.modes, self.coefficients = base, modes, 1.0 / values - 1.0
        self.n_builds = 0
        self.n_solves = 0

    def update(self, x: NDArray[np.float64]) -> None:
        self.base.update(x)
        self.n_builds = self.base.n_builds

    def solve(self, g: NDArray[np.float64]) -> NDArray[np.float64]:
        self.n_solves += 1
        return self.base.solve(g) + self.modes @ (self.coefficients * (self.modes.T @ g))

    def compiled_solver(self) -> None:
        """None: the deflation is applied from Python."""
        return None

    def dot(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        raise NotImplementedError("the deflated preconditioner is applied through solve only")


def step_iterations(state_packing: Any, model: Any) -> dict[int, int | None]:
    """Iterations of P-L-BFGS with ``k`` deflated modes (each of :data:`MODES`) on one shear
    step of :data:`GAMMA` from ``state_packing``; None where it did not converge within
    :data:`MAXITER`."""
    reference, h = hessian(state_packing, model)
    exp = ExpPreconditioner(reference, solver="direct")
    exp.update(reference.x0)
    assert exp.matrix is not None
    p = sp.kron(exp.matrix, sp.eye(reference.dim)).toarray()
    values, vectors = scipy.linalg.eigh(h, p)
    soft = np.flatnonzero(np.abs(values) > ZERO * values[-1])
    sheared = state_packing.deform(simple_shear(GAMMA, state_packing.dim))
    gtol = force_tolerance(sheared, model, 1e-9)
    out: dict[int, int | None] = {}
    for k in MODES:
        objective = Objective(sheared, model, sort=False)  # the reference's particle order
        base = ExpPreconditioner(objective, solver="direct")
        base.update(objective.x0)
        precon: Any = base
        if k:
            scale = exp.mu / base.mu  # P here is P of the reference / scale
            chosen = soft[:k]
            precon = Deflated(base, vectors[:, chosen] * np.sqrt(scale), values[chosen] * scale)
        result = minimize_objective(objective, "lbfgs", precon=precon, gtol=gtol, maxiter=MAXITER)
        out[k] = result.iterations if result.converged else None
    return out


def main(argv: list[str] | None = None) -> int:
    args = arguments(__doc__, argv)
    rows: list[dict[str, Any]] = []
    for r, state in compressed_states(args):
        if "unjammed" in state.events:
            continue
        counts = step_iterations(state.packing, MODEL)
        rows.append({"realization": r, "delta_phi": state.delta_phi, "iterations": counts})
        print(
            f"realization {r} delta phi {state.delta_phi:.0e}: "
            + ", ".join(f"k = {k}: {v}" for k, v in counts.items()),
            file=sys.stderr,
            flush=True,
        )
    medians: dict[int, list[float]] = {k: [] for k in MODES}
    for delta in DELTA_PHIS:
        at = [row for row in rows if abs(np.log(row["delta_phi"] / delta)) < 0.5]
        for k in MODES:
            # a relaxation that did not converge counts as the limit: a lower bound
            counts = [
                MAXITER if row["iterations"][k] is None else row["iterations"][k] for row in at
            ]
            medians[k].append(float(np.median(counts)))
    title = f"2D, N = {args.n}, alpha = 2, {args.seeds} realizations of root seed 0"
    lines = [
        f"# P-L-BFGS with the softest modes deflated: {title}",
        "",
        f"Iterations of one simple-shear step of {GAMMA:g} from the relaxed state (affine start, "
        "to 1e-9 of the mean contact force) with `M^-1 = P^-1 + V (Lambda^-1 - I) V^T`, `V` the "
        "k softest generalized eigenvectors of the Hessian against the Exp matrix `P` at the "
        "state before the step (dense; k = 0: P-L-BFGS). Median over the jammed states (a "
        "state the compression left unjammed is left out), the range, and how many did not "
        f"converge within {MAXITER} iterations (counted as {MAXITER} in the median).",
        "",
        "| Delta phi | states | " + " | ".join(f"k = {k}" for k in MODES) + " |",
        "|---:|---:|" + "---:|" * len(MODES),
    ]
    for i, delta in enumerate(DELTA_PHIS):
        at = [row for row in rows if abs(np.log(row["delta_phi"] / delta)) < 0.5]
        cells = []
        for k in MODES:
            done = [row["iterations"][k] for row in at if row["iterations"][k] is not None]
            failed = len(at) - len(done)
            span = f"{min(done)}-{max(done)}" if done else "-"
            cells.append(f"{medians[k][i]:.0f} ({span}{f'; {failed} failed' if failed else ''})")
        lines.append(f"| {delta:.0e} | {len(at)} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Fitted `iterations ~ Delta phi^b` through the medians, and the median at 1e-6 over "
        "that at 1e-1:",
        "",
        "| k | b | 1e-6 / 1e-1 |",
        "|---:|---:|---:|",
    ]
    fits = {}
    for k in MODES:
        fit = fit_power_law(DELTA_PHIS, medians[k])
        ratio = medians[k][DELTA_PHIS.index(1e-6)] / medians[k][DELTA_PHIS.index(1e-1)]
        fits[k] = {"exponent": fit.exponent, "stderr": fit.stderr, "ratio": ratio}
        lines.append(f"| {k} | {fit.exponent:.3f} ± {fit.stderr:.3f} | {ratio:.1f} |")
    data = {"title": title, "modes": list(MODES), "rows": rows, "medians": medians, "fits": fits}
    save(args.output_dir, f"deflation_n{args.n}", data, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
