"""``athermal paper``: the seed paper's figures, Table and scaling exponents, from one command.

:func:`reproduce` runs, on fresh seeded packings (``quick``: N = 1024 and a short Table;
``full``: the seed's N = 4096, all Table methods, more points and realizations):

1. the jamming protocol (P-L-BFGS, the seed's method of choice), with snapshots of the initial,
   an intermediate and the jammed configuration (disks to scale, contact forces as lines);
2. one relaxation after growing the jammed packing's radii by ``1 + 5e-5``, by L-BFGS,
   P-L-BFGS, FR-CG, P-FR-CG, FIRE and contact P-L-BFGS: ``max_i |grad_i|`` per iteration;
3. compression of the jammed packing for ``alpha = 2`` and ``2.5``: ``p``, ``G`` and
   ``z - z_iso`` against ``phi - phi_c`` with fitted exponents;
4. the iteration experiment: iterations per shear step (1e-6 ... 1e-5 in 10 steps) against
   ``Delta phi`` for L-BFGS and P-L-BFGS (and contact P-L-BFGS), mean and spread over
   realizations;
5. pure shear to 2 % with increments 4e-4, 2e-4 and 1e-4: stress and fabric, isotropic and
   deviatoric parts;
6. the Table (:mod:`athermal.bench`),

and writes PNG figures and ``report.md`` (figures, exponents beside the seed's values, the
Table) into the output directory.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import bench, plot
from .contact import ContactModel
from .errors import InputError
from .fitting import PowerLaw
from .minimize import minimize
from .objective import Objective
from .packing import random_packing
from .protocols import (
    ITERATION_METHODS,
    Minimizer,
    compression_steps,
    finite_strain_shear,
    jamming_steps,
    log_spaced,
    scaling_exponents,
    shear_steps,
)
from .protocols.compress import CompressionStep
from .tables import write_text_atomic

SEED_EXPONENTS = {"p": {2.0: 1.0, 2.5: 1.5}, "G": {2.0: 0.5, 2.5: 1.0}, "z": {2.0: 0.5, 2.5: 0.5}}
"""The exponents the seed reports (approximately) for alpha = 2 and 2.5."""
CONVERGENCE_METHODS = {
    "L-BFGS": Minimizer("lbfgs"),
    "P-L-BFGS": Minimizer("lbfgs", "exp"),
    "FR-CG": Minimizer("cg"),
    "P-FR-CG": Minimizer("cg", "exp"),
    "FIRE": Minimizer("fire"),
    "contact P-L-BFGS": Minimizer("lbfgs", "contact"),
}
SHEAR_INCREMENTS = (4e-4, 2e-4, 1e-4)


@dataclass(frozen=True)
class Settings:
    """Sizes of one reproduction (``quick`` or ``full``)."""

    n: int
    per_decade: int
    table_cases: tuple[int, ...]
    realizations: int
    realization_n: int
    table_alphas: tuple[float, ...]
    table_methods: tuple[str, ...] | None
    table_repeats: int
    shear_delta_phi: float


QUICK = Settings(
    n=1024,
    per_decade=2,
    table_cases=bench.CASES,
    realizations=3,
    realization_n=256,
    table_alphas=(2.0,),
    table_methods=("L-BFGS", "P-L-BFGS (A=0)", "FR-CG", "P-FR-CG"),
    table_repeats=1,
    shear_delta_phi=1e-2,
)
FULL = Settings(
    n=4096,
    per_decade=4,
    table_cases=bench.CASES,
    realizations=10,
    realization_n=4096,
    table_alphas=bench.ALPHAS,
    table_methods=None,
    table_repeats=3,
    shear_delta_phi=1e-2,
)


@dataclass(frozen=True)
class PaperResult:
    """Paths of what :func:`reproduce` wrote, and the fitted exponents per alpha."""

    figures: dict[str, str]
    report: str
    exponents: dict[str, dict[str, dict[str, float]]]
    phi_c: float
    seconds: float


def reproduce(
    directory: str | Path,
    settings: Settings = QUICK,
    *,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> PaperResult:
    """Run every experiment of the seed paper and write its figures and report to ``directory``."""
    t0 = time.perf_counter()
    out = Path(directory)
    if out.exists() and not out.is_dir():
        raise InputError(f"-o: {out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda text: None)
    figures: dict[str, str] = {}

    def save(name: str, figure: object) -> None:
        figures[name] = str(plot.save(figure, out / f"{name}.png"))  # type: ignore[arg-type]

    harmonic = ContactModel(2.0)
    say(f"jamming N = {settings.n}")
    jam_steps = []
    for step in jamming_steps(
        random_packing(settings.n, 0.8, seed=seed), harmonic, minimizer=Minimizer("lbfgs", "exp")
    ):
        jam_steps.append(step)
        say(f"jamming step {step.index} phi {step.phi:.7f}")
    final = jam_steps[-1]
    phi_c = final.phi
    middle = jam_steps[len(jam_steps) // 3]
    for name, step, label in (
        ("jamming_initial", jam_steps[0], "initial"),
        ("jamming_intermediate", middle, "intermediate"),
        ("jamming_jammed", final, "jammed"),
    ):
        title = f"{label}: phi = {step.phi:.6f}"
        save(name, plot.packing_figure(step.packing, harmonic, title=title))

    say("convergence of one relaxation")
    grown = final.packing.scale_radii(1.0 + 5e-5)
    histories = {}
    for label, how in CONVERGENCE_METHODS.items():
        result = minimize(
            Objective(grown, harmonic),
            how.method,
            precon=how.precon,
            rtol=1e-9,
            maxiter=how.maxiter,
        )
        histories[f"{label} ({result.iterations})"] = result.history_max_gradient
    save(
        "convergence",
        plot.convergence_figure(
            histories, title=f"N = {settings.n}, phi = {grown.phi:.6f}, radii x (1 + 5e-5)"
        ),
    )

    exponents: dict[str, dict[str, dict[str, float]]] = {}
    series: dict[str, dict[str, list[float]]] = {"p": {}, "G": {}, "z": {}}
    dphis: dict[str, list[float]] = {}
    fits: dict[str, dict[str, PowerLaw | None]] = {"p": {}, "G": {}, "z": {}}
    compressed: list[CompressionStep] = []
    for alpha in (2.0, 2.5):
        say(f"compression alpha = {alpha:g}")
        model = ContactModel(alpha)
        steps = list(
            compression_steps(
                final.packing, model, delta_phis=log_spaced(1e-7, 1e-1, settings.per_decade)
            )
        )
        if alpha == 2.0:
            compressed = steps
        scaling = scaling_exponents(steps)
        z_fit = scaling.z_excess
        label = f"alpha = {alpha:g}"
        dphis[label] = [s.delta_phi for s in steps]
        series["p"][label] = [s.pressure for s in steps]
        series["G"][label] = [s.shear_modulus for s in steps]
        series["z"][label] = [s.z_excess for s in steps]
        fits["p"][label], fits["G"][label] = scaling.pressure, scaling.shear_modulus
        fits["z"][label] = z_fit
        exponents[f"{alpha:g}"] = {
            key: {
                "exponent": fit.exponent,
                "stderr": fit.stderr,
                "seed": SEED_EXPONENTS[key][alpha],
            }
            for key, fit in (("p", scaling.pressure), ("G", scaling.shear_modulus), ("z", z_fit))
            if fit is not None
        }
    for key, ylabel in (("p", "pressure p"), ("G", "shear modulus G"), ("z", r"$z - z_{iso}$")):
        save(
            f"scaling_{key}",
            plot.scaling_figure(
                dphis, series[key], fits[key], ylabel=ylabel, title=f"N = {settings.n}"
            ),
        )

    say("iteration experiment")
    points = log_spaced(1e-6, 1e-1, 1)
    counts: dict[str, list[list[float]]] = {k: [[] for _ in points] for k in ITERATION_METHODS}
    for realization in range(settings.realizations):
        start = random_packing(settings.realization_n, 0.8, seed=seed + 1 + realization)
        jammed = list(jamming_steps(start, harmonic))[-1]
        compression = compression_steps(jammed.packing, harmonic, delta_phis=points)
        for k, state in enumerate(compression):
            for label, minimizer in ITERATION_METHODS.items():
                fs = finite_strain_shear(state.packing, harmonic, minimizer=minimizer)
                counts[label][k].append(float(np.mean(fs.iterations)))
            say(f"iterations: realization {realization}, delta phi {state.delta_phi:.0e}")
    save(
        "iterations",
        plot.iterations_figure(
            list(points),
            counts,
            title=f"N = {settings.realization_n}, {settings.realizations} realizations",
        ),
    )

    say("pure shear")
    sheared_from = min(
        compressed, key=lambda s: abs(np.log(s.delta_phi / settings.shear_delta_phi))
    )
    curves = {}
    for increment in SHEAR_INCREMENTS:
        shear_rows = [
            s.row()
            for s in shear_steps(
                sheared_from.packing, harmonic, mode="pure", strain=0.02, step=increment
            )
        ]
        curves[f"step {increment:g}"] = {
            key: [float(r[key]) for r in shear_rows]
            for key in ("strain", "stress_iso", "stress_dev", "fabric_iso", "fabric_dev")
        }
        say(f"pure shear, increment {increment:g}")
    save(
        "pure_shear",
        plot.shear_figure(
            curves,
            title=f"pure shear, N = {settings.n}, phi - phi_c = {sheared_from.delta_phi:.0e}",
        ),
    )

    say("Table")
    table = bench.markdown(
        bench.table1(
            cases=settings.table_cases,
            alphas=settings.table_alphas,
            labels=settings.table_methods,
            repeats=settings.table_repeats,
        )
    )
    report = _report(out, settings, phi_c, exponents, figures, table, time.perf_counter() - t0)
    return PaperResult(
        figures=figures,
        report=str(report),
        exponents=exponents,
        phi_c=phi_c,
        seconds=time.perf_counter() - t0,
    )


def _report(
    out: Path,
    settings: Settings,
    phi_c: float,
    exponents: dict[str, dict[str, dict[str, float]]],
    figures: dict[str, str],
    table: str,
    seconds: float,
) -> Path:
    lines = [
        "# Wang & Zhang, reproduced by athermal",
        "",
        f"N = {settings.n} (iteration experiment: N = {settings.realization_n}, "
        f"{settings.realizations} realizations); phi_c = {phi_c:.7f} (epsilon = 1e-6); "
        f"{seconds:.0f} s in all.",
        "",
        "## Scaling exponents",
        "",
        "| alpha | quantity | fitted | seed |",
        "|---:|---|---:|---:|",
    ]
    for alpha, per in exponents.items():
        for key, fit in per.items():
            lines.append(
                f"| {alpha} | {key} | {fit['exponent']:.3f} ± {fit['stderr']:.3f} | "
                f"{fit['seed']:g} |"
            )
    lines += ["", "## Figures", ""]
    lines += [f"![{name}]({Path(path).name})" for name, path in figures.items()]
    lines += ["", "## Table", "", table]
    path = out / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path
