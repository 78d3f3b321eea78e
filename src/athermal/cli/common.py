"""What the subcommands share: progress on stderr, the contact model and minimizer of the
options, the observables written with a configuration."""

from __future__ import annotations

import argparse
import sys
from typing import Any, cast

from ..certify import Certificate
from ..engines.precon import PreconName
from ..model.cell import Cell
from ..model.contact import ContactModel
from ..relaxation import Minimizer


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


class NotConverged(RuntimeError):
    """A minimization that stopped short of its tolerance (its result was still written)."""


def model_from(args: argparse.Namespace, fallback: ContactModel | None) -> ContactModel:
    """The contact model of ``--alpha`` / ``--stiffness``, else ``fallback``'s, else the default
    (the wall stiffness always ``fallback``'s)."""
    base = fallback if fallback is not None else ContactModel()
    return ContactModel(
        alpha=base.alpha if args.alpha is None else args.alpha,
        stiffness=base.stiffness if args.stiffness is None else args.stiffness,
        wall_stiffness=base.wall_stiffness,
    )


def precon_from(args: argparse.Namespace) -> str:
    """``--precon``, or when it is not given the command's default (``none`` for newton)."""
    if args.precon is not None:
        return str(args.precon)
    return "none" if args.method == "newton" else str(args.default_precon)


def minimizer_from(args: argparse.Namespace) -> Minimizer:
    """The minimizer of ``--method``, ``--precon``, ``--A``, ``--solver``, ``--maxiter``,
    ``--backend``."""
    return Minimizer(
        args.method,
        cast(PreconName, precon_from(args)),
        args.A,
        args.solver,
        args.maxiter,
        args.backend,
    )


def sizes_from(args: argparse.Namespace) -> dict[str, Any]:
    """The size options (``--sizes``, ``--size-ratio``, ``--polydispersity``) as keyword
    arguments of :func:`~athermal.model.packing.random_packing` and
    :class:`~athermal.studies.experiments.JamSpec`."""
    return {
        "sizes": args.sizes,
        "size_ratio": args.size_ratio,
        "polydispersity": args.polydispersity,
    }


def cell_from(args: argparse.Namespace) -> Cell:
    """The unit cell with the walls of ``--walls``."""
    return Cell.unit(args.dim, args.walls)


def check_certified(certificate: Certificate) -> None:
    """Raise :class:`NotConverged` (exit code 3) when the refinement stopped short of its
    target; the packing and its certificate were written."""
    if not certificate.converged:
        raise NotConverged(
            f"not certified: the refinement reached {certificate.relative_force_balance:.1e} of "
            f"the mean contact force, not {certificate.target:g} (the precision's limit); the "
            "packing and its certificate are written"
        )


def bits(minimizer: Minimizer, n: int, dim: int) -> str:
    """The ``bits`` a command prints: ``portable`` when its relaxations are the same bits on
    every CPU, else why they are this machine's (:meth:`Minimizer.machine_dependence`)."""
    return minimizer.machine_dependence(n, dim) or "portable"
