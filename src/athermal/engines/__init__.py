"""The engines that relax a packing's energy, behind one interface, looked up by name.

An engine (:class:`Engine`) declares what it can do (:class:`Capabilities`) and, bound to one
:class:`~athermal.model.objective.Objective` and preconditioner (:meth:`Engine.bind`), minimizes
from flat vectors in the objective's internal order (:class:`Session`). Every question "can this
engine do that" is answered here, by :func:`check`, before any work; no other module compares an
engine's name. Two are registered: ``numba`` (:mod:`.numba`, the default: every method,
preconditioner and geometry) and ``jax`` (:mod:`.jax`, the extra ``athermal[jax]``). Another is
one class and one :func:`register` call (``docs/howto/engine.md``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..minimize import MinimizeResult

if TYPE_CHECKING:
    from ..model.objective import Objective

DEFAULT = "numba"
"""The engine of a :class:`~athermal.relaxation.Minimizer` that names none."""


@dataclass(frozen=True)
class Capabilities:
    """What an engine can do.

    Parameters
    ----------
    methods : the base methods it runs (``lbfgs``, ``cg``, ``fire``, ``newton``).
    preconditioners : the preconditioners it applies (``none``, ``exp``, ``contact``).
    fire_preconditioned : FIRE with a preconditioner (else FIRE runs without one).
    solvers : the preconditioner's linear solver can be chosen (``direct``, ``amg``, ``ic0``).
    walls : packings between walls.
    frozen : particles held fixed (plane shear's glued layers).
    enthalpy : relaxation at a fixed pressure with the cell free (``relax --pressure``).
    batches : many packings of one size relaxed as one batch (:meth:`Engine.batcher`).
    deterministic : has a mode that must be asked for to give the same bits run after run
        (:meth:`Engine.make_deterministic`); an engine without it gives them always or never.
    warm_up : compiles on its first run at a size: a timing runs once untimed first.
    """

    methods: tuple[str, ...]
    preconditioners: tuple[str, ...] = ("none",)
    fire_preconditioned: bool = False
    solvers: bool = False
    walls: bool = False
    frozen: bool = False
    enthalpy: bool = False
    batches: bool = False
    deterministic: bool = False
    warm_up: bool = False


class Session(Protocol):
    """An engine bound to one objective and its preconditioner (:meth:`Engine.bind`)."""

    @property
    def n_rebuilds(self) -> int:
        """Verlet-list builds so far."""
        ...

    def minimize(
        self,
        method: str,
        x: NDArray[np.float64],
        *,
        gtol: float,
        etol: float,
        maxiter: int,
        precon: str | None = None,
    ) -> MinimizeResult:
        """Minimize from ``x`` ``(N d,)`` (internal order) by the base ``method`` to
        ``max_i |grad_i| <= gtol`` or energy ``<= etol`` within ``maxiter`` iterations, with
        the bound preconditioner (``precon`` None) or the one named ``precon``."""
        ...


class Engine(ABC):
    """An engine: its ``name``, a ``label`` for messages, its :class:`Capabilities`, and how it
    binds to an objective. The optional parts (batches, a deterministic mode) raise unless the
    capabilities declare them."""

    name: ClassVar[str]
    label: ClassVar[str]
    capabilities: ClassVar[Capabilities]

    def missing(self) -> str:
        """Empty when the engine can run here, else the one line that says what to install."""
        return ""

    @abstractmethod
    def bind(self, objective: Objective, precon: str, *, A: float, solver: str) -> Session:
        """The engine bound to ``objective`` with the preconditioner ``precon`` (parameter
        ``A``, linear ``solver``), checked by :func:`check` before."""

    def machine_dependence(self, precon: str, solver: str, n: int, dim: int) -> str:
        """Empty when relaxations of ``n`` particles in ``dim`` dimensions with ``precon`` and
        ``solver`` are the same bits on every CPU, else what makes them this machine's."""
        return f"{self.label}: not shown to give the same bits everywhere"

    def make_deterministic(self) -> None:
        """Ask for the same bits run after run (``capabilities.deterministic``)."""
        raise InputError(f"backend {self.name}: no deterministic mode")

    def batch_bytes(self, n: int, dim: int) -> tuple[int, int]:
        """Device memory one member of a batch of ``n`` particles in ``dim`` dimensions
        needs, and the memory free (bytes)."""
        raise InputError(f"backend {self.name}: no batches")

    def batcher(self, size: int) -> Any:
        """A batcher of ``size`` members: ``with batcher.member():`` around each member's
        relaxations, run in threads of this process; it counts ``calls`` and ``members``."""
        raise InputError(f"backend {self.name}: no batches")

    def describe(self) -> str:
        """Where the engine runs, for reports."""
        return self.label


_FACTORIES: dict[str, Callable[[], Engine]] = {}
_ENGINES: dict[str, Engine] = {}


def register(name: str, factory: Callable[[], Engine]) -> None:
    """Make ``factory()`` the engine called ``name`` (``Minimizer(backend=name)``,
    ``--backend name``); the factory runs once, when the engine is first asked for, so that
    registering imports nothing heavy."""
    if name in _FACTORIES:
        raise InputError(f"backend {name}: an engine of that name is registered already")
    _FACTORIES[name] = factory


def unregister(name: str) -> None:
    """Forget the engine called ``name`` (a test's, or a plugin's being replaced)."""
    if name == DEFAULT:
        raise InputError(f"backend {name}: the default engine stays")
    _FACTORIES.pop(name, None)
    _ENGINES.pop(name, None)


def names() -> tuple[str, ...]:
    """The registered engines' names, in the order they were registered."""
    return tuple(_FACTORIES)


def engine(name: str) -> Engine:
    """The engine called ``name``; :class:`InputError` for an unknown name (listing the
    engines) or an engine that cannot run here (saying what to install)."""
    if name not in _FACTORIES:
        raise InputError(f"backend: {name!r} is not one of {', '.join(map(repr, names()))}")
    if name not in _ENGINES:
        _ENGINES[name] = _FACTORIES[name]()
    found = _ENGINES[name]
    if why := found.missing():
        raise InputError(why)
    return found


def with_capability(what: str) -> tuple[str, ...]:
    """The registered engines whose capability ``what`` is true, without building them."""
    return tuple(n for n in names() if getattr(capabilities_of(n), what))


def check(
    name: str,
    method: str | None = None,
    precon: str = "none",
    solver: str = "auto",
    *,
    walls: bool = False,
    frozen: bool = False,
    enthalpy: bool = False,
    batch: bool = False,
    deterministic: bool = False,
) -> Engine:
    """The engine called ``name`` after checking that it can do what is asked: the base
    ``method`` with ``precon`` and a chosen ``solver`` (not ``auto``), walls, frozen
    particles, the enthalpy, batches, a deterministic mode. Raises :class:`InputError` with one
    line naming the engine and what it lacks."""
    found = engine(name)
    caps, label = found.capabilities, f"backend {name}: {found.label}"
    if method is not None:
        if method not in caps.methods or precon not in caps.preconditioners:
            raise InputError(
                f"{label} runs {', '.join(caps.methods)} with precon "
                f"{' or '.join(caps.preconditioners)}; got {method} with {precon}"
            )
        if method == "fire" and precon != "none" and not caps.fire_preconditioned:
            raise InputError(f"{label} runs FIRE without a preconditioner; got {precon}")
        if solver != "auto" and not caps.solvers:
            raise InputError(
                f"solver: {found.label} applies its preconditioner its own way, with no "
                "solver to choose"
            )
    lacks = [
        (walls, "walls", "has no walls yet; relax packings between walls"),
        (frozen, "frozen", "holds no particle fixed; relax frozen particles"),
        (enthalpy, "enthalpy", "has no enthalpy; relax at a pressure"),
        (batch, "batches", "runs no batches; run them"),
    ]
    for asked, capability, what in lacks:
        if asked and not getattr(caps, capability):
            able = " or ".join(f"--backend {e}" for e in with_capability(capability))
            raise InputError(f"{label} {what} with {able}")
    if deterministic and not caps.deterministic:
        why = "gives the same bits everywhere already" if name == DEFAULT else "has none"
        raise InputError(
            f"--deterministic: only with --backend "
            f"{' or '.join(with_capability('deterministic'))} ({found.label} {why})"
        )
    return found


def capabilities_of(name: str) -> Capabilities:
    """The capabilities of the engine called ``name`` (declared on its class: nothing is
    built or imported)."""
    factory = _FACTORIES[name]
    caps = getattr(factory, "capabilities", None)
    return caps if isinstance(caps, Capabilities) else engine(name).capabilities


def _builtin() -> None:
    """Register the two engines that come with athermal."""
    from .jax import JaxEngine
    from .numba import NumbaEngine

    register("numba", NumbaEngine)
    register("jax", JaxEngine)


_builtin()
