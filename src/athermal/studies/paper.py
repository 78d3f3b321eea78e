"""``athermal paper``: the paper's figures, Table and scaling exponents, from one command.

:func:`reproduce` runs, on fresh seeded packings (``quick``: N = 1024 and a short Table;
``full``: the paper's N = 4096, all Table methods, more points and realizations):

1. the jamming protocol (P-L-BFGS, the paper's method of choice): one figure with the initial,
   an intermediate and the jammed configuration (disks to scale, contact forces as lines on
   one absolute scale, rattlers marked);
2. one relaxation after growing the jammed packing's radii by ``1 + 5e-5``, by L-BFGS,
   P-L-BFGS, FR-CG, P-FR-CG, FIRE and contact P-L-BFGS: ``max_i |grad_i|`` per iteration;
3. compression of the jammed packing, and of ``scaling_packings - 1`` more, for ``alpha = 2``
   and ``2.5``: ``p``, ``G`` and ``z - z_iso`` against ``phi - phi_c`` with exponents fitted
   to every packing's points pooled, and their spread over single packings;
4. the iteration experiment: iterations per shear step (1e-6 ... 1e-5 in 10 steps) against
   ``Delta phi`` for L-BFGS and P-L-BFGS (and contact P-L-BFGS), mean and spread over
   realizations;
5. pure shear to 2 % with increments 4e-4, 2e-4 and 1e-4: stress and fabric, isotropic and
   deviatoric parts;
6. the Table (:mod:`athermal.studies.bench`),

and writes PNG figures and ``report.md`` (figures with captions, exponents with their fit
windows beside the paper's values, warnings when a fit failed or a check did not pass, the
Table) into the output directory. Every study is an :mod:`athermal.studies.experiments` call.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..analysis.fitting import PowerLaw
from ..atomic import write_text
from ..errors import InputError
from ..model.contact import ContactModel
from ..model.packing import Packing
from ..protocols import EPSILON, JammingResult
from ..protocols.compress import (
    FINITE_SIZE,
    FIT_LAWS,
    RESOLVED_CONTACTS,
    fit_reasons,
    pooled_fit,
)
from ..relaxation import RTOL
from . import bench, picture, plot
from .experiments import (
    Compression,
    CompressSpec,
    ConvergenceSpec,
    IterationSpec,
    JamSpec,
    ShearSpec,
    child_seeds,
    compress,
    convergence,
    iteration_counts,
    jam_packing,
    shear,
)

PAPER_EXPONENTS = {"p": {2.0: 1.0, 2.5: 1.5}, "G": {2.0: 0.5, 2.5: 1.0}, "z": {2.0: 0.5, 2.5: 0.5}}
"""The exponents the paper reports (approximately) for alpha = 2 and 2.5."""
SHEAR_INCREMENTS = (4e-4, 2e-4, 1e-4)
HARMONIC = ContactModel(2.0)
"""The paper's contacts, harmonic with k = 1 (:class:`~athermal.studies.experiments.JamSpec`'s
default model)."""
STRESS_UNIT = r"$k\,\ell^{\alpha-2}$"
"""Unit of stresses and moduli in 2D: stiffness k times the length unit to the alpha - 2."""
QUANTITIES = {
    "p": (f"pressure $p$ ({STRESS_UNIT})", "pressure"),
    "G": (f"shear modulus $G$ ({STRESS_UNIT})", "shear modulus (linear response)"),
    "z": (r"$z - z_{iso}$ (contacts per particle)", "excess coordination z - z_iso"),
}


@dataclass(frozen=True)
class Settings:
    """Sizes of one reproduction (``quick`` or ``full``): ``scaling_packings`` jammed packings
    of ``n`` (the main one and more) are compressed for the scaling laws."""

    n: int
    per_decade: int
    table_cases: tuple[int, ...]
    realizations: int
    realization_n: int
    table_alphas: tuple[float, ...]
    table_methods: tuple[str, ...] | None
    table_repeats: int
    shear_delta_phi: float
    scaling_packings: int


QUICK = Settings(
    n=1024,
    per_decade=2,
    table_cases=bench.CASES,
    realizations=3,
    realization_n=256,
    table_alphas=(2.0,),
    table_methods=("L-BFGS", "P-L-BFGS", "FR-CG", "P-FR-CG", bench.SCIPY),
    table_repeats=1,
    shear_delta_phi=1e-2,
    scaling_packings=4,
)
"""The default run (``athermal paper``, ``--quick``): N = 1024, the Table at alpha = 2, minutes."""
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
    scaling_packings=1,
)
"""``athermal paper --full``: the paper's N = 4096, every Table method and alpha, hours."""


@dataclass(frozen=True)
class PaperResult:
    """Paths of what :func:`reproduce` wrote, and the fitted exponents per alpha."""

    figures: dict[str, str]
    report: str
    exponents: dict[str, dict[str, dict[str, Any]]]
    phi_c: float
    seconds: float


@dataclass
class _Record:
    """What :func:`reproduce` writes as it goes: the figures (path by name), their captions and
    the warnings of the report, and where progress goes."""

    out: Path
    say: Callable[[str], None]
    figures: dict[str, str] = field(default_factory=dict)
    captions: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def save(self, name: str, figure: object, caption: str) -> None:
        """Write ``figure`` as ``name.png`` with its caption."""
        self.figures[name] = str(plot.save(figure, self.out / f"{name}.png"))  # type: ignore[arg-type]
        self.captions[name] = caption


def reproduce(
    directory: str | Path,
    settings: Settings = QUICK,
    *,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> PaperResult:
    """Run every experiment of the paper and write its figures and report to ``directory``.

    The main packing has the seed of realization 0 of root ``seed``, the iteration
    experiment's realizations those of 1 ... (:func:`~athermal.studies.experiments.child_seeds`).
    """
    t0 = time.perf_counter()
    out = Path(directory)
    if out.exists() and not out.is_dir():
        raise InputError(f"-o: {out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    record = _Record(out, progress or (lambda text: None))
    seeds = child_seeds(seed, settings.realizations + settings.scaling_packings)
    jammed = _jamming(record, settings, seeds[0])
    _convergence(record, settings, jammed)
    starts = [(jammed.packing, jammed.phi_c)]
    spec = JamSpec(n=settings.n)
    for k, extra in enumerate(seeds[1 + settings.realizations :]):
        record.say(f"jamming packing {k + 2} of {settings.scaling_packings} for the scaling laws")
        more = jam_packing(spec, extra)
        if not more.check.passed:
            record.warnings.append(
                f"scaling packing {k + 2} fails a check: " + "; ".join(more.check.problems())
            )
        starts.append((more.packing, more.phi_c))
    exponents, compressed = _scaling(record, settings, starts)
    _iterations(record, settings, seeds[1 : 1 + settings.realizations])
    _pure_shear(record, settings, compressed)
    record.say("Table")
    table = bench.markdown(
        bench.table1(
            cases=settings.table_cases,
            alphas=settings.table_alphas,
            labels=settings.table_methods,
            repeats=settings.table_repeats,
        )
    )
    report = _report(
        out,
        settings,
        jammed.phi_c,
        exponents,
        record.figures,
        record.captions,
        record.warnings,
        table,
        time.perf_counter() - t0,
    )
    return PaperResult(
        figures=record.figures,
        report=str(report),
        exponents=exponents,
        phi_c=jammed.phi_c,
        seconds=time.perf_counter() - t0,
    )


def _jamming(record: _Record, settings: Settings, seed: int) -> JammingResult:
    """The main packing jammed, and the figure of its protocol."""
    spec = JamSpec(n=settings.n)
    record.say(f"jamming N = {settings.n}")
    jammed = jam_packing(
        spec, seed, on_step=lambda s: record.say(f"jamming step {s.index} phi {s.phi:.7f}")
    )
    if not jammed.check.passed:
        record.warnings.append(
            "the jammed packing fails a check: " + "; ".join(jammed.check.problems())
        )
    phi_c, history = jammed.phi_c, jammed.history
    snapshots = [("initial", history[0]), ("intermediate", history[len(history) // 3])]
    snapshots.append(("jammed", history[-1]))
    record.save(
        "jamming",
        picture.jamming_figure(
            [(f"{label}, phi = {s.phi:.6f}", s.packing) for label, s in snapshots],
            spec.model,
            title=f"jamming, N = {settings.n}, alpha = 2",
        ),
        f"The jamming protocol (growth by {spec.dphi:g}, bisection to epsilon = {spec.epsilon:g}): "
        "(a) the random "
        "start, (b) a relaxed intermediate state, (c) the jammed packing at phi_c = "
        f"{phi_c:.7f}. Disks to scale (small light, large dark, rattlers open); contact "
        "forces as lines whose width is proportional to the force on one absolute scale for "
        "the three panels, so an unjammed state shows no force chains.",
    )
    return jammed


def _convergence(record: _Record, settings: Settings, jammed: JammingResult) -> None:
    """One relaxation of the grown jammed packing by each method, and its figure."""
    record.say("convergence of one relaxation")
    conv_spec = ConvergenceSpec()
    conv = convergence(jammed.packing, HARMONIC, conv_spec)
    record.save(
        "convergence",
        plot.convergence_figure(
            {f"{k} ({len(v) - 1})": v for k, v in conv.histories.items()},
            title=f"N = {settings.n}, alpha = 2, radii x (1 + {conv_spec.growth:g})",
            tolerance=conv.tolerance,
        ),
        f"One relaxation after growing the radii of the jammed packing by 1 + "
        f"{conv_spec.growth:g} (phi = {conv.start.phi:.6f}): the largest force on a particle "
        f"against the iteration, to {conv_spec.rtol:g} of the mean contact force (dashed "
        "line); the legend gives each method's iterations.",
    )


def _scaling(
    record: _Record, settings: Settings, starts: list[tuple[Packing, float]]
) -> tuple[dict[str, dict[str, dict[str, Any]]], Compression]:
    """The scaling laws: each start compressed from its own jamming point at alpha = 2 and 2.5,
    p, G and z - z_iso fitted over the packings pooled (as the paper's figures average
    realizations: one packing of N = 1024 resolves z - z_iso over three decades, where single
    packings' exponents scatter by 0.02-0.03, docs/jamming.md), and their figures. Returns the
    exponents by alpha and the first packing's harmonic compression."""
    exponents: dict[str, dict[str, dict[str, Any]]] = {}
    series: dict[str, dict[str, list[float]]] = {key: {} for key in QUANTITIES}
    dphis: dict[str, list[float]] = {}
    fits: dict[str, dict[str, PowerLaw | None]] = {key: {} for key in QUANTITIES}
    used: dict[str, dict[str, list[bool]]] = {key: {} for key in QUANTITIES}
    references: dict[str, dict[str, float]] = {key: {} for key in QUANTITIES}
    compress_spec = CompressSpec(per_decade=settings.per_decade)
    compressions = {}
    for alpha in (2.0, 2.5):
        model = ContactModel(alpha)
        pooled = []
        for k, (start, start_phi_c) in enumerate(starts):
            record.say(f"compression alpha = {alpha:g}, packing {k + 1} of {len(starts)}")
            pooled.append(compress(start, model, start_phi_c, compress_spec))
        compressions[alpha] = pooled[0]
        label = f"alpha = {alpha:g}"
        dphis[label] = [s.delta_phi for one in pooled for s in one.steps]
        series["p"][label] = [s.pressure for one in pooled for s in one.steps]
        series["G"][label] = [s.shear_modulus for one in pooled for s in one.steps]
        series["z"][label] = [s.z_excess for one in pooled for s in one.steps]
        step_rows = [[s.row() for s in one.steps] for one in pooled]
        exponents[f"{alpha:g}"] = {}
        for key, column in zip(QUANTITIES, FIT_LAWS, strict=True):
            references[key][label] = PAPER_EXPONENTS[key][alpha]
            used[key][label] = [
                why is None
                for rows in step_rows
                for why in fit_reasons(rows, column, compress_spec.fit_lower)
            ]
            try:
                fit: PowerLaw | None = pooled_fit(step_rows, column, compress_spec.fit_lower)
            except InputError:
                fit = None
            fits[key][label] = fit
            left_out = dict(sum((Counter(one.fits.left_out[column]) for one in pooled), Counter()))
            if fit is None:
                record.warnings.append(
                    f"alpha = {alpha:g}: no fit of {QUANTITIES[key][1]} (fewer than 3 points "
                    f"left; left out: {left_out})"
                )
                continue
            single = [f.exponent for one in pooled if (f := getattr(one.fits, column)) is not None]
            exponents[f"{alpha:g}"][key] = {
                "exponent": fit.exponent,
                "stderr": fit.stderr,
                "points": fit.points,
                "packings": len(pooled),
                "single_packing_sd": float(np.std(single, ddof=1)) if len(single) > 1 else None,
                "delta_phi_min": fit.x_min,
                "delta_phi_max": fit.x_max,
                "left_out": left_out,
                "paper": PAPER_EXPONENTS[key][alpha],
            }
        events = dict(sum((Counter(one.fits.events) for one in pooled), Counter()))
        if events:
            record.warnings.append(
                f"alpha = {alpha:g}: compression events "
                + ", ".join(f"{k} ({v} step{'s' if v > 1 else ''})" for k, v in events.items())
            )
    for key, (ylabel, what) in QUANTITIES.items():
        record.save(
            f"scaling_{key}",
            plot.scaling_figure(
                dphis,
                series[key],
                fits[key],
                ylabel=ylabel,
                title=f"N = {settings.n}, 2D",
                reference_slopes=references[key],
                phi_c_note=f"{len(starts)} packing(s), each from its own $\\phi_c$",
                used=used[key],
            ),
            f"The {what} against phi - phi_c of {len(starts)} packing(s), each from the phi_c of "
            "its own jamming protocol (not fitted), for alpha = 2 and 2.5, the fits to their "
            "points pooled. Filled markers are the fitted points, open ones were left out: the "
            f"fits take Delta phi >= {compress_spec.fit_lower:g}, p and G where Delta phi N^2 >= "
            f"{FINITE_SIZE:g} (a finite packing's scaling regime), z - z_iso where it counts at "
            f"least {RESOLVED_CONTACTS} contacts, and no step from the first unjammed one on (the "
            "report lists what each fit left out); solid lines are the fits, dotted ones the "
            "paper's slopes.",
        )

    return exponents, compressions[2.0]


def _iterations(record: _Record, settings: Settings, seeds: list[int]) -> None:
    """The paper's iteration experiment over the realizations of ``seeds``, and its figure."""
    record.say("iteration experiment")
    iter_spec = IterationSpec()
    counts: dict[str, list[list[float]]] = {
        m.name: [[] for _ in iter_spec.delta_phis] for m in iter_spec.methods
    }
    small = JamSpec(n=settings.realization_n)
    for realization, seed in enumerate(seeds):
        packing = jam_packing(small, seed)
        result = iteration_counts(packing.packing, HARMONIC, packing.phi_c, iter_spec)
        for name, per_point in result.iterations.items():
            for k, value in enumerate(per_point):
                counts[name][k].append(value)
        record.say(f"iterations: realization {realization} done")
    record.save(
        "iterations",
        plot.iterations_figure(
            list(iter_spec.delta_phis),
            counts,
            title=f"N = {settings.realization_n}, alpha = 2, {settings.realizations} realizations",
            error="sd",
        ),
        "The paper's iteration experiment: mean iterations per quasi-static simple-shear step "
        "(strain 1e-6 ... 1e-5 in 10 steps, to 1e-9 of the mean contact force) against "
        "phi - phi_c; error bars are the standard deviation over realizations.",
    )


def _pure_shear(record: _Record, settings: Settings, compressed: Compression) -> None:
    """The paper's pure shear from the compressed state nearest ``settings.shear_delta_phi``
    at its three increments, and the figure."""
    record.say("pure shear")
    curves = {}
    start_dphi = float("nan")
    for increment in SHEAR_INCREMENTS:
        run = shear(
            compressed,
            HARMONIC,
            ShearSpec(mode="pure", strain=0.02, step=increment, delta_phi=settings.shear_delta_phi),
        )
        start_dphi = run.delta_phi
        rows = [s.row() for s in run.steps]
        curves[f"step {increment:g}"] = {
            key: [float(r[key]) for r in rows]
            for key in ("strain", "stress_iso", "stress_dev", "fabric_iso", "fabric_dev")
        }
        record.say(f"pure shear, increment {increment:g}")
    record.save(
        "pure_shear",
        plot.shear_figure(
            curves, title=f"pure shear, N = {settings.n}, alpha = 2, phi - phi_c = {start_dphi:.0e}"
        ),
        "The paper's shear test: pure shear to 2 % strain in increments 4e-4, 2e-4 and 1e-4 "
        f"from the compressed state at phi - phi_c = {start_dphi:.1e}; isotropic (mean "
        "eigenvalue) and deviatoric ((lambda_max - lambda_min) / 2) parts of the stress and the "
        "fabric, each on its own axis. The curves agree when the increments are quasi-static.",
    )


def _report(
    out: Path,
    settings: Settings,
    phi_c: float,
    exponents: dict[str, dict[str, dict[str, Any]]],
    figures: dict[str, str],
    captions: dict[str, str],
    warnings_: list[str],
    table: str,
    seconds: float,
) -> Path:
    lines = [
        "# Wang & Zhang, reproduced by athermal",
        "",
        f"N = {settings.n} (iteration experiment: N = {settings.realization_n}, "
        f"{settings.realizations} realizations); phi_c = {phi_c:.7f} (epsilon = {EPSILON:g}); "
        f"{seconds:.0f} s in all. Units: unit cell, stiffness k = 1; stresses and moduli in "
        "k l^(alpha - 2).",
        "",
    ]
    if warnings_:
        lines += ["## Warnings", ""] + [f"- {w}" for w in warnings_] + [""]
    lines += [
        "## Scaling exponents",
        "",
        f"Fits of y = a (phi - phi_c)^b to the points of {settings.scaling_packings} "
        "packing(s) pooled, each compressed from its own jamming protocol's phi_c, each fit "
        "over the steps its rules take (`athermal.protocols.compress.fit_points`); 'single sd' "
        "is the spread of the exponent fitted to each packing alone, the last column says how "
        "many steps the fits left out, and why.",
        "",
        "| alpha | quantity | fitted ± stderr | single sd | points | Delta phi range | paper "
        "| left out |",
        "|---:|---|---:|---:|---:|---|---:|---|",
    ]
    for alpha, per in exponents.items():
        for key, fit in per.items():
            lines.append(
                f"| {alpha} | {key} | {fit['exponent']:.3f} ± {fit['stderr']:.3f} | "
                + ("-" if fit["single_packing_sd"] is None else f"{fit['single_packing_sd']:.3f}")
                + f" | {fit['points']:.0f} | {fit['delta_phi_min']:.1e} ... "
                f"{fit['delta_phi_max']:.1e} | {fit['paper']:g} | "
                + ("; ".join(f"{n} {why}" for why, n in fit["left_out"].items()) or "none")
                + " |"
            )
    lines += ["", "## Figures", ""]
    for name, figure in figures.items():
        lines += [f"![{name}]({Path(figure).name})", "", f"*{name}.* {captions[name]}", ""]
    lines += [
        "## Table",
        "",
        f"Each method to {RTOL:g} of the mean contact force; seconds on this machine, and "
        "relative to scipy's L-BFGS-B in the same run.",
        "",
        table,
    ]
    path = out / "report.md"
    write_text(path, "\n".join(lines) + "\n")
    return path
