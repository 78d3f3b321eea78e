"""How a relaxation is done, in one spelling: :class:`Minimizer` (method, preconditioner and
their parameters) and its display name, and the seed's force tolerance :data:`RTOL`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from .._validate import choice
from ..errors import InputError
from ..linalg import SOLVERS, SolverName
from ..precon import PRECONDITIONERS, PreconName

Method = Literal["lbfgs", "cg", "fire", "newton", "plbfgs", "pcg"]
METHODS: tuple[str, ...] = ("lbfgs", "cg", "fire", "newton", "plbfgs", "pcg")
_ALIASES: dict[str, tuple[str, PreconName]] = {"plbfgs": ("lbfgs", "exp"), "pcg": ("cg", "exp")}
_NAMES = {"lbfgs": "L-BFGS", "cg": "FR-CG", "fire": "FIRE", "newton": "Newton-CG"}
NEWTON_TAKES_NO_PRECON = "precon: newton preconditions with its own Hessian factor; give 'none'"
RTOL = 1e-9
"""The seed's tolerance: ``max_i |grad_i| <= RTOL`` x the mean contact force at the start of a
relaxation (the Table, every quasi-static step)."""


def resolve_method(method: str, precon: PreconName = "none") -> tuple[str, PreconName]:
    """The base method (``lbfgs``, ``cg``, ``fire``, ``newton``) and preconditioner that
    ``method`` with ``precon`` names: ``plbfgs`` and ``pcg`` imply ``exp`` unless another is
    given; ``newton`` takes none (its own factored Hessian preconditions its inner CG)."""
    choice(method, "method", METHODS)
    choice(precon, "precon", PRECONDITIONERS)
    if method == "newton" and precon != "none":
        raise InputError(f"{NEWTON_TAKES_NO_PRECON}; got {precon!r}")
    base, implied = _ALIASES.get(method, (method, "none"))
    return base, implied if precon == "none" else precon


@dataclass(frozen=True)
class Minimizer:
    """The energy minimizer of a relaxation: the one spelling used by the protocols, the
    benchmarks, ``paper`` and ``ensemble``.

    Parameters
    ----------
    method : ``lbfgs``, ``cg``, ``fire``, ``newton`` or the seed's ``plbfgs`` / ``pcg``.
    precon : ``none``, ``exp`` (the seed's, weights parameter ``A``) or ``contact``.
    A : Exp weight decay (dimensionless, >= 0).
    solver : ``auto``, ``direct``, ``amg`` or ``ic0`` for the preconditioner's linear solves.
    maxiter : iteration limit of one relaxation; a protocol that reaches it stops with a
        :class:`~athermal.errors.ConvergenceError`.
    """

    method: Method = "lbfgs"
    precon: PreconName = "none"
    A: float = 0.0
    solver: SolverName = "auto"
    maxiter: int = 1_000_000

    def __post_init__(self) -> None:
        resolve_method(self.method, self.precon)
        choice(self.solver, "solver", SOLVERS)
        if int(self.maxiter) != self.maxiter or self.maxiter < 1:
            raise InputError(f"maxiter: must be an integer >= 1, got {self.maxiter!r}")
        if not self.A >= 0.0:
            raise InputError(f"A: must be >= 0, got {self.A!r}")

    @property
    def label(self) -> str:
        """Machine label ``method`` or ``method+precon``, e.g. ``lbfgs+exp`` (``--json``)."""
        base, precon = resolve_method(self.method, self.precon)
        return base if precon == "none" else f"{base}+{precon}"

    @property
    def name(self) -> str:
        """Display name as in the seed: ``L-BFGS``, ``P-L-BFGS``, ``P-FR-CG``, ``contact
        P-L-BFGS``, ``FIRE``; a non-zero ``A`` or a chosen solver is added in brackets."""
        base, precon = resolve_method(self.method, self.precon)
        name = _NAMES[base]
        if precon == "exp":
            name = f"P-{name}"
        elif precon == "contact":
            name = f"contact P-{name}"
        extras = [f"A={self.A:g}"] if precon == "exp" and self.A != 0.0 else []
        if precon != "none" and self.solver != "auto":
            extras.append(self.solver)
        return f"{name} ({', '.join(extras)})" if extras else name
