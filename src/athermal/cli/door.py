"""The command line's door: every option's range and every output path of a parsed command,
checked before any work is done or any file is touched (:func:`check_request`).

A failed check raises :class:`~athermal.errors.InputError` with one line naming the option and
what is wrong with it.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from .. import engines
from ..enthalpy import check_enthalpy_method
from ..errors import InputError
from ..io import SEED_BOUND
from ..model.cell import wall_axes
from ..model.contact import ContactModel
from ..model.law import PowerContact
from ..model.packing import check_width
from ..protocols import RESOLUTION, check_growth, start_fraction
from ..protocols.compress import log_count
from ..protocols.events import check_cycles, check_steps
from ..protocols.jamming import JAMMED_PHI
from ..protocols.shear import strain_steps
from ..relaxation import Minimizer
from ..studies.bench import check_alphas
from ..studies.ensemble import INSTALL_HINT, check_batch
from .common import minimizer_from, precon_from

BYTES_PER_PARTICLE = 2000
"""Memory one particle costs a protocol run, an upper estimate (positions, radii, Verlet list of
~10 neighbours with images, gradients, L-BFGS memory of 10 pairs, the preconditioner's sparse
factor): the door refuses an N that would not fit the machine's memory."""
CUTOFF = 2.2
"""The Exp preconditioner's neighbour cutoff in units of the largest radius (the paper's)."""
MAX_STEPS = 100_000
"""Most protocol steps a command may ask for (growth steps to phi = 1, compression steps, strain
steps): more is an increment too small to make progress."""


T = TypeVar("T")
FLAGS = {"dphi_min": "--from", "dphi_max": "--to"}
"""Options whose flag is not their attribute's name."""


def _number(
    name: str, value: float | list[float] | None, ok: Callable[[float], bool], rule: str
) -> None:
    """Refuse ``value`` (one number, or each of a list-valued option's) outside its range."""
    if value is None:
        return
    for each in value if isinstance(value, list) else [value]:
        if not ((isinstance(each, int) or math.isfinite(each)) and ok(each)):
            flag = FLAGS.get(name, "--" + name.replace("_", "-"))
            raise InputError(f"{flag}: must be {rule}, got {each!r}")


def _options(args: argparse.Namespace) -> None:
    """The numeric options every command may carry, each with its range (a list-valued
    option's, such as ``--alphas``, for each of its values)."""
    rules: dict[str, tuple[Callable[[float], bool], str]] = {
        "n": (lambda v: v >= 2, "an integer >= 2"),
        "seed": (lambda v: 0 <= v < SEED_BOUND, "an integer in [0, 2**64)"),
        "phi": (lambda v: 0 < v < 1, "in (0, 1)"),
        "phi_init": (lambda v: 0 < v < 1, "in (0, 1)"),
        "phi_c": (lambda v: 0 < v < 1, "in (0, 1)"),
        "size_ratio": (lambda v: v >= 1, ">= 1"),
        "polydispersity": (lambda v: v > 0, "> 0"),
        "dphi": (lambda v: v > 0, "> 0"),
        "epsilon": (lambda v: v >= 1e-15, ">= 1e-15"),
        "rtol": (lambda v: v > 0, "> 0"),
        "gtol": (lambda v: v > 0, "> 0"),
        "maxiter": (lambda v: v >= 1, "an integer >= 1"),
        "A": (lambda v: v >= 0, ">= 0"),
        "dphi_min": (lambda v: v > 0, "> 0"),
        "dphi_max": (lambda v: 0 < v < 1, "in (0, 1)"),
        "per_decade": (lambda v: v >= 1, "an integer >= 1"),
        "strain": (lambda v: v > 0, "> 0"),
        "delta_phi": (lambda v: v > 0, "> 0"),
        "shear_delta_phi": (lambda v: 0 < v < 1, "in (0, 1)"),
        "step": (lambda v: v > 0, "> 0"),
        "realizations": (lambda v: v >= 1, "an integer >= 1"),
        "workers": (lambda v: v >= 1, "an integer >= 1"),
        "repeats": (lambda v: v >= 1, "an integer >= 1"),
        "lowest": (lambda v: v >= 1, "an integer >= 1"),
        "pressure": (lambda v: v > 0, "> 0"),
        "pressure_rtol": (lambda v: 0 < v < 1, "in (0, 1)"),
        "vectors": (lambda v: v >= 0, "an integer >= 0"),
        "finite_strain": (lambda v: 0 < v <= 1e-2, "in (0, 1e-2]"),
        "target": (lambda v: 0 < v < 1, "in (0, 1)"),
        "wall_layer": (lambda v: v > 0, "> 0"),
    }
    for name, (ok, rule) in rules.items():
        _number(name, getattr(args, name, None), ok, rule)
    for name in ("alpha", "alphas"):  # the contact law's own check, naming the option given
        value = getattr(args, name, None)
        for each in value if isinstance(value, list) else [] if value is None else [value]:
            _library(PowerContact, each, flag=f"--{name}")
    if getattr(args, "stiffness", None) is not None:
        _library(ContactModel, stiffness=args.stiffness)
    if getattr(args, "walls", ""):
        try:
            wall_axes(args.walls, args.dim)
        except InputError as exc:
            raise InputError(f"--{exc}") from None
    if getattr(args, "sizes", "bidisperse") != "bidisperse":
        try:
            check_width(args.sizes, args.polydispersity)
        except InputError as exc:
            raise InputError(f"--{exc}") from None


def _work(args: argparse.Namespace) -> None:
    """Sizes whose memory exceeds the machine, increments too small to make progress."""
    n = getattr(args, "n", None)
    if n is not None:
        need = n * BYTES_PER_PARTICLE
        total = _memory()
        if total and need > total:
            raise InputError(
                f"--n: {n} particles need ~{need / 2**30:.3g} GiB, the machine has "
                f"{total / 2**30:.3g} GiB"
            )
    if args.command in ("jam", "ensemble") and n is not None:
        r_max = _largest_radius(args, JAMMED_PHI[args.dim])
        if CUTOFF * r_max >= 0.5:
            raise InputError(
                f"--n: {n} particles are too large for the unit cell near jamming (largest "
                f"radius {r_max:.3g} at phi {JAMMED_PHI[args.dim]}; neighbour searches reach "
                f"{CUTOFF:g} radii and must stay within half the cell): use more particles"
            )
    if args.command in ("jam", "ensemble"):
        start = getattr(args, "phi_init", None)  # ensemble: the default
        start = start_fraction(args.dim, bool(args.walls)) if start is None else start
        _library(check_growth, start, args.dphi, args.dim)
        if (1.0 - start) / args.dphi > MAX_STEPS:
            raise InputError(
                f"--dphi: {args.dphi:g} needs ~{(1.0 - start) / args.dphi:.2g} growth steps to "
                f"reach phi = 1 (at most {MAX_STEPS}); take a larger increment"
            )
    if hasattr(args, "dphi_min"):  # compress, ensemble compress and shear
        count = _library(log_count, args.dphi_min, args.dphi_max, args.per_decade)
        if count > MAX_STEPS:
            raise InputError(f"--per-decade: {count:.2g} compression steps (at most {MAX_STEPS})")
    if hasattr(args, "backend"):
        _engine(args)
    if hasattr(args, "solver"):  # the minimizer's own checks (solver and A that apply, ...)
        _library(minimizer_from, args)
    elif hasattr(args, "method"):  # ensemble: method, preconditioner and engine
        _library(Minimizer, args.method, precon_from(args), backend=args.backend)
    if args.command == "ensemble" and args.batch is not None:
        try:
            check_batch(args.batch, args.n, args.dim, args.backend, args.workers, args.scheduler)
        except InputError as exc:
            raise InputError(f"--{exc}") from None
    if args.command == "relax" and args.pressure is not None:
        _library(check_enthalpy_method, args.method, args.precon or "none")
    if args.command == "shear" and _plastic(args):
        extent = args.strain
        if args.cycles is not None and args.amplitude is not None:
            extent = _library(check_cycles, args.amplitude, args.cycles)
        _library(check_steps, args.step, args.max_step, args.tol, extent)
    if args.command == "criticality":
        for option in ("force_window", "gap_window"):
            low, high = getattr(args, option)
            if not 0 < low < high:
                raise InputError(
                    f"--{option.replace('_', '-')}: need 0 < LOW < HIGH, got {low:g} {high:g}"
                )
        for path in args.inputs:
            if not Path(path).is_file():
                raise InputError(f"input: {path}: no such file")
    certifying = args.command == "jam" and args.certify
    if args.command in ("jam", "ensemble") and args.epsilon < RESOLUTION:
        if not certifying or args.alpha != 2.0:
            raise InputError(
                f"--epsilon: {args.epsilon:g} is below {RESOLUTION:g}, the resolution of float64's "
                "jammed/unjammed verdict; jam --certify (alpha = 2) bisects in double-double down "
                "to 1e-15"
            )
    if certifying or (args.command in ("certify", "criticality") and args.alpha is not None):
        try:
            PowerContact(args.alpha).half_steps()
        except InputError as exc:
            raise InputError(f"--{exc}") from None
    if args.command == "jam" and args.certify and args.pressure is not None:
        raise InputError("--certify: certifies the jammed packing; drop --pressure or --certify")
    if args.command == "jam" and args.certify and args.walls:
        raise InputError("--certify: packings between walls are not certified yet; drop --walls")
    if args.command == "bench":
        _bench(args)
    if args.command == "modes":
        if Path(args.output).suffix != ".npz":
            raise InputError(f"--output: {args.output}: the modes go to an .npz file")
        if args.lowest is not None and args.figure not in (None, "none"):
            raise InputError("--figure: D(omega) needs the full spectrum; drop --lowest")
        if args.lowest is not None and args.vectors > args.lowest:
            raise InputError(f"--vectors {args.vectors} exceeds --lowest {args.lowest}")
    if hasattr(args, "strain"):  # shear, ensemble shear
        if _library(strain_steps, args.strain, args.step) > MAX_STEPS:
            raise InputError(
                f"--step: {args.strain / args.step:.2g} strain steps (at most {MAX_STEPS})"
            )


def _library(
    check: Callable[..., T], *args: object, flag: str | None = None, **kwargs: object
) -> T:
    """Run one of the library's own checks and return what it returns; its refusal names the
    command-line option (``flag``, else the option of the name the library gives)."""
    try:
        return check(*args, **kwargs)
    except InputError as exc:
        if flag is None:
            raise InputError(flagged(str(exc), None)) from None
        raise InputError(f"{flag}: {str(exc).partition(': ')[2]}") from None


def flagged(message: str, args: argparse.Namespace | None) -> str:
    """A library refusal (``name: what is wrong``) as the command line says it: ``--name: ...``
    when ``name`` is one of the command's options (any option's name when ``args`` is None)."""
    name, colon, rest = message.partition(": ")
    if not colon or not name.isidentifier() or (args is not None and not hasattr(args, name)):
        return message
    if name in ("input", "inputs", "command", "protocol"):
        return message
    return f"{FLAGS.get(name, '--' + name.replace('_', '-'))}: {rest}"


SHEAR_OPTIONS = frozenset({"tol", "max_step", "figure", "amplitude", "cycles", "strain"})
"""Options whose needs :func:`_idle` checks in ``shear`` only (other commands have their own
options of these names)."""


def _idle(args: argparse.Namespace) -> None:
    """Options given that would do nothing here: refused, naming what they need."""
    given: frozenset[str] = getattr(args, "given", frozenset())
    needs = {
        "cell": ("pressure", "relaxes the cell at a pressure; add --pressure"),
        "pressure_rtol": ("pressure", "the accuracy of --pressure; add --pressure"),
        "wall_layer": ("plane", "glues particles to the walls in plane shear; add --mode plane"),
        "polydispersity": ("continuous", "the width of --sizes uniform or lognormal; add one"),
        "size_ratio": ("bidisperse", "the bidisperse mixture's; drop --sizes"),
        "picture": ("2D", "pictures are drawn in 2D only; drop --picture"),
        "tol": ("events", "the bracket of an exact event; add --events"),
        "max_step": ("events", "the largest step between exact events; add --events"),
        "figure": ("events", "the figure of a run with exact events; add --events"),
        "amplitude": ("cycles", "cyclic shear's amplitude; add --cycles"),
        "cycles": ("amplitude", "cyclic shear needs its amplitude; add --amplitude"),
        "strain": ("straight", "cyclic shear goes to +-amplitude; drop --strain"),
        "rtol": ("steps", "exact events relax every state to round-off; drop --rtol"),
    }
    have = {
        "pressure": getattr(args, "pressure", None) is not None,
        "plane": getattr(args, "mode", None) == "plane",
        "continuous": getattr(args, "sizes", "bidisperse") != "bidisperse",
        "bidisperse": getattr(args, "sizes", "bidisperse") == "bidisperse",
        "2D": getattr(args, "dim", 2) == 2 or getattr(args, "picture", None) == "none",
        "events": _plastic(args),
        "cycles": getattr(args, "cycles", None) is not None,
        "amplitude": getattr(args, "amplitude", None) is not None,
        "straight": getattr(args, "cycles", None) is None,
        "steps": not _plastic(args),
    }
    for option, (need, what) in needs.items():
        if option in SHEAR_OPTIONS and args.command != "shear":
            continue  # ensemble events and cycles, modes' and criticality's --figure
        if option in given and not have[need]:
            raise InputError(f"{FLAGS.get(option, '--' + option.replace('_', '-'))}: {what}")
    if "table" in given and _plastic(args):
        raise InputError("--table: a run with exact events writes its tables beside --output")
    if "resume" in given:
        path = Path(_trajectory_of(args))
        if not path.exists():
            raise InputError(
                f"--resume: nothing to resume ({path} does not exist); drop --resume to start"
            )
    if given & {"workers", "scheduler"} and importlib.util.find_spec("distributed") is None:
        raise InputError(f"--{min(given & {'workers', 'scheduler'})}: {INSTALL_HINT}")


def _plastic(args: argparse.Namespace) -> bool:
    """Whether the command is a shear with exact events (``--events`` or ``--cycles``)."""
    return bool(getattr(args, "events", False)) or getattr(args, "cycles", None) is not None


def _trajectory_of(args: argparse.Namespace) -> str:
    """The trajectory a protocol command appends to (``--resume`` continues it)."""
    if args.command == "jam":
        return str(args.trajectory or Path(args.output).with_suffix(".steps.gsd"))
    return str(args.output)


def _engine(args: argparse.Namespace) -> None:
    """``--backend``: the engine can run here and do what the command asks (walls, ``relax
    --pressure``'s enthalpy, ``--deterministic``, which it is then asked for)."""
    engine = engines.check(
        args.backend,
        walls=bool(getattr(args, "walls", "")),
        enthalpy=args.command == "relax" and args.pressure is not None,
        deterministic=args.deterministic,
    )
    if args.deterministic:  # read by the engine's compiler when it starts, not before
        engine.make_deterministic()


def _bench(args: argparse.Namespace) -> None:
    """``--alphas`` the Table has start configurations for; no option that ``--quick`` would
    replace (it runs its own cases, alpha, methods and repeats)."""
    try:
        check_alphas(args.alphas)
    except InputError as exc:
        raise InputError(f"--{exc}") from None
    if args.quick:
        from .parser import build, subparser

        bench = subparser(build(), "bench")
        for dest in ("cases", "alphas", "methods", "repeats"):
            if getattr(args, dest) != bench.get_default(dest):
                raise InputError(f"--{dest}: --quick sets its own; drop --quick or --{dest}")


def _largest_radius(args: argparse.Namespace, phi: float) -> float:
    """The largest radius of ``args.n`` particles of the size options at ``phi`` in the unit
    cell: exact for the 1:1 bidisperse mixture and the uniform distribution's bound; for the
    log-normal one the typical largest of N draws, ``exp(s sqrt(2 ln N) - s^2 / 2)``."""
    n, dim, unit = args.n, args.dim, (math.pi if args.dim == 2 else 4.0 * math.pi / 3.0)
    if args.sizes == "bidisperse":
        ratio = args.size_ratio
        small, large = n - n // 2, n // 2
        return float(ratio * (phi / (unit * (small + large * ratio**dim))) ** (1.0 / dim))
    w2 = args.polydispersity**2
    if args.sizes == "uniform":
        largest, moment = 1.0 + math.sqrt(3.0 * w2), (1.0 + w2 if dim == 2 else 1.0 + 3.0 * w2)
    else:
        s = math.sqrt(math.log1p(w2))
        largest = math.exp(s * math.sqrt(2.0 * math.log(n)) - s * s / 2.0)
        moment = (1.0 + w2) ** (dim * (dim - 1) // 2)  # E[r^d] at mean 1
    return float(largest * (phi / (unit * n * moment)) ** (1.0 / dim))


def _memory() -> int:
    """The machine's physical memory in bytes (0 where unknown)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 0


def output_files(args: argparse.Namespace) -> dict[str, Path]:
    """The files a command will write, by the option that names them."""
    out: dict[str, Path] = {}
    command = args.command
    if command in ("random", "relax", "jam", "compress", "shear", "certify"):
        out["--output"] = Path(args.output)
    if command == "jam":
        out["--trajectory"] = Path(args.trajectory or Path(args.output).with_suffix(".steps.gsd"))
        if args.dim == 2 and args.picture != "none":
            out["--picture"] = Path(args.picture or Path(args.output).with_suffix(".png"))
    if command in ("jam", "compress", "shear"):
        out["--table"] = Path(args.table or Path(args.output).with_suffix(".csv"))
    if command == "shear" and _plastic(args):
        out["--events"] = Path(args.output).with_suffix(".events.csv")
        if args.cycles is not None:
            out["--cycles"] = Path(args.output).with_suffix(".cycles.csv")
        if args.figure != "none":
            out["--figure"] = Path(args.figure or Path(args.output).with_suffix(".png"))
    if command == "criticality" and args.figure is not None:
        out["--figure"] = Path(args.figure)
    if command == "measure" and args.forces_figure is not None:
        out["--forces-figure"] = Path(args.forces_figure)
    if command == "modes":
        out["--output"] = Path(args.output)
        if args.figure != "none" and (args.figure is not None or args.lowest is None):
            out["--figure"] = Path(args.figure or Path(args.output).with_suffix(".png"))
    return out


def _file_names(args: argparse.Namespace) -> None:
    """Each file option names a file, not a folder."""
    for option in ("output", "trajectory", "table", "picture", "figure", "forces_figure"):
        value = getattr(args, option, None)
        if value is None or (option == "output" and args.command in ("paper", "ensemble")):
            continue
        if option in ("picture", "figure") and value == "none":
            continue
        flag = "--" + option.replace("_", "-")
        if str(value).strip() == "":
            raise InputError(f"{flag}: an empty path")
        if (
            str(value).endswith(("/", os.sep))
            or Path(value).name in ("", ".", "..")
            or (Path(value).is_dir())
        ):
            raise InputError(f"{flag}: {value} is a folder; name a file in it")


def _writable(option: str, path: Path, folder: Path) -> None:
    """Refuse ``path`` when no file can be made in ``folder``: a file is made and removed there
    (permissions, a read-only mount, a pseudo-filesystem such as /proc)."""
    try:
        handle, probe = tempfile.mkstemp(dir=folder, prefix=".athermal-")
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        raise InputError(f"{option}: {path}: cannot write in the folder {folder} ({why})") from None
    os.close(handle)
    os.unlink(probe)


def _paths(args: argparse.Namespace) -> None:
    """Every output: a new or regular file in a writable folder, distinct from the others and
    from the input; an existing one only with ``--overwrite`` (or ``--resume``)."""
    outputs = output_files(args)
    seen: dict[Path, str] = {}
    inputs = {Path(args.input).resolve()} if getattr(args, "input", None) else set()
    inputs |= {Path(path).resolve() for path in getattr(args, "inputs", ())}
    replace = getattr(args, "overwrite", False) or getattr(args, "resume", False)
    for option, path in outputs.items():
        folder = path.parent if str(path.parent) else Path(".")
        if not folder.is_dir():
            raise InputError(f"{option}: {path}: the folder {folder} does not exist")
        _writable(option, path, folder)
        if path.exists():
            if not stat.S_ISREG(path.stat().st_mode):
                raise InputError(f"{option}: {path} exists and is not a regular file")
            if not replace:
                again = " (or continue the run with --resume)" if hasattr(args, "resume") else ""
                raise InputError(f"{option}: {path} exists; replace it with --overwrite{again}")
        key = path.resolve()
        if key in seen:
            raise InputError(f"{option}: {path} is also {seen[key]}")
        if key in inputs:
            raise InputError(f"{option}: {path} is the input file")
        seen[key] = option
    if args.command in ("paper", "ensemble"):
        target = Path(args.output)
        if target.exists() and not target.is_dir():
            raise InputError(f"--output: {target} exists and is not a directory")
        if args.command == "paper" and (target / "report.md").exists() and not args.overwrite:
            raise InputError(
                f"--output: {target} holds the report of an earlier run; replace it with "
                "--overwrite"
            )
        parent = target.parent if str(target.parent) else Path(".")
        if not target.exists() and not parent.is_dir():
            raise InputError(f"--output: the folder {parent} does not exist")
        _writable("--output", target, target if target.exists() else parent)


def check_request(args: argparse.Namespace) -> None:
    """Refuse a command whose options or outputs are wrong, before any work (module docstring)."""
    _options(args)
    _file_names(args)
    _idle(args)
    _work(args)
    _paths(args)
