"""Why the iterations of every preconditioned method grow towards jamming, and what Newton-CG's
depend on: the spectrum of the preconditioned Hessian (issue 12, "measure why").

For jammed packings of the iteration experiment (``--cache``, realizations of root seed 0)
compressed to each Delta phi:

1. the generalized eigenvalues of ``H v = lambda P v`` at the relaxed state (dense, ``N d``
   square), ``H`` the Hessian (:meth:`athermal.model.objective.Objective.hessian`), for ``P = I``
   (L-BFGS, FIRE), the Exp preconditioner (A = 0, P-L-BFGS) and the contact preconditioner;
   without the zero modes (translations, rattlers: :data:`ZERO`; their count is checked
   against ``d (n_rattlers + 1)``), the smallest ``lambda_min``, the largest ``lambda_max`` and
   the condition number ``kappa`` of what is left, and ``kappa ~ Delta phi^c`` fitted over the
   realizations' geometric means; and the participation ratio of ``H``'s softest mode,
   ``(sum_i |u_i|^2)^2 / (N' sum_i |u_i|^4)`` over the ``N'`` non-rattlers: about 1/2 for a
   plane wave, ``<< 1`` for a localized mode;
2. one simple-shear step of 1e-6 from the relaxed state, started affinely and relaxed by
   Newton-CG, and one of 1e-8 (the contact network holds): the contacts that changed and the
   eigenvalues of ``H(end) v = lambda M v``, ``M = H(start) + SHIFT_MIN kappa_d I``
   (Newton's factor as it would be built at the start; ``kappa_d`` the mean positive diagonal
   of ``H``), without ``H(end)``'s zero modes: how many lie outside ``[1/2, 2]``, the ones CG
   on the lagged factor has to find one by one.

A state a compression step left unjammed (its ``"unjammed"`` event,
:func:`athermal.protocols.compress.is_unjammed`) is reported and left out, as is a step that
ends unjammed.

    python -m benchmarks.spectrum --n 1024 --seeds 10
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from matplotlib.figure import Figure
from numpy.typing import NDArray

from athermal.analysis.fitting import fit_power_law
from athermal.analysis.observables import rattlers
from athermal.engines.precon import ContactPreconditioner, ExpPreconditioner
from athermal.minimize.newton import SHIFT_MIN
from athermal.model.cell import simple_shear
from athermal.model.contact import ContactModel, find_contacts
from athermal.model.objective import Objective
from athermal.model.packing import Packing
from athermal.protocols.compress import CompressionStep
from athermal.relaxation import force_tolerance, minimize_objective
from athermal.studies import plot
from athermal.studies.experiments import JamSpec, child_seeds, compression_steps
from benchmarks.machine import pin, save
from benchmarks.physics import EPSILON, GROWTH, RESULTS, jammed

MODEL = ContactModel(2.0)
"""The contact law of the packings (harmonic)."""
DELTA_PHIS = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
PRECONDITIONERS = ("none", "exp", "contact")
LABELS = {"none": "P = I (L-BFGS)", "exp": "Exp (P-L-BFGS)", "contact": "contact"}
STEPS = (1e-6, 1e-8)
OUTLIER = 2.0
"""Eigenvalues of ``M^-1 H(end)`` beyond this factor from 1 count as outliers."""
LOWEST = 100
"""The smallest kept eigenvalues (over the largest) a state holds for its soft-mode count (at
most 50 lie below the 1e-1 floor here)."""
CURVE_POINTS = 200
"""Points of each cumulative spectrum kept for the figure (log-spaced in rank)."""
ZERO = 1e-11
"""Generalized eigenvalues within this fraction of the largest are zero modes (translations,
rattlers): round-off leaves them below 1e-14 of it here, the softest physical mode is above
1e-8."""


def pair_set(packing: Packing, model: ContactModel) -> set[tuple[int, int]]:
    """The contacts of ``packing`` as pairs ``(i, j)``."""
    contacts = find_contacts(packing, model)
    return set(zip(contacts.i.tolist(), contacts.j.tolist(), strict=True))


def n_rattlers(packing: Packing, model: ContactModel) -> int:
    """The rattlers of ``packing`` (:func:`~athermal.analysis.observables.rattlers`)."""
    return int(rattlers(find_contacts(packing, model), packing.n, packing.dim).sum())


def hessian(packing: Packing, model: ContactModel) -> tuple[Objective, np.ndarray]:
    """The objective (caller's particle order) and the dense Hessian at ``packing``."""
    obj = Objective(packing, model, sort=False)
    return obj, obj.hessian(obj.x0).matrix().toarray()


def preconditioner(name: str, obj: Objective) -> np.ndarray:
    """The dense ``(N d, N d)`` matrix ``P`` of ``name`` at ``obj.x0``."""
    if name == "none":
        return np.eye(obj.n_dof)
    precon = (ExpPreconditioner if name == "exp" else ContactPreconditioner)(obj, solver="direct")
    precon.update(obj.x0)
    matrix = precon.matrix
    assert matrix is not None
    if matrix.shape[0] == obj.n:
        matrix = sp.kron(matrix, sp.eye(obj.dim))
    return np.asarray(matrix.toarray())


def spectrum(h: np.ndarray, p: np.ndarray) -> dict[str, Any]:
    """The generalized eigenvalues of ``(h, p)`` without the zero modes (:data:`ZERO`): their
    range, ``kappa``, how many were dropped, and the largest dropped and smallest kept relative
    to the largest (the gap)."""
    values = scipy.linalg.eigh(h, p, eigvals_only=True)
    top = float(values[-1])
    zero = np.abs(values) <= ZERO * top
    kept = values[~zero]
    return {
        "zeros": int(zero.sum()),
        "lambda_min": float(kept[0]),
        "lambda_max": top,
        "kappa": top / float(kept[0]),
        "largest_dropped": float(np.abs(values[zero]).max()) / top if zero.any() else 0.0,
        "smallest_kept": float(kept[0]) / top,
        "values": kept / top,
        "lowest": (kept[:LOWEST] / top).tolist(),
    }


def cumulative(values: NDArray[np.float64]) -> dict[str, list[float]]:
    """The fraction of ``values`` (ascending) at or below each of :data:`CURVE_POINTS` of them,
    log-spaced in rank: the curve of the figure, 4 significant digits."""
    ranks = np.unique(np.geomspace(1, values.size, CURVE_POINTS).round().astype(int))
    return {
        "value": [float(f"{v:.4g}") for v in values[ranks - 1]],
        "fraction": [float(f"{f:.4g}") for f in ranks / values.size],
    }


def softest_participation(h: np.ndarray, zeros: int, live: int, dim: int) -> float:
    """The participation ratio, over ``live`` particles, of the eigenvector of ``h`` just above
    its ``zeros`` zero modes."""
    _, vector = scipy.linalg.eigh(h, subset_by_index=[zeros, zeros])
    weight = (vector[:, 0] ** 2).reshape(-1, dim).sum(axis=1)
    return float(weight.sum() ** 2 / (live * (weight**2).sum()))


def step_outliers(packing: Packing, model: ContactModel, gamma: float) -> dict[str, float] | None:
    """One shear step of ``gamma`` relaxed by Newton-CG from the affine start, and the
    eigenvalues of ``H(end)`` against Newton's factor built at the start (module doc, part 2);
    None when the step ends unjammed (every particle a rattler)."""
    obj, h0 = hessian(packing, model)
    sheared = packing.deform(simple_shear(gamma, packing.dim))
    gtol = force_tolerance(sheared, model, 1e-9)
    end = minimize_objective(Objective(sheared, model), "newton", gtol=gtol).packing
    _, h1 = hessian(end, model)
    diagonal = np.diag(h0)
    kappa_d = float(diagonal[diagonal > 0.0].mean())
    m = h0 + SHIFT_MIN * kappa_d * np.eye(obj.n_dof)
    values = scipy.linalg.eigh(h1, m, eigvals_only=True)
    values = values[np.abs(values) > ZERO]  # M ~ H: the nonzero ones are of order 1
    if values.size == 0:
        return None
    outside = (values < 1.0 / OUTLIER) | (values > OUTLIER)
    return {
        "gamma": gamma,
        "changed": len(pair_set(packing, model) ^ pair_set(end, model)),
        "outliers": int(outside.sum()),
        "below": int((values < 1.0 / OUTLIER).sum()),
        "above": int((values > OUTLIER).sum()),
        "min": float(values.min()),
        "max": float(values.max()),
    }


def count_soft_modes(rows: list[dict[str, Any]]) -> None:
    """Replace each jammed row's ``lowest`` eigenvalues under each preconditioner by
    ``soft_modes``: how many lie below the smallest of the same realization at 1e-1 (None
    without a jammed state there)."""
    for row in rows:
        top = [r for r in rows if r["realization"] == row["realization"] and r["delta_phi"] > 0.05]
        for name in PRECONDITIONERS:
            lowest = np.array(row[name].pop("lowest"))
            floor = top[0][name]["smallest_kept"] if top else None
            row[name]["soft_modes"] = None if floor is None else int(np.sum(lowest < floor))


def geometric_mean(values: list[float]) -> float:
    """Of the finite ``values`` (an unjammed state's are NaN)."""
    return float(np.exp(np.nanmean(np.log(values))))


def figure(data: dict[str, Any], path: Path) -> None:
    """``kappa`` against Delta phi per preconditioner (left) and the spectra of realization 0
    at three Delta phi (right)."""
    fig = Figure(figsize=(10, 4), layout="constrained")
    left, right = fig.subplots(1, 2)
    deltas = np.array(data["delta_phi"])
    colors = {"none": "tab:blue", "exp": "tab:red", "contact": "tab:green"}
    for name in PRECONDITIONERS:
        kappas = np.array(data["kappa"][name])  # (realizations, deltas)
        for row in kappas:
            left.loglog(deltas, row, ".", color=colors[name], alpha=0.4)
        fit = data["fits"][name]
        left.loglog(
            deltas,
            fit["prefactor"] * deltas ** fit["exponent"],
            "-",
            color=colors[name],
            label=f"{LABELS[name]}: $\\kappa \\sim \\Delta\\phi^{{{fit['exponent']:.2f}}}$",
        )
    left.set_xlabel(r"$\Delta\phi$")
    left.set_ylabel(r"$\kappa(P^{-1}H)$ without zero modes")
    left.legend(fontsize=8)
    styles = {1e-6: "-", 1e-3: "--", 1e-1: ":"}
    for name in PRECONDITIONERS:
        for delta, style in styles.items():
            if f"{delta:.0e}" not in data["spectra"][name]:  # unjammed there
                continue
            curve = data["spectra"][name][f"{delta:.0e}"]
            right.loglog(
                curve["value"],
                curve["fraction"],
                style,
                color=colors[name],
                label=f"{name}, {delta:.0e}",
            )
    right.set_xlabel(r"$\lambda / \lambda_{max}$ of $H v = \lambda P v$")
    right.set_ylabel("fraction of eigenvalues below")
    right.legend(fontsize=7, ncol=3)
    fig.suptitle(data["title"], fontsize=9)
    plot.save(fig, path, dpi=110)


def arguments(doc: str, argv: list[str] | None) -> argparse.Namespace:
    """The command line of this script and of ``deflation.py`` (pins the process)."""
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--n", type=int, default=1024)
    parser.add_argument("--seeds", type=int, default=10, help="realizations of root seed 0")
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument("--cache", type=Path, default=Path(__file__).parent / "cache")
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    pin(args.core)
    return args


def compressed_states(args: argparse.Namespace) -> Iterator[tuple[int, CompressionStep]]:
    """``(realization, state)``: the jammed packings of ``args`` (N, realizations of root seed
    0, from the cache) compressed to each of :data:`DELTA_PHIS`; an unjammed state is said on
    stderr."""
    spec = JamSpec(args.n, 2, MODEL.alpha, dphi=GROWTH, epsilon=EPSILON)
    for k, seed in enumerate(child_seeds(0, args.seeds)):
        packing, phi_c, _ = jammed(args.cache, spec, seed)
        for state in compression_steps(packing, MODEL, phi_c=phi_c, delta_phis=DELTA_PHIS):
            if "unjammed" in state.events:
                print(f"realization {k} delta phi {state.delta_phi:.0e}: unjammed", file=sys.stderr)
            yield k, state


def main(argv: list[str] | None = None) -> int:
    args = arguments(__doc__, argv)
    kappa: dict[str, list[list[float]]] = {
        name: [[] for _ in range(args.seeds)] for name in PRECONDITIONERS
    }
    rows: list[dict[str, Any]] = []
    spectra: dict[str, dict[str, dict[str, list[float]]]] = {n: {} for n in PRECONDITIONERS}
    for k, state in compressed_states(args):
        row: dict[str, Any] = {"realization": k, "delta_phi": state.delta_phi}
        row["unjammed"] = "unjammed" in state.events
        rows.append(row)
        if row["unjammed"]:
            for name in PRECONDITIONERS:
                kappa[name][k].append(float("nan"))
            continue
        obj, h = hessian(state.packing, MODEL)
        rattling = n_rattlers(state.packing, MODEL)
        row["expected_zeros"] = obj.dim * (rattling + 1)  # translations and rattlers
        for name in PRECONDITIONERS:
            result = spectrum(h, preconditioner(name, obj))
            values = result.pop("values")
            if k == 0:
                spectra[name][f"{state.delta_phi:.0e}"] = cumulative(values)
            row[name] = result
            kappa[name][k].append(result["kappa"])
        row["participation"] = softest_participation(
            h, row["none"]["zeros"], obj.n - rattling, obj.dim
        )
        row["steps"] = [step_outliers(state.packing, MODEL, g) for g in STEPS]
        print(
            f"realization {k} delta phi {state.delta_phi:.0e}: "
            + ", ".join(f"{n} kappa {row[n]['kappa']:.3g}" for n in PRECONDITIONERS)
            + f", softest mode's participation {row['participation']:.3f}"
            + "; "
            + ", ".join(
                f"step {s['gamma']:g}: {s['changed']} changed, {s['outliers']} outliers"
                for s in row["steps"]
                if s is not None
            ),
            file=sys.stderr,
            flush=True,
        )
    jammed_rows = [r for r in rows if not r["unjammed"]]
    count_soft_modes(jammed_rows)
    fits = {}
    for name in PRECONDITIONERS:
        means = [geometric_mean(list(col)) for col in zip(*kappa[name], strict=True)]
        fit = fit_power_law(DELTA_PHIS, means)
        fits[name] = {"exponent": fit.exponent, "stderr": fit.stderr}
        fits[name]["prefactor"] = fit.prefactor
    title = f"2D, N = {args.n}, alpha = 2, {args.seeds} realizations of root seed 0"
    lines = [
        f"# The spectrum of the preconditioned Hessian near jamming: {title}",
        "",
        "Generalized eigenvalues of `H v = lambda P v` at the relaxed compressed state, without "
        f"the zero modes (|lambda| <= {ZERO:g} lambda_max); `kappa = lambda_max / lambda_min` "
        "of the rest "
        "(geometric mean over the jammed states, range in brackets; a compression step of a "
        "decade can unjam a packing of this size, whose phi_c spreads by about 1e-3, and such "
        "states are left out of every figure here). The gap: the largest "
        "dropped eigenvalue and the smallest kept, over lambda_max (worst over all states).",
        "",
        "| Delta phi | jammed states | "
        + " | ".join(f"kappa, {LABELS[n]}" for n in PRECONDITIONERS)
        + " | participation of H's softest mode |",
        "|---:|---:|" + "---:|" * (len(PRECONDITIONERS) + 1),
    ]
    for i, delta in enumerate(DELTA_PHIS):
        at = [r for r in jammed_rows if abs(np.log(r["delta_phi"] / delta)) < 0.5]
        cells = [f"{len(at)} of {args.seeds}"]
        for name in PRECONDITIONERS:
            col = [kappa[name][r][i] for r in range(args.seeds)]
            cells.append(f"{geometric_mean(col):.3g} ({np.nanmin(col):.3g}-{np.nanmax(col):.3g})")
        ratio = [r["participation"] for r in at]
        cells.append(f"{np.mean(ratio):.3f} ({min(ratio):.3f}-{max(ratio):.3f})")
        lines.append(f"| {delta:.0e} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Fitted `kappa ~ Delta phi^c` through the geometric means, 1e-7 ... 1e-1 (CG's "
        "iteration bound, `sqrt(kappa)`, then goes as `Delta phi^(c/2)`):",
        "",
        "| P | c | c / 2 | largest dropped / lambda_max | smallest kept / lambda_max | "
        "states with zero modes other than d (n_rattlers + 1) |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for name in PRECONDITIONERS:
        dropped = max(r[name]["largest_dropped"] for r in jammed_rows)
        kept = min(r[name]["smallest_kept"] for r in jammed_rows)
        other = [
            f"{r['delta_phi']:.0e} (realization {r['realization']}): {r[name]['zeros']} "
            f"against {r['expected_zeros']}"
            for r in jammed_rows
            if r[name]["zeros"] != r["expected_zeros"]
        ]
        fit = fits[name]
        lines.append(
            f"| {LABELS[name]} | {fit['exponent']:.3f} ± {fit['stderr']:.3f} | "
            f"{0.5 * fit['exponent']:.3f} | {dropped:.1e} | {kept:.1e} | "
            f"{'; '.join(other) if other else 'none'} |"
        )
    lines += [
        "",
        "Soft modes: the eigenvalues (over lambda_max) of each state below the smallest of its "
        "own realization at 1e-1, the modes a deflation (a coarse space of them) would take "
        "out of the preconditioned iteration to give it the conditioning it has at 1e-1 "
        f"(counted among the {LOWEST} smallest); mean over the realizations (range):",
        "",
        "| Delta phi | " + " | ".join(LABELS[n] for n in PRECONDITIONERS) + " |",
        "|---:|" + "---:|" * len(PRECONDITIONERS),
    ]
    for delta in DELTA_PHIS:
        cells = []
        for name in PRECONDITIONERS:
            counts = [
                r[name]["soft_modes"]
                for r in jammed_rows
                if abs(np.log(r["delta_phi"] / delta)) < 0.5 and r[name]["soft_modes"] is not None
            ]
            cells.append(f"{np.mean(counts):.1f} ({min(counts)}-{max(counts)})" if counts else "-")
        lines.append(f"| {delta:.0e} | " + " | ".join(cells) + " |")
    unjammed_steps = sum(step is None for r in jammed_rows for step in r["steps"])
    lines += [
        "",
        "One simple-shear step from each state, relaxed by Newton-CG from the affine start: "
        "contacts changed between start and end, and the eigenvalues of `H(end) v = "
        f"lambda M v` (M = H(start) + {SHIFT_MIN:g} kappa_d I, zero modes of H(end) left out) "
        f"outside [1/{OUTLIER:g}, {OUTLIER:g}] (below / above), mean over the realizations "
        f"(range); steps that ended unjammed: {unjammed_steps}:",
        "",
        "| Delta phi | "
        + " | ".join(f"gamma {g:g}: changed | outliers (below / above)" for g in STEPS)
        + " |",
        "|---:|" + "---:|---:|" * len(STEPS),
    ]
    for delta in DELTA_PHIS:
        at = [r for r in jammed_rows if abs(np.log(r["delta_phi"] / delta)) < 0.5]
        cells = []
        for s in range(len(STEPS)):
            steps = [r["steps"][s] for r in at if r["steps"][s] is not None]
            changed = [step["changed"] for step in steps]
            out = [step["outliers"] for step in steps]
            below = np.mean([step["below"] for step in steps])
            above = np.mean([step["above"] for step in steps])
            cells.append(
                f"{np.mean(changed):.1f} ({min(changed)}-{max(changed)}) | "
                f"{np.mean(out):.1f} ({min(out)}-{max(out)}; {below:.1f} / {above:.1f})"
            )
        lines.append(f"| {delta:.0e} | " + " | ".join(cells) + " |")
    data = {
        "title": title,
        "seeds": child_seeds(0, args.seeds),
        "delta_phi": list(DELTA_PHIS),
        "kappa": kappa,
        "fits": fits,
        "rows": rows,
        "spectra": spectra,
    }
    name = f"spectrum_n{args.n}"
    args.output_dir.mkdir(parents=True, exist_ok=True)
    figure(data, args.output_dir / f"{name}.png")
    lines += ["", f"Figure: `{name}.png`."]
    save(args.output_dir, name, data, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
