"""The ``athermal`` command's parser class and the option groups its subcommands share (each
option's default stated once, in its ``default=``; the help formatter prints it)."""

from __future__ import annotations

import argparse
import re
from typing import Any, NoReturn

from .. import engines
from ..engines.precon import PRECONDITIONERS
from ..linalg import SOLVERS
from ..model.packing import POLYDISPERSITY, SIZE_DISTRIBUTIONS
from ..protocols import DPHI, EPSILON, JAM_PROTOCOL, JAM_PROTOCOLS, RESOLUTION, SHEAR_MODES
from ..relaxation import MAXITER, METHODS, RTOL
from ..studies.avalanches import EventsSpec
from ..studies.experiments import CompressSpec, ShearSpec


class Help(argparse.HelpFormatter):
    """Help with every default printed as ``(default: X)``; options without one say in their
    help what they do when absent."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or default is None
            or default is False
            or default is argparse.SUPPRESS
            or default == ""
            or not action.option_strings
        ):
            return text
        if isinstance(default, list):
            return text + " (default: " + " ".join(str(d) for d in default) + ")"
        return text + " (default: %(default)s)"


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``athermal CMD: error: ...``, exit 2) naming the
    subcommand, no usage dump."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", Help)
        super().__init__(*args, **kwargs)
        # read "-1e-6" as a (bad) number, not as an option: argparse's own pattern misses
        # exponents, and then says only "expected one argument"
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


Options = argparse.ArgumentParser | argparse._ArgumentGroup
"""Where an option helper adds its options: a parser, or a group of one's options."""


def add_json(parser: Options) -> None:
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )


def add_model(parser: argparse.ArgumentParser, *, from_file: bool) -> None:
    """``--alpha`` and ``--stiffness``: a command with an input file defaults to the file's."""
    if from_file:
        parser.add_argument(
            "--alpha",
            type=float,
            default=None,
            help="contact exponent alpha >= 2 (2 = Hooke, 2.5 = Hertz; default: the file's, "
            "else 2)",
        )
        parser.add_argument(
            "--stiffness",
            type=float,
            default=None,
            help="contact stiffness k (default: the file's, else 1)",
        )
    else:
        parser.add_argument(
            "--alpha",
            type=float,
            default=2.0,
            help="contact exponent alpha >= 2 (2 = Hooke, 2.5 = Hertz)",
        )
        parser.add_argument(
            "--stiffness", type=float, default=None, help="contact stiffness k (default: 1)"
        )
    add_json(parser)


def add_minimizer(parser: argparse.ArgumentParser, what: str, precon: str = "none") -> None:
    parser.add_argument(
        "--method",
        default="lbfgs",
        choices=METHODS,
        help=f"minimizer {what} (plbfgs / pcg: lbfgs / cg with --precon exp)".replace("  ", " "),
    )
    parser.add_argument(
        "--precon",
        default=None,
        choices=PRECONDITIONERS,
        help=f"preconditioner (default: {precon}; none with --method newton)",
    )
    parser.set_defaults(default_precon=precon)
    parser.add_argument("--A", type=float, default=0.0, help="Exp preconditioner parameter A")
    parser.add_argument(
        "--solver",
        default="auto",
        choices=SOLVERS,
        help="linear solver of the preconditioner (ic0: incomplete Cholesky)",
    )
    parser.add_argument("--maxiter", type=int, default=MAXITER, help="iteration limit")
    add_backend(parser)


def add_backend(parser: Options) -> None:
    parser.add_argument(
        "--backend",
        default=engines.DEFAULT,
        choices=engines.names(),
        help="engine: "
        + "; ".join(
            f"{name} ({', '.join(engines.capabilities_of(name).methods)})"
            for name in engines.names()
        )
        + " (jax: the extra athermal[jax], no --solver)",
    )
    parser.add_argument(
        "--deterministic",
        action="store_true",
        help="with --backend jax on a GPU: XLA's deterministic scatter-adds, the same bits from "
        "run to run (slower; the numba engine is the same bits everywhere already)",
    )


def add_jamming(parser: Options) -> None:
    """The jamming protocol's options."""
    parser.add_argument("--dphi", type=float, default=DPHI, help="growth increment of phi")
    parser.add_argument(
        "--epsilon",
        type=float,
        default=EPSILON,
        help=f"bisection accuracy of phi_c (>= {RESOLUTION:g})",
    )
    parser.add_argument(
        "--protocol",
        dest="bisection",
        default=JAM_PROTOCOL,
        choices=JAM_PROTOCOLS,
        help="where each bisection trial starts: seed = the last unjammed configuration "
        "(the paper's Algorithm 1), ohern = the previous trial (O'Hern et al.'s compression and "
        "decompression of one configuration)",
    )


def add_protocol_outputs(parser: argparse.ArgumentParser) -> None:
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


def add_quasi_static(parser: argparse.ArgumentParser) -> None:
    """The options of a protocol that relaxes every step of a file's packing."""
    parser.add_argument(
        "--rtol", type=float, default=RTOL, help="force tolerance, x the mean contact force"
    )
    add_minimizer(parser, "of every step")
    add_protocol_outputs(parser)
    add_model(parser, from_file=True)


def add_packing(parser: Options) -> None:
    parser.add_argument("--n", type=int, default=1024, help="number of particles")
    parser.add_argument("--dim", type=int, default=2, choices=(2, 3), help="dimensions")
    parser.add_argument(
        "--sizes",
        default="bidisperse",
        choices=SIZE_DISTRIBUTIONS,
        help="size distribution: a 1:1 bidisperse mixture, or radii drawn (seeded) from a "
        "uniform or log-normal distribution of width --polydispersity",
    )
    parser.add_argument(
        "--size-ratio",
        type=float,
        default=1.4,
        help="large / small radius of the bidisperse mixture (number ratio 1:1)",
    )
    parser.add_argument(
        "--polydispersity",
        type=float,
        default=POLYDISPERSITY,
        help="standard deviation / mean of the radii (uniform: < 0.577, log-normal: <= 1)",
    )
    parser.add_argument(
        "--walls",
        default="",
        help="flat frictionless walls normal to these axes ('y', 'x', 'xy'; 'z' in 3D), the "
        "cell's faces there; the other axes periodic (default: none, periodic)",
    )


def add_compression_range(parser: Options) -> None:
    parser.add_argument(
        "--from",
        dest="dphi_min",
        type=float,
        default=CompressSpec.delta_min,
        help="smallest phi - phi_c",
    )
    parser.add_argument(
        "--to",
        dest="dphi_max",
        type=float,
        default=CompressSpec.delta_max,
        help="largest phi - phi_c",
    )
    parser.add_argument(
        "--per-decade",
        type=int,
        default=CompressSpec.per_decade,
        help="compression steps per decade",
    )


def add_shear_options(parser: Options) -> None:
    parser.add_argument(
        "--mode",
        default=ShearSpec.mode,
        choices=SHEAR_MODES,
        help="simple or pure shear, uniaxial compression of the last axis (between walls "
        "normal to it: a wall moving in), or plane shear (walls normal to y or z: the particles "
        "near each wall glued to it, the upper one moved along x)",
    )
    parser.add_argument("--strain", type=float, default=ShearSpec.strain, help="final strain")
    parser.add_argument("--step", type=float, default=ShearSpec.step, help="strain increment")


def add_events_options(parser: Options, protocol: str) -> None:
    """The AQS shear of ``ensemble events`` (to a strain) or ``ensemble cycles`` (amplitudes)."""
    parser.add_argument(
        "--shear-delta-phi",
        type=float,
        default=EventsSpec.delta_phi,
        help="shear each packing at phi_c + this (radii scaled from its jamming point)",
    )
    parser.add_argument(
        "--mode", default=EventsSpec.mode, choices=SHEAR_MODES, help="how the packings are sheared"
    )
    parser.add_argument("--step", type=float, default=EventsSpec.step, help="strain step")
    parser.add_argument(
        "--max-step",
        type=float,
        default=None,
        help="the largest step, grown to between events (default: 10 x --step with Hooke's "
        "law, alpha 2; else --step)",
    )
    parser.add_argument(
        "--tol", type=float, default=EventsSpec.tol, help="an event's bracket in strain"
    )
    if protocol == "events":
        parser.add_argument("--strain", type=float, default=EventsSpec.strain, help="final strain")
        parser.add_argument(
            "--transient",
            type=float,
            default=EventsSpec.transient,
            help="events below this strain are left out of the statistics",
        )
    else:
        parser.add_argument(
            "--amplitudes",
            type=float,
            nargs="+",
            default=list(EventsSpec.amplitudes),
            help="cyclic shear at each of these amplitudes, from the same start",
        )
        parser.add_argument(
            "--cycles", type=int, default=EventsSpec.cycles, help="cycles at most per amplitude"
        )


def add_frame(parser: argparse.ArgumentParser, what: str) -> None:
    """``--frame K`` or ``--delta-phi D``: which state of a multi-frame input to start from."""
    which = parser.add_mutually_exclusive_group()
    which.add_argument(
        "--frame",
        type=int,
        default=None,
        help=f"frame of the input to {what} (negative counts from the end; default: the last)",
    )
    which.add_argument(
        "--delta-phi",
        type=float,
        default=None,
        help=f"{what} the frame whose logged phi - phi_c is nearest this (a compression "
        "trajectory)",
    )
