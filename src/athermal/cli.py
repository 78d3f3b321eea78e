"""The ``athermal`` command (see docs/contract.md): ``random``, ``measure``, ``relax``, ``bench``,
and the protocols ``jam``, ``compress`` and ``shear``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

from . import bench, commands
from .door import check_request
from .errors import ConvergenceError, InputError
from .io import read_gsd, write_gsd
from .minimize import METHODS, PRECONDITIONERS, minimize
from .objective import Objective
from .observables import Observables, measure
from .packing import random_packing
from .protocols import SHEAR_MODES


def _add_model_options(parser: argparse.ArgumentParser, default: float | None) -> None:
    parser.add_argument(
        "--alpha",
        type=float,
        default=default,
        help="contact exponent alpha >= 2 (2 = Hooke, 2.5 = Hertz)"
        + ("" if default is not None else "; default: the file's, else 2"),
    )
    parser.add_argument(
        "--stiffness",
        type=float,
        default=None,
        help="contact stiffness k (default: the file's, else 1)",
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )


def _add_minimizer_options(
    parser: argparse.ArgumentParser, what: str, maxiter: int = 100_000, precon: str = "none"
) -> None:
    parser.add_argument(
        "--method",
        default="lbfgs",
        choices=METHODS,
        help=f"minimizer {what} (plbfgs / pcg: lbfgs / cg with --precon exp; default lbfgs)",
    )
    parser.add_argument(
        "--precon",
        default=precon,
        choices=PRECONDITIONERS,
        help=f"preconditioner (default {precon})",
    )
    parser.add_argument("--A", type=float, default=0.0, help="Exp preconditioner parameter A (0)")
    parser.add_argument(
        "--solver",
        default="auto",
        choices=("auto", "direct", "amg"),
        help="linear solver of the preconditioner (default auto)",
    )
    parser.add_argument("--maxiter", type=int, default=maxiter, help=f"iteration limit ({maxiter})")


def _add_protocol_outputs(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--table", default=None, help="per-step CSV table (default: the output with .csv)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    again = parser.add_mutually_exclusive_group()
    again.add_argument(
        "--resume",
        action="store_true",
        help="continue the interrupted run that wrote the trajectory (same arguments)",
    )
    again.add_argument(
        "--overwrite",
        action="store_true",
        help="replace existing outputs (removed only once the first step is done)",
    )


def _version() -> str:
    """The installed package's version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("athermal")
    except PackageNotFoundError:
        return "unknown"


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``athermal CMD: error: ...``, exit 2), no usage dump."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="athermal",
        description="Quasi-static simulation of athermal soft-particle packings.",
    )
    parser.add_argument("--version", action="version", version=f"athermal {_version()}")
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=_Parser
    )

    rnd = sub.add_parser(
        "random",
        help="random bidisperse packing and its observables",
        description="Place N particles at random (number ratio 1:1, size ratio "
        "--size-ratio) in the unit cell at packing fraction --phi, write them to "
        "a GSD file and print their observables.",
    )
    rnd.add_argument("--n", type=int, default=1024, help="number of particles (default 1024)")
    rnd.add_argument("--dim", type=int, default=2, choices=(2, 3), help="dimensions (default 2)")
    rnd.add_argument("--phi", type=float, default=0.84, help="packing fraction (default 0.84)")
    rnd.add_argument("--size-ratio", type=float, default=1.4, help="large/small radius (1.4)")
    rnd.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    rnd.add_argument("-o", "--output", required=True, help="GSD file to write")
    rnd.add_argument("--overwrite", action="store_true", help="replace an existing output")
    _add_model_options(rnd, 2.0)

    mea = sub.add_parser(
        "measure",
        help="observables of a configuration",
        description="Print the observables of the last frame of a GSD file.",
    )
    mea.add_argument("input", help="GSD file (athermal's, or any HOOMD-schema file)")
    mea.add_argument("--frame", type=int, default=-1, help="frame index (default: last)")
    _add_model_options(mea, None)

    rel = sub.add_parser(
        "relax",
        help="one energy minimization",
        description="Relax the last frame of a GSD file to a force tolerance and "
        "write the relaxed packing. Exit code 3 when it did not converge (the "
        "result is written and reported all the same).",
    )
    rel.add_argument("input", help="GSD file")
    rel.add_argument("-o", "--output", required=True, help="GSD file to write")
    rel.add_argument("--overwrite", action="store_true", help="replace an existing output")
    _add_minimizer_options(rel, "")
    tol = rel.add_mutually_exclusive_group()
    tol.add_argument("--gtol", type=float, help="absolute tolerance on max_i |grad_i|")
    tol.add_argument(
        "--rtol", type=float, help="tolerance relative to the mean contact force (default 1e-9)"
    )
    _add_model_options(rel, None)

    jam = sub.add_parser(
        "jam",
        help="jam a random packing (growth + bisection, the seed's Algorithm 1)",
        description="Place N particles at random at --phi-init, then grow them by --dphi "
        "and relax until the relaxed packing is jammed (E > 0, p > 0), and bisect the "
        "packing fraction down to --epsilon. Writes the jammed packing (its log holds "
        "phi_c); --trajectory also keeps every relaxed step.",
    )
    jam.add_argument("--n", type=int, default=1024, help="number of particles (default 1024)")
    jam.add_argument("--dim", type=int, default=2, choices=(2, 3), help="dimensions (default 2)")
    jam.add_argument("--size-ratio", type=float, default=1.4, help="large/small radius (1.4)")
    jam.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    jam.add_argument(
        "--phi-init", type=float, default=None, help="start fraction (default 0.8 2D, 0.6 3D)"
    )
    jam.add_argument("--dphi", type=float, default=1e-3, help="growth increment (1e-3)")
    jam.add_argument("--epsilon", type=float, default=1e-6, help="bisection accuracy (1e-6)")
    jam.add_argument("-o", "--output", required=True, help="GSD file for the jammed packing")
    jam.add_argument(
        "--trajectory",
        default=None,
        help="GSD trajectory of every relaxed step (default: the output with .steps.gsd)",
    )
    jam.add_argument(
        "--picture",
        default=None,
        help="PNG of the jammed packing with its contact forces (2D; default: the output "
        "with .png; 'none' for no picture)",
    )
    _add_minimizer_options(jam, "of every step", 1_000_000, "exp")
    _add_protocol_outputs(jam)
    _add_model_options(jam, 2.0)

    com = sub.add_parser(
        "compress",
        help="quasi-static compression above jamming (scaling laws)",
        description="Grow the particles of a jammed packing to phi_c + delta phi for "
        "log-spaced delta phi, relaxing each state; writes every state to a GSD "
        "trajectory and a CSV table (pressure, energy, z, moduli by linear response, "
        "iterations) and fits p, G and z - z_iso against delta phi.",
    )
    com.add_argument("input", help="GSD file with a jammed packing (e.g. from athermal jam)")
    com.add_argument("-o", "--output", required=True, help="GSD trajectory to write")
    com.add_argument(
        "--phi-c", type=float, default=None, help="jamming fraction (default: the file's phi_c)"
    )
    com.add_argument("--from", dest="dphi_min", type=float, default=1e-7, help="smallest (1e-7)")
    com.add_argument("--to", dest="dphi_max", type=float, default=1e-1, help="largest (1e-1)")
    com.add_argument("--per-decade", type=int, default=4, help="steps per decade (4)")
    com.add_argument("--rtol", type=float, default=1e-9, help="force tolerance (1e-9 x mean)")
    _add_minimizer_options(com, "of every step", 1_000_000)
    _add_protocol_outputs(com)
    _add_model_options(com, None)

    she = sub.add_parser(
        "shear",
        help="quasi-static simple or pure shear",
        description="Deform a packing by small affine shear increments, relaxing after "
        "each; writes every state to a GSD trajectory and a CSV table (stress and "
        "fabric, their isotropic and deviatoric parts, plastic events).",
    )
    she.add_argument("input", help="GSD file with the start packing")
    she.add_argument("-o", "--output", required=True, help="GSD trajectory to write")
    she.add_argument("--mode", default="pure", choices=SHEAR_MODES, help="shear (default pure)")
    she.add_argument("--strain", type=float, default=0.02, help="final strain (0.02)")
    she.add_argument("--step", type=float, default=1e-4, help="strain increment (1e-4)")
    she.add_argument("--rtol", type=float, default=1e-9, help="force tolerance (1e-9 x mean)")
    _add_minimizer_options(she, "of every step", 1_000_000)
    _add_protocol_outputs(she)
    _add_model_options(she, None)

    ens = sub.add_parser(
        "ensemble",
        help="many realizations of a protocol on Dask",
        description="Run M realizations of jam, compress, shear or the iteration "
        "experiment, realization k with the k-th child of SeedSequence(--seed), on a local "
        "Dask cluster started here (--workers) or an existing one (--scheduler). Each "
        "realization writes its trajectory and result into DIR; rerunning with the same DIR "
        "skips finished ones; a summary (JSON, CSV, figure) aggregates them. Without the "
        "dask extra the realizations run one after another.",
    )
    ens.add_argument("protocol", choices=("jam", "compress", "shear", "iterations"))
    ens.add_argument("--realizations", type=int, required=True, help="how many (M)")
    ens.add_argument("--workers", type=int, default=None, help="local worker processes")
    ens.add_argument("--scheduler", default=None, help="address of an existing scheduler")
    ens.add_argument("--seed", type=int, default=0, help="root seed (default 0)")
    ens.add_argument("-o", "--output", required=True, help="directory of the ensemble")
    ens.add_argument("--n", type=int, default=1024, help="particles (default 1024)")
    ens.add_argument("--dim", type=int, default=2, choices=(2, 3), help="dimensions (2)")
    ens.add_argument("--size-ratio", type=float, default=1.4, help="large/small radius (1.4)")
    ens.add_argument("--epsilon", type=float, default=1e-6, help="bisection accuracy (1e-6)")
    ens.add_argument("--method", default="lbfgs", choices=METHODS, help="minimizer (lbfgs)")
    ens.add_argument(
        "--precon", default="exp", choices=PRECONDITIONERS, help="preconditioner (exp)"
    )
    ens.add_argument("--alpha", type=float, default=2.0, help="contact exponent (2)")
    ens.add_argument("--quiet", action="store_true", help="no progress on stderr")
    ens.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )

    pap = sub.add_parser(
        "paper",
        help="reproduce the seed paper's figures, Table and exponents",
        description="Jamming snapshots, the convergence of one relaxation, the scaling "
        "laws of p, G and z for alpha = 2 and 2.5, the iteration experiment, the pure-shear "
        "test and the Table, written as PNG figures and report.md into DIR. --quick (the "
        "default) runs at N = 1024 in minutes; --full at the seed's N = 4096 (hours).",
    )
    pap.add_argument("-o", "--output", required=True, help="directory to write into")
    size = pap.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="N = 1024 (default)")
    size.add_argument("--full", action="store_true", help="the seed's N = 4096")
    pap.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    pap.add_argument(
        "--overwrite", action="store_true", help="replace the report of an earlier run"
    )
    pap.add_argument("--quiet", action="store_true", help="no progress on stderr")
    pap.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )

    ben = sub.add_parser(
        "bench",
        help="the seed's Table benchmark (docs/benchmarks.md, B1)",
        description="Minimizers and preconditioners on the three cases of the "
        "seed's Table (N = 4096) to 1e-9 of the mean contact force, with scipy's "
        "L-BFGS-B as the in-run reference. Prints a markdown table.",
    )
    ben.add_argument(
        "--cases",
        type=int,
        nargs="+",
        default=list(bench.CASES),
        choices=bench.CASES,
        help="cases (default 1 2 3)",
    )
    ben.add_argument(
        "--alphas",
        type=float,
        nargs="+",
        default=list(bench.ALPHAS),
        help="contact exponents (default 2 2.5)",
    )
    ben.add_argument(
        "--methods",
        nargs="+",
        default=None,
        metavar="LABEL",
        help="method labels (default all: " + ", ".join(m.label for m in bench.METHODS) + ")",
    )
    ben.add_argument("--repeats", type=int, default=3, help="timing repeats (median, default 3)")
    ben.add_argument(
        "--quick",
        action="store_true",
        help="case 3, alpha 2, L-BFGS / P-L-BFGS / scipy, one repeat",
    )
    ben.add_argument("--quiet", action="store_true", help="no progress on stderr")
    ben.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )
    for each in (parser, *sub.choices.values()):
        # read "-1e-6" as a (bad) number, not as an option: argparse's own pattern misses
        # exponents, and then says only "expected one argument"
        each._negative_number_matcher = NEGATIVE_NUMBER
    return parser


def _report(obs: Observables, extra: dict[str, Any], as_json: bool) -> None:
    data = {**obs.to_dict(), **extra}
    if as_json:
        print(json.dumps(data))
        return
    rows = [
        ("particles", f"{obs.n} in {obs.dim}D"),
        ("packing fraction", f"{obs.phi:.6f}"),
        ("energy", f"{obs.energy:.6e}"),
        ("pressure", f"{obs.pressure:.6e}"),
        ("shear stress", f"{obs.shear_stress:.6e}"),
        ("stress iso / dev", f"{obs.stress_iso:.6e} / {obs.stress_dev:.6e}"),
        ("fabric iso / dev", f"{obs.fabric_iso:.6f} / {obs.fabric_dev:.6f}"),
        ("contacts", f"{obs.contacts}"),
        ("rattlers", f"{obs.n_rattlers}"),
        ("z (rattlers removed)", f"{obs.z:.6f}"),
        ("max |grad_i|", f"{obs.max_gradient:.3e}"),
    ]
    rows += [(key, str(value)) for key, value in extra.items()]
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")


def _run(args: argparse.Namespace) -> None:
    if args.command == "random":
        model = commands.model_from(args, None)
        start = time.perf_counter()
        packing = random_packing(
            args.n, args.phi, dim=args.dim, seed=args.seed, size_ratio=args.size_ratio
        )
        obs = measure(packing, model)
        write_gsd(
            args.output,
            packing,
            model=model,
            seed=args.seed,
            observables=commands.file_observables(obs),
        )
        _report(
            obs,
            {
                "seed": args.seed,
                "output": args.output,
                "seconds": round(time.perf_counter() - start, 4),
            },
            args.json,
        )
    elif args.command == "measure":
        frame = read_gsd(args.input, frame=args.frame)
        model = commands.model_from(args, frame.model)
        _report(measure(frame.packing, model), {"alpha": model.alpha}, args.json)
    elif args.command == "relax":
        _relax(args)
    elif args.command == "bench":
        _bench(args)
    elif args.command == "paper":
        commands.paper(args)
    elif args.command == "ensemble":
        commands.ensemble(args)
    elif args.command == "jam":
        commands.jam(args)
    elif args.command == "compress":
        commands.compress(args)
    elif args.command == "shear":
        commands.shear(args)


def _bench(args: argparse.Namespace) -> None:
    if args.quick:
        args.cases, args.alphas, args.methods, args.repeats = [3], [2.0], bench.QUICK_METHODS, 1
    show = not args.quiet and sys.stderr.isatty()

    def progress(row: bench.Row) -> None:
        if show:
            print(
                f"alpha {row.alpha:g} case {row.case} {row.method}: {row.iterations} "
                f"iterations, {row.seconds:.2f} s",
                file=sys.stderr,
                flush=True,
            )

    rows = bench.table1(args.cases, args.alphas, args.methods, args.repeats, progress)
    if args.json:
        print(json.dumps({"rows": [dataclasses.asdict(r) for r in rows]}))
    else:
        print(bench.markdown(rows), end="")


def _relax(args: argparse.Namespace) -> None:
    frame = read_gsd(args.input)
    model = commands.model_from(args, frame.model)
    measure(frame.packing, model)  # refuses coincident particles before any work
    rtol = 1e-9 if args.gtol is None and args.rtol is None else args.rtol
    res = minimize(
        Objective(frame.packing, model),
        args.method,
        precon=args.precon,
        A=args.A,
        solver=args.solver,
        gtol=args.gtol,
        rtol=rtol,
        maxiter=args.maxiter,
    )
    obs = measure(res.packing, model)
    write_gsd(
        args.output,
        res.packing,
        model=model,
        seed=frame.seed,
        observables=commands.file_observables(obs),
    )
    summary = {
        "method": res.method,
        "precon": res.precon,
        "converged": res.converged,
        "message": res.message,
        "iterations": res.iterations,
        "evaluations": res.evaluations,
        "seconds": round(res.seconds, 6),
        "energy": res.energy,
        "max_gradient": res.max_gradient,
        "gtol": res.gtol,
        "output": args.output,
    }
    _report(obs, summary, args.json)
    if not res.converged:
        raise NotConverged(f"did not converge: {res.message}")


class NotConverged(RuntimeError):
    """A minimization that stopped short of its tolerance (its result was still written)."""


def _one_line_warning(command: str) -> Callable[..., None]:
    """A ``warnings.showwarning`` that prints ``athermal COMMAND: warning: message`` on stderr."""

    def show(message: Warning | str, *_: object, **__: object) -> None:
        print(f"athermal {command}: warning: {message}", file=sys.stderr)

    return show


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``athermal`` command; returns the exit code."""
    args = _parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _one_line_warning(args.command)
            check_request(args)
            _run(args)
    except BrokenPipeError:  # the reader of stdout went away (`athermal ... --json | head`)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except KeyboardInterrupt:
        again = "; rerun with --resume to continue" if hasattr(args, "resume") else ""
        print(f"athermal {args.command}: interrupted{again}", file=sys.stderr)
        return 130
    except InputError as exc:
        print(f"athermal {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except ConvergenceError as exc:
        print(f"athermal {args.command}: error: {exc}", file=sys.stderr)
        return 3
    except NotConverged as exc:
        print(f"athermal {args.command}: {exc}", file=sys.stderr)
        return 3
    except OSError as exc:
        print(
            f"athermal {args.command}: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(
                ": "
            ),
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
