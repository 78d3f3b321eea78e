"""The ``athermal`` command's parser: every subcommand, option and default (docs/contract.md), one
function per subcommand; the shared option groups are :mod:`athermal.cli.options`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

from ..certify import TARGET
from ..certify.criticality import FORCE_WINDOW, GAP_WINDOW
from ..engines.precon import PRECONDITIONERS
from ..enthalpy import CELL_FREEDOMS
from ..protocols.events import EVENT_TOL
from ..relaxation import METHODS, RTOL
from ..studies import bench
from ..studies.experiments import ShearSpec
from .options import (
    Parser,
    add_backend,
    add_compression_range,
    add_events_options,
    add_frame,
    add_jamming,
    add_json,
    add_minimizer,
    add_model,
    add_packing,
    add_protocol_outputs,
    add_quasi_static,
    add_shear_options,
)


def _random_command(sub: argparse._SubParsersAction) -> None:
    """``athermal random``."""
    rnd = sub.add_parser(
        "random",
        help="random packing and its observables",
        description="Place N particles at random (bidisperse 1:1 with size ratio "
        "--size-ratio, or polydisperse: --sizes) in the unit cell at packing fraction --phi, "
        "write them to a GSD file and print their observables.",
    )
    add_packing(rnd)
    rnd.add_argument("--phi", type=float, default=0.84, help="packing fraction")
    rnd.add_argument("--seed", type=int, default=0, help="random seed")
    rnd.add_argument("-o", "--output", required=True, help="GSD file to write")
    rnd.add_argument("--overwrite", action="store_true", help="replace an existing output")
    add_model(rnd, from_file=False)


def _measure_command(sub: argparse._SubParsersAction) -> None:
    """``athermal measure``."""
    mea = sub.add_parser(
        "measure",
        help="observables of a configuration",
        description="Print the observables of one frame of a GSD file, the statistics of its "
        "contact forces (P(f/<f>) and its exponential tail, contact and force anisotropy; "
        "--json: the histogram) and the numbers its writer logged with it (phi_c, strain, "
        "Delta phi, ...). Units and signs: docs/quantities.md.",
    )
    mea.add_argument("input", help="GSD file (athermal's, or any HOOMD-schema file)")
    mea.add_argument("--frame", type=int, default=-1, help="frame index (-1: the last)")
    mea.add_argument(
        "--forces-figure",
        default=None,
        help="also draw the contact-force distribution P(f/<f>) to this image file",
    )
    mea.add_argument("--overwrite", action="store_true", help="replace an existing figure")
    add_model(mea, from_file=True)


def _modes_command(sub: argparse._SubParsersAction) -> None:
    """``athermal modes``."""
    mod = sub.add_parser(
        "modes",
        help="vibrational modes and density of states of a configuration",
        description="Eigenpairs of the stiffness matrix (Hessian, unit masses) of one frame, "
        "rattlers removed: the full spectrum (dense, up to N = 4096 in 2D) or the lowest "
        "--lowest K (shift-invert), participation ratios, D(omega) and its plateau frequency "
        "omega*. Writes an NPZ file (eigenvalues, frequencies, participation, the lowest "
        "--vectors eigenvectors (V, N, d), D(omega)) and a D(omega) figure. Checks: d zero "
        "modes (translations; between walls one per periodic axis) and no negative eigenvalue "
        "at a stable minimum.",
    )
    mod.add_argument("input", help="GSD file (a relaxed packing)")
    mod.add_argument("-o", "--output", required=True, help="NPZ file to write (.npz)")
    mod.add_argument("--frame", type=int, default=-1, help="frame index (-1: the last)")
    mod.add_argument(
        "--seed", type=int, default=0, help="seed of omega*'s bootstrap (its uncertainty)"
    )
    mod.add_argument(
        "--lowest",
        type=int,
        default=None,
        help="only the lowest K eigenpairs (default: the full spectrum, with D(omega))",
    )
    mod.add_argument(
        "--vectors",
        type=int,
        default=10,
        help="eigenvectors written for this many of the lowest vibrational modes",
    )
    mod.add_argument(
        "--figure",
        default=None,
        help="D(omega) and participation figure (default: OUT with .png; 'none' for none; "
        "needs the full spectrum)",
    )
    mod.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    add_model(mod, from_file=True)


def _moduli_command(sub: argparse._SubParsersAction) -> None:
    """``athermal moduli``."""
    mdl = sub.add_parser(
        "moduli",
        help="bulk and shear moduli of a configuration",
        description="Bulk modulus B = -V dp/dV (radii fixed; bulk_phi = phi dp/dphi along "
        "growing radii, compress's bulk_modulus) and shear modulus G (simple shear x += gamma "
        "y) of a relaxed frame by exact linear response (the non-affine relaxation solved with "
        "the sparse Hessian, rattlers removed), with the affine (Born) values; with "
        "--finite-strain S also from 10 quasi-static strain steps up to S (the paper's "
        "measurement). Units: docs/quantities.md.",
    )
    mdl.add_argument("input", help="GSD file (relaxed packings: jam's output, a trajectory)")
    which = mdl.add_mutually_exclusive_group()
    which.add_argument("--frame", type=int, default=-1, help="frame index (-1: the last)")
    which.add_argument("--all-frames", action="store_true", help="every frame of a trajectory")
    mdl.add_argument(
        "--finite-strain",
        type=float,
        default=None,
        metavar="S",
        help="also measure B and G by quasi-static strain steps up to S (e.g. 1e-5)",
    )
    add_model(mdl, from_file=True)


def _certify_command(sub: argparse._SubParsersAction) -> None:
    """``athermal certify``."""
    cer = sub.add_parser(
        "certify",
        help="certify a jammed packing: force balance beyond float64",
        description="Refine a relaxed jammed packing by Newton's method with the residual forces "
        "in double-double (~32 digits) until its largest net force is --target times its mean "
        "contact force, and write it with its certificate: the force balance reached, the "
        "contacts beyond isostatic, the lowest non-zero eigenvalue of the non-rattlers' "
        "Hessian, the smallest contact force and gap (docs/quantities.md). The file keeps the "
        "positions' low parts (log/athermal/position_lo). Refused: a packing that is not jammed, "
        "not relaxed, or whose contacts change in the refinement (exit 2); exit 3 when the "
        "precision's limit comes before --target.",
    )
    cer.add_argument("input", help="GSD file with a jammed packing (jam's output)")
    cer.add_argument("-o", "--output", required=True, help="GSD file for the certified packing")
    cer.add_argument("--frame", type=int, default=-1, help="frame index (-1: the last)")
    cer.add_argument(
        "--target",
        type=float,
        default=TARGET,
        help="force balance to reach, x the mean contact force",
    )
    cer.add_argument(
        "--fast",
        action="store_true",
        help="factor on cvxopt's optimized BLAS: many times faster for large 3D packings, the "
        "bits this machine's (docs/decisions.md, 'Factorizations on the machine's BLAS')",
    )
    cer.add_argument("--overwrite", action="store_true", help="replace an existing output")
    add_model(cer, from_file=True)


def _criticality_command(sub: argparse._SubParsersAction) -> None:
    """``athermal criticality``."""
    cri = sub.add_parser(
        "criticality",
        help="weak forces and small gaps of jammed packings, and their critical exponents",
        description="Pool the contact forces f / <f> and the gaps h = r_ij / (r_i + r_j) - 1 "
        "between non-rattlers of many jammed packings (certified ones: athermal certify, jam "
        "--certify), split the forces into those of bucklers (particles with d + 1 contacts, "
        "localized) and the others (extended), and fit their small-value power laws by maximum "
        "likelihood over a window: P(f) ~ f^theta, g(h) ~ h^-gamma, beside the mean-field "
        "theta_e = 0.42311 and gamma = 0.41269 (Charbonneau, Corwin, Parisi & Zamponi, PRL "
        "114, 125504 (2015)); gamma also a decade at a time across the gap window "
        "(gamma_local).",
    )
    cri.add_argument("inputs", nargs="+", help="GSD files of jammed packings (the last frame)")
    cri.add_argument(
        "--force-window",
        type=float,
        nargs=2,
        default=list(FORCE_WINDOW),
        metavar=("LOW", "HIGH"),
        help="window of f / <f> for the force exponents",
    )
    cri.add_argument(
        "--gap-window",
        type=float,
        nargs=2,
        default=list(GAP_WINDOW),
        metavar=("LOW", "HIGH"),
        help="window of h for the gap exponent",
    )
    cri.add_argument("--figure", default=None, help="PNG of the cumulative distributions and fits")
    cri.add_argument("--overwrite", action="store_true", help="replace an existing figure")
    add_model(cri, from_file=True)


def _relax_command(sub: argparse._SubParsersAction) -> None:
    """``athermal relax``."""
    rel = sub.add_parser(
        "relax",
        help="one energy minimization",
        description="Relax the last frame of a GSD file to a force tolerance and write the "
        "relaxed packing. Exit code 3 when it did not converge (the result is written and "
        "reported all the same).",
    )
    rel.add_argument("input", help="GSD file")
    rel.add_argument("-o", "--output", required=True, help="GSD file to write")
    rel.add_argument("--overwrite", action="store_true", help="replace an existing output")
    add_minimizer(rel, "")
    rel.add_argument(
        "--pressure",
        type=float,
        default=None,
        help="minimize the enthalpy U + P V at this pressure, the cell free (lbfgs, cg or fire; "
        "--precon none or exp, the Exp preconditioner extended to the cell)",
    )
    rel.add_argument(
        "--cell",
        default="volume",
        choices=CELL_FREEDOMS,
        help="with --pressure: what of the cell relaxes (walls: the gaps between the walls, "
        "at the force per unit area --pressure on them)",
    )
    tol = rel.add_mutually_exclusive_group()
    tol.add_argument("--gtol", type=float, help="absolute tolerance on max_i |grad_i|")
    tol.add_argument(
        "--rtol",
        type=float,
        help=f"tolerance relative to the mean contact force (default: {RTOL:g} unless --gtol)",
    )
    add_model(rel, from_file=True)


def _jam_command(sub: argparse._SubParsersAction) -> None:
    """``athermal jam``."""
    jam = sub.add_parser(
        "jam",
        help="jam a random packing (growth + bisection, after the paper's Algorithm 1)",
        description="Place N particles at random at --phi-init, then grow them by --dphi and "
        "relax until the relaxed packing is jammed (E > 0, p > 0), and bisect the packing "
        "fraction down to --epsilon; check the result (decompression unjams it, isostatic, "
        "a minimum). Writes the jammed packing (its log holds phi_c), the trajectory of every "
        "relaxed step, a per-step table and a picture.",
    )
    add_packing(jam)
    jam.add_argument("--seed", type=int, default=0, help="random seed")
    jam.add_argument(
        "--phi-init",
        type=float,
        default=None,
        help="start packing fraction (default: 0.8 in 2D, 0.6 in 3D; between walls 0.7, 0.5)",
    )
    add_jamming(jam)
    jam.add_argument(
        "--pressure",
        type=float,
        default=None,
        help="then compress (or decompress) the jammed packing to this pressure, within "
        "--pressure-rtol, and write that packing (phi_c still the jamming run's)",
    )
    jam.add_argument(
        "--pressure-rtol", type=float, default=1e-3, help="relative accuracy of --pressure"
    )
    jam.add_argument(
        "--certify",
        action="store_true",
        help="refine the jammed packing in double-double to force balance 1e-20 of its mean "
        "contact force and write its certificate with it (as athermal certify)",
    )
    jam.add_argument("-o", "--output", required=True, help="GSD file for the jammed packing")
    jam.add_argument(
        "--trajectory",
        default=None,
        help="GSD trajectory of every relaxed step, always written (default: the output "
        "with .steps.gsd)",
    )
    jam.add_argument(
        "--picture",
        default=None,
        help="PNG of the jammed packing with its contact forces (2D; default: the output "
        "with .png; 'none' for no picture)",
    )
    add_minimizer(jam, "of every step", "exp")
    add_protocol_outputs(jam)
    add_model(jam, from_file=False)


def _compress_command(sub: argparse._SubParsersAction) -> None:
    """``athermal compress``."""
    com = sub.add_parser(
        "compress",
        help="quasi-static compression above jamming (scaling laws)",
        description="Grow the particles of a jammed packing to phi_c + delta phi for "
        "log-spaced delta phi, relaxing each state; writes every state to a GSD trajectory "
        "and a CSV table (pressure, energy, z, moduli by linear response, iterations) and "
        "fits p, G and z - z_iso against delta phi.",
    )
    com.add_argument("input", help="GSD file with a jammed packing (e.g. from athermal jam)")
    com.add_argument("-o", "--output", required=True, help="GSD trajectory to write")
    com.add_argument(
        "--frame", type=int, default=None, help="frame of the input (default: the last)"
    )
    com.add_argument(
        "--phi-c",
        type=float,
        default=None,
        help="jamming fraction (default: the frame's logged phi_c, else its phi)",
    )
    com.add_argument(
        "--from-unjammed",
        action="store_true",
        help="compress a start that is not a relaxed packing at its jamming point all the same "
        "(a warning says what is wrong with it; refused without this flag)",
    )
    add_compression_range(com)
    add_quasi_static(com)


def _shear_command(sub: argparse._SubParsersAction) -> None:
    """``athermal shear``."""
    she = sub.add_parser(
        "shear",
        help="quasi-static simple or pure shear",
        description="Deform a packing by small affine shear increments, relaxing after each; "
        "writes every state to a GSD trajectory and a CSV table (stress and fabric, their "
        "isotropic and deviatoric parts, the driven stress tau, plastic events). "
        "tau = -sigma_xy in simple shear, (sigma_yy - sigma_xx) / 2 in pure shear, the "
        "shear force per unit area on the walls in plane shear (docs/quantities.md).",
    )
    she.add_argument("input", help="GSD file with the start packing (or a compression trajectory)")
    she.add_argument("-o", "--output", required=True, help="GSD trajectory to write")
    add_frame(she, "shear")
    add_shear_options(she)
    she.add_argument(
        "--wall-layer",
        type=float,
        default=None,
        help="plane shear: glue to each wall the particles whose centres lie within this "
        "distance of it (default: the largest diameter)",
    )
    plastic = she.add_argument_group(
        "exact plastic events (docs/howto/plasticity.md): every event located by the end of "
        "its branch of minima"
    )
    plastic.add_argument(
        "--events",
        action="store_true",
        help="locate every plastic event to --tol in strain; writes the states (.csv), the "
        "events (.events.csv) and the frames before and after each event",
    )
    plastic.add_argument(
        "--tol", type=float, default=EVENT_TOL, help="an event's bracket in strain (with --events)"
    )
    plastic.add_argument(
        "--max-step",
        type=float,
        default=None,
        help="the largest step, grown to between events (with --events; default: 10 x --step "
        "with Hooke's law, alpha 2; else --step)",
    )
    plastic.add_argument(
        "--cycles",
        type=int,
        default=None,
        help="cyclic shear: this many cycles 0 -> A -> -A -> 0 with exact events, stopping at "
        "a limit cycle (needs --amplitude)",
    )
    plastic.add_argument(
        "--amplitude", type=float, default=None, help="cyclic shear's amplitude A (with --cycles)"
    )
    plastic.add_argument(
        "--figure",
        default=None,
        help="PNG of the stress-strain curve with its events marked and of the drops' "
        "distributions (default: OUTPUT with .png; 'none' for none)",
    )
    add_quasi_static(she)


def _paper_command(sub: argparse._SubParsersAction) -> None:
    """``athermal paper``."""
    pap = sub.add_parser(
        "paper",
        help="reproduce the paper's figures, Table and exponents",
        description="The jamming figure, the convergence of one relaxation, the scaling laws "
        "of p, G and z for alpha = 2 and 2.5, the iteration experiment, the pure-shear test "
        "and the Table, written as PNG figures and report.md into DIR. --quick (the default) "
        "runs at N = 1024 in minutes; --full at the paper's N = 4096 (hours).",
    )
    pap.add_argument("-o", "--output", required=True, help="directory to write into")
    size = pap.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="N = 1024 (the default)")
    size.add_argument("--full", action="store_true", help="the paper's N = 4096")
    pap.add_argument("--seed", type=int, default=0, help="root seed")
    pap.add_argument(
        "--overwrite", action="store_true", help="replace the report of an earlier run"
    )
    pap.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_json(pap)


def _bench_command(sub: argparse._SubParsersAction) -> None:
    """``athermal bench``."""
    ben = sub.add_parser(
        "bench",
        help="the paper's Table benchmark (docs/benchmarks.md, B1)",
        description="Minimizers and preconditioners on the three cases of the paper's Table "
        "(N = 4096) to 1e-9 of the mean contact force, with scipy's L-BFGS-B as the in-run "
        "reference. Prints a markdown table.",
    )
    ben.add_argument(
        "--cases",
        type=int,
        nargs="+",
        default=list(bench.CASES),
        choices=bench.CASES,
        help="cases",
    )
    ben.add_argument(
        "--alphas", type=float, nargs="+", default=list(bench.ALPHAS), help="contact exponents"
    )
    ben.add_argument(
        "--methods",
        nargs="+",
        default=None,
        metavar="LABEL",
        help="methods by label (default: all, " + ", ".join(bench.LABELS) + ")",
    )
    ben.add_argument("--repeats", type=int, default=3, help="timing repeats (their median)")
    add_backend(ben)
    ben.add_argument(
        "--quick",
        action="store_true",
        help="case 3, alpha 2, " + " / ".join(bench.QUICK_LABELS) + ", one repeat",
    )
    ben.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_json(ben)


def build() -> argparse.ArgumentParser:
    """The parser of every subcommand."""
    from . import _version

    parser = Parser(
        prog="athermal", description="Quasi-static simulation of athermal soft-particle packings."
    )
    parser.add_argument("--version", action="version", version=f"athermal {_version()}")
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=Parser
    )
    for command in COMMANDS:
        command(sub)
    return parser


ENSEMBLE_PROTOCOLS = {
    "jam": "jam a packing",
    "compress": "jam a packing and compress it",
    "shear": "jam, compress and shear a packing",
    "iterations": "jam a packing and run the paper's iteration experiment on it",
    "events": "jam a packing and shear it with every plastic event located (avalanches)",
    "cycles": "jam a packing and shear it in cycles at each amplitude (yielding)",
}
"""What each realization of ``athermal ensemble PROTOCOL`` runs."""


def _ensemble(sub: argparse._SubParsersAction) -> None:
    """``athermal ensemble PROTOCOL``: one parser per protocol, each with only the options its
    realizations use."""
    ens = sub.add_parser(
        "ensemble",
        help="many realizations of a protocol on Dask",
        description="Run M realizations of jam, compress, shear or the iteration experiment, "
        "realization k with the k-th child seed of SeedSequence(--seed), on a local Dask "
        "cluster started here (--workers) or an existing one (--scheduler). Each realization "
        "writes its trajectory and result into DIR; rerunning with the same DIR skips finished "
        "ones; a summary (JSON, CSV, figure) aggregates them. Without the dask extra the "
        "realizations run one after another. 'athermal ensemble PROTOCOL --help' lists a "
        "protocol's options.",
    )
    protocols = ens.add_subparsers(
        dest="protocol", required=True, metavar="PROTOCOL", parser_class=Parser
    )
    for name, what in ENSEMBLE_PROTOCOLS.items():
        each = protocols.add_parser(
            name,
            help=what,
            description=f"M realizations, each of which will {what}, on Dask (athermal "
            "ensemble --help).",
        )
        each.set_defaults(default_precon="exp")
        run = each.add_argument_group("the ensemble")
        run.add_argument("--realizations", type=int, required=True, help="how many (M)")
        run.add_argument(
            "--workers",
            type=int,
            default=None,
            help="local worker processes (the dask extra; default: one per core available)",
        )
        run.add_argument(
            "--scheduler", default=None, help="address of an existing scheduler (the dask extra)"
        )
        run.add_argument(
            "--batch",
            type=int,
            default=None,
            help="with --backend jax: relax B realizations at a time as one batch on the device "
            "(in this process, no --workers / --scheduler)",
        )
        run.add_argument("--seed", type=int, default=0, help="root seed")
        run.add_argument("-o", "--output", required=True, help="directory of the ensemble")
        run.add_argument("--quiet", action="store_true", help="no progress on stderr")
        add_json(run)
        jamming = each.add_argument_group("the packings and their jamming")
        add_packing(jamming)
        jamming.add_argument("--alpha", type=float, default=2.0, help="contact exponent")
        add_jamming(jamming)
        jamming.add_argument(
            "--method", default="lbfgs", choices=METHODS, help="minimizer of every step"
        )
        jamming.add_argument(
            "--precon",
            default=None,
            choices=PRECONDITIONERS,
            help="preconditioner (default: exp; none with --method newton)",
        )
        add_backend(jamming)
        if name in ("compress", "shear"):
            add_compression_range(each.add_argument_group("the compression"))
        if name == "shear":
            shearing = each.add_argument_group("the shear")
            add_shear_options(shearing)
            shearing.add_argument(
                "--shear-delta-phi",
                type=float,
                default=ShearSpec.delta_phi,
                help="start from the compressed state nearest this phi - phi_c",
            )
        if name in ("events", "cycles"):
            add_events_options(each.add_argument_group("the shear"), name)


COMMANDS: tuple[Callable[[argparse._SubParsersAction], None], ...] = (
    _random_command,
    _measure_command,
    _modes_command,
    _moduli_command,
    _certify_command,
    _criticality_command,
    _relax_command,
    _jam_command,
    _compress_command,
    _shear_command,
    _ensemble,
    _paper_command,
    _bench_command,
)
"""The subcommands' parsers, in the order ``athermal --help`` lists them."""


def subparser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    """The parser of subcommand ``command``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[command]
    raise KeyError(command)
