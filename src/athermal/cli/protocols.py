"""The protocol subcommands: ``jam``, ``compress`` and ``shear``.

Each appends every completed step to its GSD trajectory (:mod:`athermal.studies.checkpoint`), keeps
the per-step CSV table current, shows a live line on stderr and prints a summary (``--json``: one
object on stdout). ``--resume`` continues an interrupted run from its trajectory, bit for bit.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import asdict
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from .. import engines
from ..certify.bisection import MARCH_BITS, float64_epsilon
from ..errors import InputError
from ..io import Frame, count_frames, read_gsd
from ..model.contact import ContactModel, find_contacts
from ..model.packing import Packing
from ..protocols import (
    JAMMING_SCHEME,
    compression_steps,
    log_spaced,
    scaling_exponents,
    shear_steps,
    start_fraction,
)
from ..protocols.compress import FIT_LAWS
from ..protocols.events import BranchState, CycleEnd, PlasticEvent
from ..protocols.pressure import check_reachable
from ..protocols.shear import check_mode, rough_walls
from ..studies.checkpoint import (
    Step,
    Trajectory,
    compression_step,
    fingerprint,
    jamming_step,
    run_id,
    shear_step,
)
from ..studies.experiments import JamSpec, jam_packing
from ..studies.jammed import finish_jamming
from ..studies.plasticity import PlasticitySpec, run_plasticity
from ..studies.tables import Row, write_table
from .common import (
    NotConverged,
    Progress,
    bits,
    check_certified,
    minimizer_from,
    model_from,
    precon_from,
    sizes_from,
)
from .printer import emit

S = TypeVar("S", bound=Step)


class _Recorder(Generic[S]):
    """Appends each completed step to the trajectory, rewrites the table, shows progress."""

    def __init__(
        self,
        args: argparse.Namespace,
        trajectory: Trajectory,
        resumed: list[S],
        describe: Callable[[S], str],
    ) -> None:
        self.trajectory, self.describe = trajectory, describe
        self.table = _table_path(args, args.output)
        self.steps = list(resumed)
        self.rows: list[Row] = [s.row() for s in resumed]
        self.progress = Progress(args.quiet)

    def __call__(self, step: S) -> None:
        self.trajectory.append(step)
        self.steps.append(step)
        self.rows.append(step.row())
        write_table(self.table, self.rows)
        self.progress(self.describe(step))

    def run(self, steps: Iterable[S]) -> list[S]:
        """Record every step of ``steps``; return all, the resumed ones first."""
        for step in steps:
            self(step)
        return self.close()

    def close(self) -> list[S]:
        self.progress.close()
        if self.rows:
            write_table(self.table, self.rows)
        return self.steps


def _digits(bracket: float) -> int:
    """Decimals that show a number known to within ``bracket``."""
    return max(1, round(-float(np.log10(bracket)))) if 0.0 < bracket < 1.0 else 6


def _table_path(args: argparse.Namespace, output: str) -> str:
    return args.table if args.table is not None else str(Path(output).with_suffix(".csv"))


def _trajectory(
    args: argparse.Namespace,
    path: str,
    protocol: str,
    model: ContactModel,
    file_seed: int | None,
    glued: NDArray[np.bool_] | None = None,
    **parameters: Any,
) -> Trajectory:
    """The checkpoint of this run: its identity from every parameter, ``--resume`` and
    ``--overwrite`` as given; ``glued`` marks plane shear's glued particles in every frame."""
    identity = run_id(
        protocol,
        {
            "alpha": model.alpha,
            "stiffness": model.kmat.tolist(),
            "minimizer": [args.method, precon_from(args), args.A, args.solver, args.maxiter]
            + ([] if args.backend == engines.DEFAULT else [args.backend]),
            **parameters,
        },
    )
    return Trajectory(
        path,
        identity,
        model=model,
        seed=file_seed,
        resume=args.resume,
        overwrite=args.overwrite,
        glued=glued,
    )


def jam(args: argparse.Namespace) -> None:
    """``athermal jam``: random packing, jamming by growth and bisection, the jammed packing."""
    t0 = time.perf_counter()
    model = model_from(args, None)
    phi_init = (
        start_fraction(args.dim, bool(args.walls)) if args.phi_init is None else args.phi_init
    )
    spec = JamSpec(
        n=args.n,
        dim=args.dim,
        alpha=model.alpha,
        stiffness=float(model.stiffness),
        **sizes_from(args),
        phi_init=phi_init,
        dphi=args.dphi,
        epsilon=float64_epsilon(args.epsilon),
        protocol=args.bisection,
        minimizer=minimizer_from(args),
        walls=args.walls,
    )
    if args.pressure is not None and not args.resume:  # before the first file
        check_reachable(spec.start(args.seed), model, args.pressure, spec.minimizer)
    trajectory_path = args.trajectory or str(Path(args.output).with_suffix(".steps.gsd"))
    trajectory = _trajectory(
        args,
        trajectory_path,
        "jam",
        model,
        args.seed,
        spec=asdict(spec),  # the run is its spec, as an ensemble's realization is
        seed=args.seed,
        scheme=JAMMING_SCHEME,
    )
    done = [jamming_step(f) for f in trajectory.frames]
    record = _Recorder(
        args,
        trajectory,
        done,
        lambda s: (
            f"step {s.index} {s.phase} phi {s.phi:.9f} {'jammed' if s.jammed else 'unjammed'} "
            f"E {s.energy:.3e} iterations {s.iterations}"
        ),
    )
    result = jam_packing(spec, args.seed, resume=done, on_step=record)
    record.close()
    kept = finish_jamming(
        result,
        model,
        epsilon=args.epsilon,
        pressure=args.pressure,
        pressure_rtol=args.pressure_rtol,
        minimizer=spec.minimizer,
        certifying=args.certify,
        march=Path(trajectory_path).with_suffix(".march.npz"),
        resume=args.resume,
    )
    kept.write(args.output, model, args.seed)
    obs, final, certified = kept.observables, kept.packing, kept.certified
    phi_c, phi_low = kept.phi_c, kept.phi_low
    width = phi_c - phi_low
    phi_text = f"{phi_c:.{_digits(width)}f} (bracket {width:.1g})"
    picture = None
    if args.dim == 2 and args.picture != "none":
        from ..studies.picture import packing_figure
        from ..studies.plot import save

        picture = args.picture or str(Path(args.output).with_suffix(".png"))
        state = "jammed" if args.pressure is None else f"at p = {obs.pressure:.4g}"
        title = (
            f"{state}: N = {args.n}, alpha = {model.alpha:g}\n"
            f"phi_c = {phi_text}, z = {obs.z:.3f} (rattlers removed)"
        )
        save(packing_figure(final, model, title=title), picture)
    bound = (lambda phi: phi) if args.json else (lambda phi: f"{phi:.{_digits(width) + 2}f}")
    relaxed = bits(spec.minimizer, args.n, args.dim)  # the float64 jam's
    emit(
        {
            "phi_c": phi_c if args.json else phi_text,
            "phi_low": bound(phi_low),
            "phi_high": bound(phi_c),
            "protocol": args.bisection,
            "written": kept.written,
            "energy": obs.energy,
            "pressure": obs.pressure,
            "z": obs.z,
            "n_rattlers": obs.n_rattlers,
            "contacts": obs.contacts,
            **kept.at_pressure(),
            "jamming_check": kept.jamming_check(),
            "checks_passed": result.check.passed,
            **({} if certified is None else {"certificate": asdict(certified.certificate)}),
            **({"bisected_in_double_double": kept.bisected} if kept.bisected else {}),
            **({} if kept.refused is None else {"certificate": {"refused": kept.refused}}),
            "steps": result.steps,
            "resumed_steps": len(done),
            "iterations": result.iterations,
            "seconds": round(time.perf_counter() - t0, 3),
            "seed": args.seed,
            "method": spec.minimizer.label,
            "bits": f"{MARCH_BITS}; its float64 jam: {relaxed}" if kept.bisected else relaxed,
            "output": args.output,
            "trajectory": trajectory_path,
            "table": record.table,
            "picture": picture,
        },
        args.json,
    )
    if certified is not None:
        check_certified(certified.certificate)
    if kept.refused is not None:
        raise NotConverged(
            f"not certified ({kept.refused}); the jammed packing is written uncertified"
        )


def _frame_index(args: argparse.Namespace) -> int:
    """The input frame that ``--frame`` or ``--delta-phi`` names (default: the last)."""
    count = count_frames(args.input)
    target = getattr(args, "delta_phi", None)
    if target is not None:
        logged = []
        for k in range(count):
            log = read_gsd(args.input, frame=k).log
            if "delta_phi" in log:
                logged.append((abs(np.log(float(log["delta_phi"]) / target)), k))
        if not logged:
            raise InputError(f"--delta-phi: {args.input} logs no delta_phi (not a compression)")
        return min(logged)[1]
    frame = -1 if args.frame is None else args.frame
    if not -count <= frame < count:
        raise InputError(f"--frame: {args.input} has {count} frames, no frame {frame}")
    return frame % count


def _start(args: argparse.Namespace) -> tuple[Packing, ContactModel, Frame, int]:
    index = _frame_index(args)
    frame = read_gsd(args.input, frame=index)
    model = model_from(args, frame.model)
    find_contacts(frame.packing, model)  # refuses coincident particles before any work
    if hasattr(args, "backend"):
        engines.check(args.backend, walls=bool(frame.packing.cell.walls))
    return frame.packing, model, frame, index


def compress(args: argparse.Namespace) -> None:
    """``athermal compress``: quasi-static compression of a jammed packing, with fits."""
    t0 = time.perf_counter()
    packing, model, frame, index = _start(args)
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
        start=fingerprint(packing),
        phi_c=phi_c,
        deltas=deltas.tolist(),
        rtol=args.rtol,
    )
    done = [compression_step(f) for f in trajectory.frames]
    record = _Recorder(
        args,
        trajectory,
        done,
        lambda s: (
            f"step {s.index + 1}/{deltas.size} delta phi {s.delta_phi:.1e} "
            f"p {s.pressure:.3e} G {s.shear_modulus:.3e} iterations {s.iterations}"
        ),
    )
    steps = record.run(
        compression_steps(
            packing,
            model,
            phi_c=phi_c,
            delta_phis=deltas,
            minimizer=minimizer_from(args),
            rtol=args.rtol,
            resume=done,
            from_unjammed=args.from_unjammed,
        )
    )
    fits = scaling_exponents(steps)
    laws = {name: getattr(fits, name) for name in FIT_LAWS}
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
            "table": record.table,
            "exponents": exponents,
            "phi_c": fits.phi_c,
            "phi_c_fitted": fits.phi_c_fitted if np.isfinite(fits.phi_c_fitted) else None,
            "events": fits.events,
            "left_out": fits.left_out,
            "left_basin_at_delta_phi": fits.left_basin,
            "frame": index,
            "steps": len(steps),
            "resumed_steps": len(done),
            "iterations": sum(s.iterations for s in steps),
            "seconds": round(time.perf_counter() - t0, 3),
            "bits": bits(minimizer_from(args), frame.packing.n, frame.packing.dim),
            "output": args.output,
        },
        args.json,
    )


def shear(args: argparse.Namespace) -> None:
    """``athermal shear``: quasi-static simple or pure shear, uniaxial compression or plane
    shear."""
    t0 = time.perf_counter()
    packing, model, frame, index = _start(args)
    if args.events or args.cycles is not None:
        _plastic(args, packing, model, frame, index, t0)
        return
    check_mode(args.mode, args.strain, packing.cell, args.wall_layer)
    logged_g = frame.log.get("shear_modulus")
    if logged_g is not None and float(logged_g.reshape(-1)[0]) < 0.0:
        warnings.warn(
            f"frame {index} is unstable to shear at fixed cell (its logged shear modulus "
            f"{float(logged_g.reshape(-1)[0]):.3g} < 0): the shear starts with a rearrangement",
            stacklevel=2,
        )
    frozen = None
    if args.mode == "plane":  # refused here, before the trajectory is claimed
        lower, upper = rough_walls(packing, args.wall_layer)
        frozen = lower | upper
    trajectory = _trajectory(
        args,
        args.output,
        "shear",
        model,
        frame.seed,
        glued=frozen,
        start=fingerprint(packing),
        mode=args.mode,
        strain=args.strain,
        step=args.step,
        rtol=args.rtol,
        **({"wall_layer": args.wall_layer} if args.mode == "plane" else {}),
    )
    done = [shear_step(f, model, frozen) for f in trajectory.frames]
    record = _Recorder(
        args,
        trajectory,
        done,
        lambda s: (
            f"step {s.index} strain {s.strain:.2e} tau {s.tau:.3e} "
            f"{'plastic ' if s.plastic else ''}iterations {s.iterations}"
        ),
    )
    steps = record.run(
        shear_steps(
            packing,
            model,
            mode=args.mode,
            strain=args.strain,
            step=args.step,
            minimizer=minimizer_from(args),
            rtol=args.rtol,
            resume=done,
            wall_layer=args.wall_layer,
        )
    )
    start_log = {k: float(v) for k, v in frame.log.items() if k in ("phi", "phi_c", "delta_phi")}
    emit(
        {
            "table": record.table,
            "mode": args.mode,
            "frame": index,
            "start": start_log,
            "steps": len(steps),
            "resumed_steps": len(done),
            "plastic_events": sum(int(s.plastic) for s in steps),
            "iterations": sum(s.iterations for s in steps),
            "seconds": round(time.perf_counter() - t0, 3),
            "bits": bits(minimizer_from(args), frame.packing.n, frame.packing.dim),
            "output": args.output,
        },
        args.json,
    )


def _plastic(
    args: argparse.Namespace,
    packing: Packing,
    model: ContactModel,
    frame: Frame,
    index: int,
    t0: float,
) -> None:
    """``athermal shear --events`` or ``--cycles``: AQS with exact plastic events
    (:func:`athermal.studies.plasticity.run_plasticity`)."""
    cyclic = args.cycles is not None
    check_mode(args.mode, args.amplitude if cyclic else args.strain, packing.cell, args.wall_layer)
    spec = PlasticitySpec(
        mode=args.mode,
        strain=args.strain,
        step=args.step,
        max_step=args.max_step,
        tol=args.tol,
        amplitude=args.amplitude,
        cycles=args.cycles,
        minimizer=minimizer_from(args),
        wall_layer=args.wall_layer,
    )

    def show(item: BranchState | PlasticEvent | CycleEnd) -> None:
        if args.quiet or args.json:
            return
        if isinstance(item, PlasticEvent):
            print(
                f"event {item.index} at strain {item.strain:.10f}: stress drop "
                f"{item.stress_drop:.3e}, energy drop {item.energy_drop:.3e}, "
                f"{item.moved:.1f} particles moved",
                file=sys.stderr,
                flush=True,
            )
        elif isinstance(item, CycleEnd):
            again = "" if item.repeats is None else f", repeats cycle {item.cycle - item.repeats}"
            print(
                f"cycle {item.cycle}: {item.events} events, energy {item.state.energy:.6e}{again}",
                file=sys.stderr,
                flush=True,
            )

    run = run_plasticity(
        packing,
        model,
        spec,
        args.output,
        seed=frame.seed,
        overwrite=args.overwrite,
        resume=args.resume,
        on_item=show,
    )
    figure = None
    if args.figure != "none":
        from ..studies.plot import save

        title = f"N = {packing.n}, {args.mode} shear, {len(run.events)} events"
        figure = save(run.figure(title), args.figure or Path(args.output).with_suffix(".png"))
    start_log = {k: float(v) for k, v in frame.log.items() if k in ("phi", "phi_c", "delta_phi")}
    emit(
        {
            "mode": args.mode,
            "frame": index,
            "start": start_log,
            **run.summary(),
            "seconds": round(time.perf_counter() - t0, 3),
            "output": args.output,
            **{f"table_{k}": v for k, v in run.files.items() if k != "trajectory"},
            **({} if figure is None else {"figure": str(figure)}),
        },
        args.json,
    )
