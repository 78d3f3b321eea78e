"""The ``athermal`` command (docs/contract.md): the parser (:mod:`.parser`), the checks of a
request before any work (:mod:`.door`), the subcommands (:mod:`.basic`, :mod:`.analysis`,
:mod:`.protocols`, :mod:`.studies`) and their one printer (:mod:`.printer`)."""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

from ..errors import ConvergenceError, InputError
from . import analysis, basic, protocols, studies
from .common import NotConverged
from .door import check_request, flagged
from .parser import build, subparser

COMMANDS: dict[str, Callable[[argparse.Namespace], None]] = {
    "random": basic.random,
    "measure": basic.measure_file,
    "relax": basic.relax,
    "modes": analysis.modes,
    "moduli": analysis.moduli,
    "certify": analysis.certify_file,
    "criticality": analysis.criticality,
    "bench": basic.bench,
    "jam": protocols.jam,
    "compress": protocols.compress,
    "shear": protocols.shear,
    "paper": studies.paper,
    "ensemble": studies.ensemble,
}
"""Each subcommand's function, by name."""


def _version() -> str:
    """The installed package's version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("athermal")
    except PackageNotFoundError:
        return "unknown"


def _one_line_warning(command: str) -> Callable[..., None]:
    """A ``warnings.showwarning`` that prints ``athermal COMMAND: warning: message`` on stderr."""

    def show(message: Warning | str, *_: object, **__: object) -> None:
        print(f"athermal {command}: warning: {message}", file=sys.stderr)

    return show


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    """The parsed arguments; an unknown option is reported first, by its subcommand's parser.

    argparse stops at a missing required argument before it names the unknown ones, so a
    misspelt ``--ouput`` would read as "-o required": a first pass with nothing required
    collects the unknown options, the second one parses with every rule. A request for help
    skips the first pass, so that the usage shows the required options as required. The
    namespace's ``given`` holds the destinations of the options on the command line (as typed
    or abbreviated), for the door's checks of options that would do nothing.
    """
    parser = build()
    words = sys.argv[1:] if argv is None else list(argv)
    if "-h" in words or "--help" in words:
        return parser.parse_args(words)
    with _nothing_required(parser), _no_defaults(parser):
        given, unknown = parser.parse_known_args(words)
    if unknown:
        where = parser if given.command is None else subparser(parser, given.command)
        if getattr(given, "protocol", None) is not None:  # ensemble PROTOCOL
            where = subparser(where, given.protocol)
        where.error(f"unrecognized arguments: {' '.join(unknown)}")
    args = parser.parse_args(words)
    args.given = frozenset(vars(given)) - {"command", "protocol", "default_precon"}
    return args


def _actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """Every action of ``parser`` and of its subcommands, at any depth."""
    actions = list(parser._actions)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            actions += [a for sub in action.choices.values() for a in _actions(sub)]
    return actions


@contextmanager
def _no_defaults(parser: argparse.ArgumentParser) -> Iterator[None]:
    """No default for any argument of ``parser`` or its subcommands while inside: a namespace
    parsed then holds only the arguments given."""
    actions = [a for a in _actions(parser) if not isinstance(a, argparse._SubParsersAction)]
    defaults = [a.default for a in actions]
    for action in actions:
        action.default = argparse.SUPPRESS
    try:
        yield
    finally:
        for action, default in zip(actions, defaults, strict=True):
            action.default = default


@contextmanager
def _nothing_required(parser: argparse.ArgumentParser) -> Iterator[None]:
    """Every argument of ``parser`` and of its subcommands optional while inside."""
    required = [a for a in _actions(parser) if a.required]
    for action in required:
        action.required = False
    try:
        yield
    finally:
        for action in required:
            action.required = True


def _interrupted(args: argparse.Namespace) -> int:
    """Report an interrupted command in one line; its exit code, 130."""
    again = "; rerun with --resume to continue" if hasattr(args, "resume") else ""
    if args.command == "ensemble":
        again = "; rerun the same command to continue (finished realizations are kept)"
    print(f"athermal {args.command}: interrupted{again}", file=sys.stderr)
    return 130


def _caused_by_interrupt(exc: BaseException) -> bool:
    """Whether a ``KeyboardInterrupt`` stands in the chain of causes of ``exc``: numba reports
    one raised while its compiled code calls back into Python (its ``_numba_unpickle``) as a
    ``SystemError``, "returned a result with an exception set" (seen once in CI, in the SIGINT
    test of ``athermal jam``)."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``athermal`` command; returns the exit code."""
    args = _parse(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _one_line_warning(args.command)
            check_request(args)
            COMMANDS[args.command](args)
    except BrokenPipeError:  # the reader of stdout went away (`athermal ... --json | head`)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except KeyboardInterrupt:
        return _interrupted(args)
    except SystemError as exc:  # Ctrl-C while compiled code called back into Python
        if not _caused_by_interrupt(exc):
            raise
        return _interrupted(args)
    except (InputError, ConvergenceError) as exc:
        text = flagged(str(exc), args) if isinstance(exc, InputError) else str(exc)
        print(f"athermal {args.command}: error: {text}", file=sys.stderr)
        return 2 if isinstance(exc, InputError) else 3
    except NotConverged as exc:
        print(f"athermal {args.command}: {exc}", file=sys.stderr)
        return 3
    except OSError as exc:
        text = f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": ")
        print(f"athermal {args.command}: error: {text}", file=sys.stderr)
        return 1
    return 0
