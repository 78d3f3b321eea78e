"""The quick subcommands: ``random``, ``measure``, ``relax`` and ``bench``."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from .. import engines
from ..analysis.forces import ForceStatistics, force_statistics
from ..analysis.observables import Observables, file_observables, measure
from ..enthalpy import relax_at_pressure
from ..io import count_frames, read_gsd, write_gsd
from ..minimize import MinimizeResult
from ..model.packing import random_packing
from ..relaxation import RTOL, relax_once
from ..studies import bench as table1
from ..studies.checkpoint import readable_log
from ..studies.plot import force_distribution_figure, save
from .common import (
    NotConverged,
    bits,
    cell_from,
    minimizer_from,
    model_from,
    sizes_from,
)
from .printer import emit


def _observables(obs: Observables, as_json: bool) -> dict[str, Any]:
    """The observables as printed: ``--json`` keeps the contract's keys and full precision;
    plain text names each with its unit (docs/quantities.md)."""
    if as_json:
        return obs.to_dict()
    return {
        "particles": f"{obs.n} in {obs.dim}D",
        "packing fraction phi": repr(float(obs.phi)),
        "energy E": obs.energy,
        "pressure p": obs.pressure,
        "shear stress -sigma_xy": obs.shear_stress,
        "stress iso / dev": f"{obs.stress_iso:.6g} / {obs.stress_dev:.6g}",
        "fabric iso / dev": f"{obs.fabric_iso:.6g} / {obs.fabric_dev:.6g}",
        "contacts": obs.contacts,
        "rattlers": obs.n_rattlers,
        "z (rattlers removed)": obs.z,
        "max |grad_i|": obs.max_gradient,
        **(
            {"wall pressure": "  ".join(f"{w} {p:.6g}" for w, p in obs.wall_pressure.items())}
            if obs.walls
            else {}
        ),
    }


def _exact(value: Any) -> Any:
    """A logged float as text with every digit (integers without a decimal point)."""
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() and abs(value) < 2**53 else repr(value)
    return value


def random(args: argparse.Namespace) -> None:
    """``athermal random``: a random packing and its observables."""
    model = model_from(args, None)
    start = time.perf_counter()
    packing = random_packing(
        args.n, args.phi, seed=args.seed, cell=cell_from(args), **sizes_from(args)
    )
    obs = measure(packing, model)
    write_gsd(args.output, packing, model=model, seed=args.seed, observables=file_observables(obs))
    extra = {
        "seed": args.seed,
        "output": args.output,
        "seconds": round(time.perf_counter() - start, 4),
    }
    emit({**_observables(obs, args.json), **extra}, args.json)


def measure_file(args: argparse.Namespace) -> None:
    """``athermal measure``: the observables of one frame and what its writer logged."""
    frame = read_gsd(args.input, frame=args.frame)
    index = args.frame % count_frames(args.input)  # as the file counts them, not -1
    model = model_from(args, frame.model)
    obs = measure(frame.packing, model)
    forces = force_statistics(frame.packing, model)
    if args.forces_figure is not None:
        figure = force_distribution_figure(
            {f"{forces.contacts} contacts": (forces.counts, forces.overflow)},
            title=f"{Path(args.input).name}, frame {index}: N = {obs.n}, phi = {obs.phi:.6f}",
        )
        save(figure, args.forces_figure)
    logged = {
        key: value.item() if value.ndim == 0 else value.tolist()
        for key, value in frame.log.items()
        if value.size <= 3 and key not in ("phi",)
    }
    if not args.json:  # every digit; counts as integers; a step's codes as its table's text
        text = readable_log(frame.log)
        logged = {
            k: _exact(v) if isinstance(text[k], np.ndarray) else text[k] or "none"
            for k, v in logged.items()
        }
    emit(
        {
            **_observables(obs, args.json),
            **_forces(forces, args.json),
            "alpha": model.alpha,
            "frame": index,
            "log": logged,
        },
        args.json,
    )


def _forces(forces: ForceStatistics, as_json: bool) -> dict[str, Any]:
    """The force statistics as printed: ``--json`` has them all under ``forces``."""
    if as_json:
        return {"forces": forces.to_dict()}
    tail = forces.tail
    return {
        "force tail decay (f/<f> >= 1)": "-"
        if tail is None
        else f"{tail.decay:.3f} ± {tail.stderr:.3f} over {tail.x_min:.2f} ... {tail.x_max:.2f}",
        "anisotropy contacts / forces": f"{forces.contact_anisotropy:.4g} / "
        f"{forces.force_anisotropy:.4g}",
    }


def relax(args: argparse.Namespace) -> None:
    """``athermal relax``: one energy minimization."""
    frame = read_gsd(args.input)
    model = model_from(args, frame.model)
    at_pressure: dict[str, Any] = {}
    res: MinimizeResult
    if args.pressure is None:
        relaxed = relax_once(
            frame.packing, model, minimizer_from(args), gtol=args.gtol, rtol=args.rtol
        )
        res, final = relaxed, relaxed.packing
    else:
        found = relax_at_pressure(
            frame.packing,
            model,
            args.pressure,
            cell=args.cell,
            method=args.method,
            precon=args.precon or "none",
            gtol=args.gtol,
            rtol=RTOL if args.gtol is None and args.rtol is None else args.rtol,
            maxiter=args.maxiter,
        )
        res, final = found.result, found.packing
        at_pressure = {
            "target_pressure": found.target,
            "cell": args.cell,
            "deformation": found.deformation.tolist(),
            "enthalpy": res.energy,
        }
    obs = measure(final, model)
    write_gsd(args.output, final, model=model, seed=frame.seed, observables=file_observables(obs))
    summary = {
        "method": res.method,
        "precon": res.precon,
        "bits": bits(minimizer_from(args), frame.packing.n, frame.packing.dim)
        if args.pressure is None
        else "portable",
        "converged": res.converged,
        "message": res.message,
        "iterations": res.iterations,
        "evaluations": res.evaluations,
        "seconds": round(res.seconds, 6),
        "energy": res.energy,
        "max_gradient": res.max_gradient,
        "gtol": res.gtol,
        **at_pressure,
        "output": args.output,
    }
    if at_pressure:  # the objective's value was the enthalpy; energy is the observables'
        del summary["energy"]
    elif not args.json:  # printed with the observables already
        del summary["energy"], summary["max_gradient"]
    emit({**_observables(obs, args.json), **summary}, args.json)
    if not res.converged:
        raise NotConverged(f"did not converge: {res.message}")


def bench(args: argparse.Namespace) -> None:
    """``athermal bench``: the paper's Table."""
    if args.quick:
        args.cases, args.alphas, args.repeats = [3], [2.0], 1
        args.methods = [
            f"{label} ({args.backend})"
            if args.backend != engines.DEFAULT and label != table1.SCIPY
            else label
            for label in table1.QUICK_LABELS
        ]
    show = not args.quiet and sys.stderr.isatty()

    def progress(row: table1.Row) -> None:
        if show:
            print(
                f"alpha {row.alpha:g} case {row.case} {row.method}: {row.iterations} "
                f"iterations, {row.seconds:.2f} s",
                file=sys.stderr,
                flush=True,
            )

    rows = table1.table1(
        args.cases, args.alphas, args.methods, args.repeats, progress, args.backend
    )
    if args.json:
        emit({"rows": [dataclasses.asdict(r) for r in rows]}, True)
    else:
        print(table1.markdown(rows), end="")
