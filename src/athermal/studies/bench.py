"""The paper's Table benchmark (docs/benchmarks.md, B1): minimizers and preconditioners, 3 cases.

Start configurations ship with the package (``athermal/data``, see its README): N = 4096
bidisperse disks at phi = 0.8438, relaxed, alpha = 2 and 2.5. The cases:
1. radii x (1 + 5e-5); 2. simple shear gamma = 1e-4 of positions and cell; 3. every coordinate
displaced by U[-a, a], a = 1e-4 x mean diameter, ``default_rng(20240601)``. Every method runs to
``max_i |grad_i| <= 1e-9 F0``, F0 the mean contact force at the start of the case; scipy's
L-BFGS-B (m = 10) on the same compiled energy is the in-run reference.
"""

from __future__ import annotations

import statistics
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from importlib import resources

import numpy as np
import scipy.optimize

from .. import engines
from ..errors import InputError
from ..model.cell import Cell, simple_shear
from ..model.contact import ContactModel
from ..model.objective import Objective
from ..model.packing import Packing
from ..relaxation import RTOL, Minimizer, relax_objective

CASES = (1, 2, 3)
ALPHAS = (2.0, 2.5)
SCIPY = "scipy L-BFGS-B"
"""Label of the in-run reference, scipy's L-BFGS-B (m = 10) on the same compiled energy."""
METHODS = (
    Minimizer("lbfgs"),
    Minimizer("lbfgs", "exp"),
    Minimizer("lbfgs", "exp", solver="direct"),
    Minimizer("lbfgs", "exp", 3.0),
    Minimizer("cg"),
    Minimizer("cg", "exp"),
    Minimizer("fire"),
    Minimizer("lbfgs", "contact"),
    Minimizer("newton"),
)
"""The Table's methods (their :attr:`~athermal.relaxation.Minimizer.name` labels its rows);
P-L-BFGS twice, with the solver ``auto`` takes (the incomplete factor) and the exact one."""


def methods_on(backend: str) -> tuple[Minimizer, ...]:
    """The Table's :data:`METHODS` that the engine ``backend`` runs, on it (on another engine
    than the default their names end in ``(backend)``)."""
    if backend == engines.DEFAULT:
        return METHODS
    found = []
    for method in METHODS:
        try:
            found.append(replace(method, backend=backend))
        except InputError:  # what the engine has not (its capabilities)
            continue
    return tuple(found)


LABELS = (*(m.name for m in METHODS), SCIPY)
RENAMED = {"P-L-BFGS (A=0)": "P-L-BFGS"}
"""Labels of earlier versions, still accepted (with a DeprecationWarning)."""
QUICK_LABELS = ("L-BFGS", "P-L-BFGS", SCIPY)
PAPER_ITERATIONS = {  # the paper's own Table (alpha = 2.5, its hardware), cases 1 / 2 / 3
    "L-BFGS": (2003, 2749, 602),
    "P-L-BFGS": (705, 986, 380),
    "P-L-BFGS (A=3)": (813, 1351, 432),
    "FR-CG": (4574, 7306, 940),
    "P-FR-CG": (1101, 2013, 528),
}
PAPER_ALPHA = 2.5
"""The contact exponent of the paper's Table."""


@dataclass(frozen=True)
class Row:
    """One (case, alpha, method) result; ``seconds`` is the median over the repeats."""

    case: int
    alpha: float
    method: str
    iterations: int
    evaluations: int
    seconds: float
    energy: float
    grad_over_f0: float
    converged: bool


def check_alphas(alphas: Sequence[float]) -> list[float]:
    """``alphas`` as floats if the Table has a start configuration for each (:data:`ALPHAS`)."""
    out = [float(alpha) for alpha in alphas]
    for alpha in out:
        if alpha not in ALPHAS:
            have = " and ".join(f"{a:g}" for a in ALPHAS)
            raise InputError(
                f"alphas: the Table has start configurations for alpha {have}, not {alpha:g}"
            )
    return out


def reference_packing(alpha: float) -> Packing:
    """The relaxed N = 4096 start configuration for ``alpha`` (2 or 2.5)."""
    (alpha,) = check_alphas([alpha])
    name = f"table1_N4096_alpha{alpha:g}.npz"
    with resources.files("athermal.data").joinpath(name).open("rb") as handle:
        ref = np.load(handle)
        return Packing(ref["positions"], ref["radii"], Cell.box(ref["box"]))


def make_case(packing: Packing, case: int) -> Packing:
    """The start of Table case ``case`` (1, 2 or 3) from a relaxed ``packing``."""
    if case == 1:
        return packing.scale_radii(1.0 + 5e-5)
    if case == 2:
        return packing.deform(simple_shear(1e-4))
    if case == 3:
        a = 1e-4 * 2.0 * float(packing.radii.mean())
        shift = np.random.default_rng(20240601).uniform(-a, a, packing.positions.shape)
        return packing.with_positions(packing.positions + shift)
    raise InputError(f"case: must be one of {CASES}, got {case}")


def run(start: Packing, model: ContactModel, method: Minimizer | None) -> Row:
    """One minimization of ``start`` to ``1e-9 F0`` by ``method`` (None: scipy's L-BFGS-B)."""
    objective = Objective(start, model)
    f0 = objective.mean_contact_force(objective.x0)
    t0 = time.perf_counter()
    if method is None:
        res = scipy.optimize.minimize(
            objective,
            objective.x0,
            jac=True,
            method="L-BFGS-B",
            options={
                "maxcor": 10,
                "gtol": RTOL * f0 / np.sqrt(objective.dim),
                "ftol": 0.0,
                "maxiter": 50_000,
                "maxfun": 100_000,
            },
        )
        seconds = time.perf_counter() - t0
        energy, grad = objective(res.x)
        gmax = objective.max_gradient(grad)
        return Row(
            0,
            model.alpha,
            SCIPY,
            int(res.nit),
            int(res.nfev),
            seconds,
            energy,
            gmax / f0,
            gmax <= RTOL * f0,
        )
    out = relax_objective(objective, method, rtol=RTOL)
    seconds = time.perf_counter() - t0
    return Row(
        0,
        model.alpha,
        method.name,
        out.iterations,
        out.evaluations,
        seconds,
        out.energy,
        out.max_gradient / f0,
        out.converged,
    )


def table1(
    cases: Sequence[int] = CASES,
    alphas: Sequence[float] = ALPHAS,
    labels: Sequence[str] | None = None,
    repeats: int = 3,
    progress: Callable[[Row], None] | None = None,
    backend: str = engines.DEFAULT,
) -> list[Row]:
    """All rows of the Table; ``labels`` picks methods by name (default all, :data:`LABELS`;
    on another engine :func:`methods_on` and scipy's reference), ``progress`` sees each row.
    On an engine that compiles per size (its ``warm_up`` capability) each method runs once
    more first, untimed."""
    if labels is not None:
        for old in set(labels) & set(RENAMED):
            warnings.warn(
                f"methods: {old!r} is now called {RENAMED[old]!r}", DeprecationWarning, stacklevel=2
            )
        labels = [RENAMED.get(label, label) for label in labels]
    engine = engines.engine(backend)
    methods = methods_on(backend)
    by_label: dict[str, Minimizer | None] = {m.name: m for m in methods}
    by_label[SCIPY] = None
    unknown = set(labels or ()) - set(by_label)
    if unknown:
        raise InputError(f"methods: unknown {sorted(unknown)}; choose from {list(by_label)}")
    if repeats < 1:
        raise InputError(f"repeats: must be >= 1, got {repeats}")
    alphas = check_alphas(alphas)
    chosen = [label for label in by_label if labels is None or label in labels]
    warm = 1 if engine.capabilities.warm_up else 0
    rows = []
    for alpha in alphas:
        base, model = reference_packing(alpha), ContactModel(alpha)
        for case in cases:
            start = make_case(base, case)
            for label in chosen:
                skip = warm if by_label[label] is not None else 0
                runs = [run(start, model, by_label[label]) for _ in range(skip + repeats)][skip:]
                first = runs[0]
                row = Row(
                    case,
                    alpha,
                    label,
                    first.iterations,
                    first.evaluations,
                    statistics.median(r.seconds for r in runs),
                    first.energy,
                    first.grad_over_f0,
                    first.converged,
                )
                rows.append(row)
                if progress is not None:
                    progress(row)
    return rows


def markdown(rows: Sequence[Row]) -> str:
    """The rows as a markdown table: seconds relative to scipy's in the same run (where it
    ran) and, at the paper's alpha, the paper's own iteration counts."""
    ref = {(r.alpha, r.case): r.seconds for r in rows if r.method == SCIPY}
    seed_column = any(r.alpha == PAPER_ALPHA for r in rows)
    header = "| alpha | case | method | iterations | evaluations | seconds |"
    rule = "|---:|---:|---|---:|---:|---:|"
    if ref:
        header, rule = header + " s / scipy |", rule + "---:|"
    header += " final energy | max\\|grad\\| / F0 | converged |"
    rule += "---:|---:|---|"
    if seed_column:
        header, rule = header + f" paper's iterations (alpha {PAPER_ALPHA:g}) |", rule + "---:|"
    lines = [header, rule]
    for r in rows:
        cells = [
            f"{r.alpha:g}",
            str(r.case),
            r.method,
            str(r.iterations),
            str(r.evaluations),
            f"{r.seconds:.3f}",
        ]
        if ref:
            base = ref.get((r.alpha, r.case))
            cells.append(f"{r.seconds / base:.2f}" if base else "-")
        cells += [f"{r.energy:.10e}", f"{r.grad_over_f0:.2e}", "yes" if r.converged else "no"]
        if seed_column:
            seed = PAPER_ITERATIONS.get(r.method)
            cells.append(str(seed[r.case - 1]) if seed and r.alpha == PAPER_ALPHA else "-")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
