"""The study subcommands: ``paper`` (the paper's figures and Table) and ``ensemble``."""

from __future__ import annotations

import argparse
from typing import Any

from ..relaxation import Minimizer
from ..studies.avalanches import EventsSpec
from ..studies.experiments import CompressSpec, JamSpec, ShearSpec
from .common import Progress, precon_from, sizes_from
from .printer import emit


def paper(args: argparse.Namespace) -> None:
    """``athermal paper``: every figure, the Table and the exponents of the paper."""
    from ..studies.paper import FULL, QUICK, reproduce

    progress = Progress(args.quiet)
    settings = FULL if args.full else QUICK
    result = reproduce(args.output, settings, seed=args.seed, progress=progress)
    progress.close()
    emit(
        {
            "figures": result.figures,
            "report": result.report,
            "exponents": result.exponents,
            "phi_c": result.phi_c,
            "seconds": round(result.seconds, 1),
        },
        args.json,
    )


COMPRESS = {"delta_min": "dphi_min", "delta_max": "dphi_max", "per_decade": "per_decade"}
"""The compression spec's fields by the options of ``ensemble compress`` and ``shear``."""
SHEAR = {"mode": "mode", "strain": "strain", "step": "step", "delta_phi": "shear_delta_phi"}
"""The shear spec's fields by the options of ``ensemble shear``."""
EVENTS = {
    **SHEAR,
    "tol": "tol",
    "max_step": "max_step",
    "transient": "transient",
    "amplitudes": "amplitudes",
    "cycles": "cycles",
}
"""The events spec's fields by the options of ``ensemble events`` and ``ensemble cycles``."""


def _spec_options(args: argparse.Namespace, fields: dict[str, str]) -> dict[str, Any]:
    """The spec fields of ``fields`` that the protocol's parser has options for (the others keep
    the spec's defaults)."""
    return {name: getattr(args, dest) for name, dest in fields.items() if hasattr(args, dest)}


def _events_options(args: argparse.Namespace) -> dict[str, Any]:
    """The events spec's fields given (``ensemble events``, ``cycles``); amplitudes a tuple."""
    if args.protocol not in ("events", "cycles"):
        return {}
    given = _spec_options(args, EVENTS)
    if "amplitudes" in given:
        given["amplitudes"] = tuple(given["amplitudes"])
    return given


def ensemble(args: argparse.Namespace) -> None:
    """``athermal ensemble``: M realizations of a protocol on Dask."""
    from ..studies.ensemble import EnsembleSpec, run_ensemble

    engine = Minimizer(backend=args.backend)  # the compression's and shear's
    spec = EnsembleSpec(
        args.protocol,
        jam=JamSpec(
            n=args.n,
            dim=args.dim,
            alpha=args.alpha,
            **sizes_from(args),
            dphi=args.dphi,
            epsilon=args.epsilon,
            protocol=args.bisection,
            minimizer=Minimizer(args.method, precon_from(args), backend=args.backend),  # type: ignore[arg-type]
            walls=args.walls,
        ),
        compress=CompressSpec(minimizer=engine, **_spec_options(args, COMPRESS)),
        shear=ShearSpec(minimizer=engine, **_spec_options(args, SHEAR)),
        events=EventsSpec(minimizer=engine, **_events_options(args)),
    )
    progress = Progress(args.quiet)
    result = run_ensemble(
        spec,
        args.output,
        args.realizations,
        seed=args.seed,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=progress,
        batch=args.batch,
    )
    progress.close()
    emit(
        {
            "realizations": [r.to_json() for r in result.realizations]
            if args.json
            else len(result.realizations),
            "summary": result.summary,
            "computed": result.computed,
            "engine": result.engine,
            "seconds": round(result.seconds, 3),
            "files": result.files,
        },
        args.json,
    )
