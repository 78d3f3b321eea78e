"""The long-running subcommands of ``athermal``: ``jam``, ``compress``, ``shear``, ``paper``,
``ensemble``.

Each appends every completed step to its GSD trajectory (:mod:`athermal.checkpoint`), keeps the
per-step CSV table current, shows a live line on stderr and prints a summary (``--json``: one
object on stdout). ``--resume`` continues an interrupted run from its trajectory, bit for bit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from .checkpoint import Trajectory, compression_step, jamming_step, run_id, shear_step
from .contact import ContactModel, find_contacts
from .io import read_gsd, write_gsd
from .observables import Observables, measure
from .packing import Packing, random_packing
from .protocols import (
    JAMMING_SCHEME,
    PHI_INIT,
    Minimizer,
    check_jammed,
    compression_steps,
    jamming_steps,
    log_spaced,
    scaling_exponents,
    shear_steps,
)
from .tables import Row, write_table

S = TypeVar("S")


class Progress:
    """One live line on stderr; shown only on a terminal and without ``--quiet``."""

    def __init__(self, quiet: bool) -> None:
        self.show = not quiet and sys.stderr.isatty()

    def __call__(self, text: str) -> None:
        if self.show:
            print(f"\r\033[K{text}", end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.show:
            print(file=sys.stderr, flush=True)


def model_from(args: argparse.Namespace, fallback: ContactModel | None) -> ContactModel:
    """The contact model of ``--alpha`` / ``--stiffness``, else ``fallback``'s, else the default."""
    base = fallback if fallback is not None else ContactModel()
    return ContactModel(
        alpha=base.alpha if args.alpha is None else args.alpha,
        stiffness=base.stiffness if args.stiffness is None else args.stiffness,
    )


def file_observables(obs: Observables) -> dict[str, float | np.ndarray]:
    """The observables written with a configuration."""
    return {
        "energy": obs.energy,
        "pressure": obs.pressure,
        "stress": obs.stress,
        "fabric": obs.fabric,
        "phi": obs.phi,
        "z": obs.z,
    }


def emit(summary: dict[str, Any], as_json: bool) -> None:
    """Print ``summary``: one JSON object, or aligned ``key  value`` lines."""
    if as_json:
        print(json.dumps(summary))
        return
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        print(f"{key:<{width}}  {value}")


def _minimizer(args: argparse.Namespace) -> Minimizer:
    return Minimizer(args.method, args.precon, args.A, args.solver, args.maxiter)


def _digits(bracket: float) -> int:
    """Decimals that show a number known to within ``bracket``."""
    return max(1, round(-float(np.log10(bracket)))) if 0.0 < bracket < 1.0 else 6


def _table_path(args: argparse.Namespace, trajectory: str) -> str:
    return args.table if args.table is not None else str(Path(trajectory).with_suffix(".csv"))


def _fingerprint(packing: Packing) -> str:
    """Digest of a start configuration, so a resumed run checks it starts from the same one."""
    digest = hashlib.sha256()
    for arr in (packing.positions, packing.radii, packing.cell.h):
        digest.update(np.ascontiguousarray(arr).tobytes())
    return digest.hexdigest()


def _parameters(args: argparse.Namespace, model: ContactModel, **extra: Any) -> dict[str, Any]:
    return {
        "alpha": model.alpha,
        "stiffness": model.kmat.tolist(),
        "minimizer": [args.method, args.precon, args.A, args.solver, args.maxiter],
        **extra,
    }


def _trajectory(
    args: argparse.Namespace,
    path: str,
    protocol: str,
    model: ContactModel,
    file_seed: int | None,
    **parameters: Any,
) -> Trajectory:
    """The checkpoint of this run: its identity from every parameter, ``--resume`` and
    ``--overwrite`` as given."""
    identity = run_id(protocol, _parameters(args, model, **parameters))
    return Trajectory(
        path, identity, model=model, seed=file_seed, resume=args.resume, overwrite=args.overwrite
    )


def _run(
    trajectory: Trajectory,
    resumed: list[S],
    steps: Iterable[S],
    table: str,
    row: Callable[[S], Row],
    describe: Callable[[S], str],
    quiet: bool,
) -> Iterator[S]:
    """Stream ``resumed`` then ``steps``; append and tabulate each new step as it completes."""
    progress = Progress(quiet)
    rows = [row(s) for s in resumed]
    yield from resumed
    for step in steps:
        trajectory.append(step)  # type: ignore[arg-type]
        rows.append(row(step))
        write_table(table, rows)
        progress(describe(step))
        yield step
    progress.close()
    if rows:
        write_table(table, rows)


def jam(args: argparse.Namespace) -> None:
    """``athermal jam``: random packing, jamming by growth and bisection, the jammed packing."""
    t0 = time.perf_counter()
    model = model_from(args, None)
    phi_init = PHI_INIT[args.dim] if args.phi_init is None else args.phi_init
    start = random_packing(
        args.n, phi_init, dim=args.dim, seed=args.seed, size_ratio=args.size_ratio
    )
    trajectory_path = args.trajectory or str(Path(args.output).with_suffix(".steps.gsd"))
    trajectory = _trajectory(
        args,
        trajectory_path,
        "jam",
        model,
        args.seed,
        n=args.n,
        dim=args.dim,
        size_ratio=args.size_ratio,
        seed=args.seed,
        phi_init=phi_init,
        dphi=args.dphi,
        epsilon=args.epsilon,
        scheme=JAMMING_SCHEME,
    )
    done = [jamming_step(f) for f in trajectory.frames]
    table = _table_path(args, args.output)
    steps = list(
        _run(
            trajectory,
            done,
            jamming_steps(
                start,
                model,
                dphi=args.dphi,
                epsilon=args.epsilon,
                minimizer=_minimizer(args),
                resume=done,
            ),
            table,
            lambda s: s.row(),
            lambda s: (
                f"step {s.index} {s.phase} phi {s.phi:.9f} "
                f"{'jammed' if s.jammed else 'unjammed'} E {s.energy:.3e} "
                f"iterations {s.iterations}"
            ),
            args.quiet,
        )
    )
    final = steps[-1]
    obs = measure(final.packing, model)
    check = check_jammed(final.packing, model, epsilon=args.epsilon, minimizer=_minimizer(args))
    for problem in check.problems():
        print(
            f"athermal jam: warning: the jammed packing fails a check: {problem}", file=sys.stderr
        )
    write_gsd(
        args.output,
        final.packing,
        model=model,
        seed=args.seed,
        observables={
            **file_observables(obs),
            "phi_c": final.phi,
            "phi_low": final.phi_low,
            "phi_high": final.phi_high,
        },
    )
    phi_text = f"{final.phi:.{_digits(final.bracket)}f} (bracket {final.bracket:.1g})"
    picture = None
    if args.dim == 2 and args.picture != "none":
        from .plot import packing_figure, save

        picture = args.picture or str(Path(args.output).with_suffix(".png"))
        title = f"jammed: N = {args.n}, phi_c = {phi_text}, z = {obs.z:.3f}"
        save(packing_figure(final.packing, model, title=title), picture)
    emit(
        {
            "phi_c": final.phi if args.json else phi_text,
            "phi_low": final.phi_low,
            "phi_high": final.phi_high,
            "energy": obs.energy,
            "pressure": obs.pressure,
            "z": obs.z,
            "n_rattlers": obs.n_rattlers,
            "contacts": obs.contacts,
            "excess_contacts": check.excess_contacts,
            "unjams_when_decompressed": check.unjams,
            "decompression": check.decompression,
            "stable": check.stable,
            "checks_passed": check.passed,
            "steps": len(steps),
            "resumed_steps": len(done),
            "iterations": sum(s.iterations for s in steps),
            "seconds": round(time.perf_counter() - t0, 3),
            "seed": args.seed,
            "method": _minimizer(args).label,
            "output": args.output,
            "trajectory": trajectory_path,
            "table": table,
            "picture": picture,
        },
        args.json,
    )


def _start(args: argparse.Namespace) -> tuple[Packing, ContactModel, Any]:
    frame = read_gsd(args.input)
    model = model_from(args, frame.model)
    find_contacts(frame.packing, model)  # refuses coincident particles before any work
    return frame.packing, model, frame


def compress(args: argparse.Namespace) -> None:
    """``athermal compress``: quasi-static compression of a jammed packing, with fits."""
    t0 = time.perf_counter()
    packing, model, frame = _start(args)
    phi_c = args.phi_c
    if phi_c is None and "phi_c" in frame.log:
        phi_c = float(frame.log["phi_c"].reshape(-1)[0])
    deltas = log_spaced(args.dphi_min, args.dphi_max, args.per_decade)
    trajectory = _trajectory(
        args,
        args.output,
        "compress",
        model,
        frame.seed,
        start=_fingerprint(packing),
        phi_c=phi_c,
        deltas=deltas.tolist(),
        rtol=args.rtol,
    )
    done = [compression_step(f) for f in trajectory.frames]
    table = _table_path(args, args.output)
    steps = list(
        _run(
            trajectory,
            done,
            compression_steps(
                packing,
                model,
                phi_c=phi_c,
                delta_phis=deltas,
                minimizer=_minimizer(args),
                rtol=args.rtol,
                resume=done,
            ),
            table,
            lambda s: s.row(),
            lambda s: (
                f"step {s.index + 1}/{deltas.size} delta phi {s.delta_phi:.1e} "
                f"p {s.pressure:.3e} G {s.shear_modulus:.3e} iterations {s.iterations}"
            ),
            args.quiet,
        )
    )
    fits = scaling_exponents(steps)
    laws = {
        "pressure": fits.pressure,
        "shear_modulus": fits.shear_modulus,
        "z_excess": fits.z_excess,
    }
    exponents = {
        name: None
        if fit is None
        else {
            "exponent": fit.exponent,
            "stderr": fit.stderr,
            "points": fit.points,
            "delta_phi_range": [fit.x_min, fit.x_max],
        }
        for name, fit in laws.items()
    }
    emit(
        {
            "table": table,
            "exponents": exponents,
            "phi_c": fits.phi_c,
            "phi_c_fitted": fits.phi_c_fitted if np.isfinite(fits.phi_c_fitted) else None,
            "events": fits.events,
            "steps": len(steps),
            "resumed_steps": len(done),
            "iterations": sum(s.iterations for s in steps),
            "seconds": round(time.perf_counter() - t0, 3),
            "output": args.output,
        },
        args.json,
    )


def shear(args: argparse.Namespace) -> None:
    """``athermal shear``: quasi-static simple or pure shear."""
    t0 = time.perf_counter()
    packing, model, frame = _start(args)
    trajectory = _trajectory(
        args,
        args.output,
        "shear",
        model,
        frame.seed,
        start=_fingerprint(packing),
        mode=args.mode,
        strain=args.strain,
        step=args.step,
        rtol=args.rtol,
    )
    done = [shear_step(f, model) for f in trajectory.frames]
    table = _table_path(args, args.output)
    steps = list(
        _run(
            trajectory,
            done,
            shear_steps(
                packing,
                model,
                mode=args.mode,
                strain=args.strain,
                step=args.step,
                minimizer=_minimizer(args),
                rtol=args.rtol,
                resume=done,
            ),
            table,
            lambda s: s.row(),
            lambda s: (
                f"step {s.index} strain {s.strain:.2e} tau {s.tau:.3e} "
                f"{'plastic ' if s.plastic else ''}iterations {s.iterations}"
            ),
            args.quiet,
        )
    )
    emit(
        {
            "table": table,
            "mode": args.mode,
            "steps": len(steps),
            "resumed_steps": len(done),
            "plastic_events": sum(int(s.plastic) for s in steps),
            "iterations": sum(s.iterations for s in steps),
            "seconds": round(time.perf_counter() - t0, 3),
            "output": args.output,
        },
        args.json,
    )


def paper(args: argparse.Namespace) -> None:
    """``athermal paper``: every figure, the Table and the exponents of the seed paper."""
    from .paper import FULL, QUICK, reproduce

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


def ensemble(args: argparse.Namespace) -> None:
    """``athermal ensemble``: M realizations of a protocol on Dask."""
    from .ensemble import EnsembleSpec, run_ensemble

    spec = EnsembleSpec(
        args.protocol,
        n=args.n,
        dim=args.dim,
        alpha=args.alpha,
        size_ratio=args.size_ratio,
        epsilon=args.epsilon,
        method=args.method,
        precon=args.precon,
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
    )
    progress.close()
    emit(
        {
            "realizations": result.realizations,
            "summary": result.summary,
            "computed": result.computed,
            "engine": result.engine,
            "seconds": round(result.seconds, 3),
            "files": result.files,
        },
        args.json,
    )
