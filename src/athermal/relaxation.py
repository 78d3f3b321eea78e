"""Relaxing a packing: how (:class:`Minimizer`, the paper's method names and the force tolerance
:data:`RTOL`) and doing it (:func:`relax`), on the minimizers of :mod:`athermal.minimize`.

The physics above the minimizer library: the tolerance relative to the mean contact force
(``rtol``), the preconditioners by name (:mod:`athermal.precon`), the hooks of an
:class:`~athermal.objective.Objective` (particles of ``d`` coordinates, the step cap, the
round-off of the contact energy, its compiled line search, FIRE's curvature bound) and the
packing at the result (:class:`Relaxation`).
"""

from __future__ import annotations

import importlib.util
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Literal, cast

import numpy as np
from numpy.typing import NDArray

from . import minimize as library
from ._portable import power
from ._validate import choice
from .cell import Cell
from .contact import ContactModel, Contacts, find_contacts
from .errors import FROZEN_NOT_ON_JAX, JAX_MISSING, ConvergenceError, InputError
from .linalg import SOLVERS, SolverName, available, resolve_solver
from .minimize import NEWTON_TAKES_NO_PRECON, MinimizeResult, Preconditioner, Status
from .moduli import stability
from .objective import Objective
from .packing import Packing
from .precon import PRECONDITIONERS, PreconName, make_preconditioner

Method = Literal["lbfgs", "cg", "fire", "newton", "plbfgs", "pcg"]
METHODS: tuple[str, ...] = ("lbfgs", "cg", "fire", "newton", "plbfgs", "pcg")
Backend = Literal["numba", "jax"]
BACKENDS: tuple[str, ...] = ("numba", "jax")
_ALIASES: dict[str, tuple[str, PreconName]] = {"plbfgs": ("lbfgs", "exp"), "pcg": ("cg", "exp")}
_NAMES = {"lbfgs": "L-BFGS", "cg": "FR-CG", "fire": "FIRE", "newton": "Newton-CG"}
RTOL = 1e-9
"""The paper's tolerance: ``max_i |grad_i| <= RTOL`` x the mean contact force at the start of a
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
    method : ``lbfgs``, ``cg``, ``fire``, ``newton`` or the paper's ``plbfgs`` / ``pcg``.
    precon : ``none``, ``exp`` (the paper's, weights parameter ``A``) or ``contact``.
    A : Exp weight decay (dimensionless, >= 0).
    solver : ``auto``, ``direct``, ``amg`` or ``ic0`` for the preconditioner's linear solves.
    maxiter : iteration limit of one relaxation; a protocol that reaches it stops with a
        :class:`~athermal.errors.ConvergenceError`.
    backend : the engine: ``numba`` (CPU) or ``jax`` (:mod:`athermal.jaxengine`, the extra
        ``athermal[jax]``; ``lbfgs``, ``cg``, ``fire``, ``plbfgs``, ``pcg``, preconditioners
        ``none`` and ``exp``, FIRE without one; ``solver`` does not apply there).
    """

    method: Method = "lbfgs"
    precon: PreconName = "none"
    A: float = 0.0
    solver: SolverName = "auto"
    maxiter: int = 1_000_000
    backend: Backend = "numba"

    def __post_init__(self) -> None:
        base, precon = resolve_method(self.method, self.precon)
        choice(self.solver, "solver", SOLVERS)
        choice(self.backend, "backend", BACKENDS)
        if self.backend == "jax":
            if importlib.util.find_spec("jax") is None:
                raise InputError(JAX_MISSING)
            from . import jaxengine  # the extra, there: imported when asked for

            jaxengine.check_supported(base, precon)
        if int(self.maxiter) != self.maxiter or self.maxiter < 1:
            raise InputError(f"maxiter: must be an integer >= 1, got {self.maxiter!r}")
        if not self.A >= 0.0:
            raise InputError(f"A: must be >= 0, got {self.A!r}")
        if self.A != 0.0 and precon != "exp":
            raise InputError(f"A: the Exp preconditioner's parameter, and the precon is {precon}")
        if self.solver != "auto" and self.backend == "jax":
            raise InputError(
                "solver: the JAX engine applies its preconditioner one way (a V-cycle on the "
                "device), with no solver to choose"
            )
        if self.solver != "auto" and precon == "none":
            raise InputError("solver: the preconditioner's linear solver, and the precon is none")

    def machine_dependence(self, n: int, dim: int) -> str:
        """Empty when this minimizer's relaxations of ``n`` particles in ``dim`` dimensions are
        the same bits on every CPU, else what makes them this machine's: a solver that sums in
        its BLAS's order, or another engine (``docs/decisions.md``, "Same input, same bits")."""
        if self.backend == "jax":
            return "the JAX engine: XLA compiles for each device"
        _, precon = resolve_method(self.method, self.precon)
        if precon == "none":
            return ""
        solver = resolve_solver(self.solver, n, dim, m_matrix=precon == "exp")
        if solver == "amg":
            return "AMG: pyamg's setup and coarse solve call BLAS"
        if solver == "direct" and not available("cholespy"):
            return "SciPy's SuperLU (cholespy missing) calls BLAS"
        return ""

    @property
    def label(self) -> str:
        """Machine label ``method`` or ``method+precon``, e.g. ``lbfgs+exp`` (``--json``), with
        ``/jax`` on the JAX engine."""
        base, precon = resolve_method(self.method, self.precon)
        label = base if precon == "none" else f"{base}+{precon}"
        return f"{label}/jax" if self.backend == "jax" else label

    @property
    def name(self) -> str:
        """Display name as in the paper: ``L-BFGS``, ``P-L-BFGS``, ``P-FR-CG``, ``contact
        P-L-BFGS``, ``FIRE``; a non-zero ``A`` or a chosen solver is added in brackets."""
        base, precon = resolve_method(self.method, self.precon)
        name = _NAMES[base]
        if precon == "exp":
            name = f"P-{name}"
        elif precon == "contact":
            name = f"contact P-{name}"
        extras = [f"A={self.A:g}"] if precon == "exp" and self.A != 0.0 else []
        if precon != "none" and self.solver != "auto" and self.backend == "numba":
            extras.append(self.solver)
        if self.backend == "jax":
            extras.append("jax")
        return f"{name} ({', '.join(extras)})" if extras else name


@dataclass(frozen=True, eq=False)
class Relaxation(MinimizeResult):
    """A :class:`~athermal.minimize.MinimizeResult` of a packing's energy: ``x`` in the
    objective's internal order, ``packing`` the final configuration in the caller's order,
    ``neighbor_rebuilds`` the Verlet list's builds during the run."""

    packing: Packing = field(kw_only=True)
    neighbor_rebuilds: int = field(default=0, kw_only=True)

    @classmethod
    def of(cls, result: MinimizeResult, objective: Objective, rebuilds: int) -> Relaxation:
        """``result`` of minimizing ``objective``, with its packing and ``rebuilds``."""
        fields = {k: getattr(result, k) for k in MinimizeResult.__dataclass_fields__}
        return cls(**fields, packing=objective.packing(result.x), neighbor_rebuilds=rebuilds)


def minimize_objective(
    objective: Objective,
    method: Method = "lbfgs",
    *,
    x0: NDArray[np.float64] | None = None,
    precon: PreconName | Preconditioner = "none",
    A: float = 0.0,
    solver: SolverName = "auto",
    gtol: float | None = None,
    rtol: float | None = None,
    maxiter: int = 100_000,
    etol: float = 0.0,
    memory: int = 10,
    cg_variant: Literal["fr", "pr+"] = "fr",
) -> Relaxation:
    """Relax ``objective`` from ``x0`` to ``max_i |grad_i| <= gtol``.

    Parameters
    ----------
    method : ``lbfgs``, ``cg``, ``fire``, ``newton``, or the paper's ``plbfgs`` / ``pcg``
        (``newton`` takes no ``precon``: its inner CG uses its own factored Hessian).
    x0 : the start ``(N d,)`` in the objective's internal order; default ``objective.x0``.
    precon : preconditioner name, or a ready :class:`~athermal.minimize.Preconditioner`
        (reused across calls, e.g. by the quasi-static protocols).
    A, solver : parameter of the Exp weights and the linear solver (``direct`` Cholesky,
        ``amg``, incomplete Cholesky ``ic0``, or ``auto`` by size), used when ``precon`` is a
        name.
    gtol, rtol : absolute tolerance on ``max_i |grad_i|``, or relative to the mean contact
        force at the start (give exactly one).
    maxiter : iteration limit (non-convergence is reported in the result).
    etol : the run also stops, converged, once the energy is ``<= etol`` (absolute, energy
        units; default 0: only an exactly zero energy). The jamming protocol uses it to end the
        relaxation of an unjammed packing.
    memory : L-BFGS memory ``m``.
    cg_variant : ``fr`` (Fletcher-Reeves) or ``pr+`` (Polak-Ribiere+).

    The result's ``status`` (:class:`~athermal.minimize.Status`) says why the run stopped.
    """
    start = objective.x0 if x0 is None else np.asarray(x0, dtype=np.float64)
    if start.shape != (objective.n_dof,):
        raise InputError(f"x0: expected shape ({objective.n_dof},), got {start.shape}")
    base, name = resolve_method(method, precon if isinstance(precon, str) else "none")
    if base == "newton" and not isinstance(precon, str):
        raise InputError(NEWTON_TAKES_NO_PRECON)
    tol = objective.tolerance(gtol, rtol, start)
    if not 0.0 <= etol < np.inf:
        raise InputError(f"etol: energy tolerance must be finite and >= 0, got {etol}")
    pre = None
    if base != "newton":
        pre = (
            make_preconditioner(name, objective, A=A, solver=solver)
            if isinstance(precon, str)
            else precon
        )
    options: dict[str, Any] = {}
    if base == "fire" and pre is None:
        options["curvature"] = objective.curvature_bound(start)
    rebuilds = objective.n_rebuilds
    result = library.minimize(
        objective,
        start,
        method=cast(library.Method, base),
        precon=pre,
        gtol=tol,
        maxiter=maxiter,
        etol=etol,
        memory=memory,
        cg_variant=cg_variant,
        options=options,
    )
    return Relaxation.of(result, objective, objective.n_rebuilds - rebuilds)


def relax_objective(
    objective: Objective,
    how: Minimizer,
    *,
    gtol: float | None = None,
    rtol: float | None = None,
    maxiter: int | None = None,
    x0: NDArray[np.float64] | None = None,
) -> Relaxation:
    """:func:`minimize_objective` from ``x0`` with the method, preconditioner, ``A``, solver
    and (unless given) ``maxiter`` of ``how``, on its engine (``how.backend``)."""
    if how.backend == "jax":
        start = objective.x0 if x0 is None else np.asarray(x0, dtype=np.float64)
        tol = objective.tolerance(gtol, rtol, start)
        limit = how.maxiter if maxiter is None else maxiter
        return _on_device(objective, engine_for(objective, how), how.method, start, tol, 0.0, limit)
    return minimize_objective(
        objective,
        how.method,
        x0=x0,
        precon=how.precon,
        A=how.A,
        solver=how.solver,
        gtol=gtol,
        rtol=rtol,
        maxiter=how.maxiter if maxiter is None else maxiter,
    )


def relax(
    packing: Packing,
    model: ContactModel,
    how: Minimizer | None = None,
    *,
    gtol: float | None = None,
    rtol: float | None = None,
    maxiter: int | None = None,
) -> Relaxation:
    """Relax ``packing`` (radii and cell fixed) under ``model`` by ``how`` (default L-BFGS) to
    ``max_i |grad_i| <= gtol``, or ``rtol`` x the mean contact force at the start (default
    :data:`RTOL` when neither is given), within ``maxiter`` iterations (default the
    minimizer's), with the protocols' hand-over (:class:`Relaxer`: Newton-CG to P-L-BFGS after
    :data:`NEWTON_PATIENCE` iterations, a failed line search to FIRE). Returns the
    :class:`Relaxation` (its ``packing`` in the caller's order, ``status`` why it stopped).

    Examples
    --------
    >>> from athermal import ContactModel, random_packing
    >>> from athermal.relaxation import Minimizer, relax
    >>> result = relax(random_packing(64, 0.88, seed=1), ContactModel(2.0), Minimizer("fire"))
    >>> result.converged, result.packing.n
    (True, 64)
    """
    objective = Objective(packing, model)
    tol = objective.tolerance(gtol, RTOL if gtol is None and rtol is None else rtol)
    relaxer = Relaxer(objective, how or Minimizer())
    return relaxer.attempt(objective.x0, gtol=tol, maxiter=maxiter)


MAX_ESCAPES = 3
"""How often :meth:`Relaxer.relax_to_minimum` leaves a saddle along its negative mode before it
gives up."""
NEWTON_PATIENCE = 300
"""Newton-CG iterations after which :meth:`Relaxer.relax` goes on with P-L-BFGS (Exp). Near
jamming a quasi-static step that rearranges can send Newton crawling (CG meeting negative
curvature, the line search cutting its steps to a few per cent) for thousands of iterations,
where P-L-BFGS takes many more but much cheaper ones; ordinary steps take 1-150
(:mod:`athermal.minimize.newton`). Measurements: ``docs/decisions.md``, section "Relaxing a
protocol step", ``NEWTON_PATIENCE``."""
ROUND_OFF_MARGIN = 10.0
""":func:`round_off_floor` is this many times the round-off estimate ``eps (L kappa + f)``."""


class Relaxer:
    """An :class:`Objective` with its preconditioner, for the relaxation of one protocol step.

    Each step builds its own (from the step's start configuration), so that a step depends on
    that configuration alone and an interrupted protocol resumes bit for bit; within the step
    the preconditioner rebuilds by its own rule and the Verlet list by the skin (a build costs
    little against the relaxation: ``docs/decisions.md``, section "Relaxing a protocol step").
    When L-BFGS or CG
    stops because no Wolfe step exists (it happens within a few times ``gtol`` of a minimum
    near jamming, where the energy differences of a step are at round-off), FIRE, which needs
    no line search, finishes the relaxation from there; a Newton-CG relaxation that has not
    converged in :data:`NEWTON_PATIENCE` iterations goes on with P-L-BFGS (Exp). The result
    counts every part.
    """

    def __init__(self, objective: Objective, minimizer: Minimizer) -> None:
        self.objective = objective
        self.minimizer = minimizer
        self.method, name = resolve_method(minimizer.method, minimizer.precon)
        self.engine = engine_for(objective, minimizer) if minimizer.backend == "jax" else None
        self.precon = (
            make_preconditioner(name, objective, A=minimizer.A, solver=minimizer.solver)
            if self.engine is None
            else None
        )

    def relax(
        self,
        x: NDArray[np.float64],
        *,
        gtol: float,
        etol: float = 0.0,
        what: str = "step",
        maxiter: int | None = None,
    ) -> Relaxation:
        """:meth:`attempt`; raises :class:`ConvergenceError` naming ``what`` when it did not
        converge."""
        result = self.attempt(x, gtol=gtol, etol=etol, maxiter=maxiter)
        if not result.converged:
            raise ConvergenceError(
                f"{what}: {self.minimizer.label} did not converge ({result.message}; "
                f"max|grad| {result.max_gradient:.3e} > gtol {gtol:.3e}); raise maxiter or "
                "try another method"
            )
        return result

    def attempt(
        self,
        x: NDArray[np.float64],
        *,
        gtol: float,
        etol: float = 0.0,
        maxiter: int | None = None,
    ) -> Relaxation:
        """Minimize from ``x`` ``(N d,)`` (internal order) to ``max_i |grad_i| <= gtol`` or
        energy ``<= etol`` within ``maxiter`` iterations (default the minimizer's), handing
        over as the class says; the result says whether it converged."""
        maxiter = self.minimizer.maxiter if maxiter is None else maxiter
        patience = NEWTON_PATIENCE if self.method == "newton" else maxiter
        result = self._minimize(self.method, x, self.precon, gtol, etol, min(patience, maxiter))
        if result.status is Status.ITERATION_LIMIT and patience < maxiter:
            exp = make_preconditioner("exp", self.objective, solver=self.minimizer.solver)
            result = self._go_on(result, "lbfgs", "P-L-BFGS", exp, gtol, etol, maxiter)
        if result.status is Status.LINE_SEARCH_FAILED:
            result = self._go_on(result, "fire", "FIRE", self.precon, gtol, etol, maxiter)
        return result

    def relax_to_minimum(
        self, x: NDArray[np.float64], *, gtol: float, etol: float = 0.0, what: str = "step"
    ) -> tuple[Relaxation, int]:
        """:meth:`relax`, then check that the result is a local minimum
        (:func:`~athermal.moduli.stability`); a saddle is left along its negative mode and
        relaxed again. Returns the last result and how many saddles were left; raises
        :class:`ConvergenceError` after :data:`MAX_ESCAPES` saddles in a row.

        The move along the mode is a line search downhill (:meth:`_leave_saddle`), so that the
        minimizer starts well away from the saddle (or from the remnant of a minimum that
        vanished, where the gradient is small but no minimum is near), and the relaxation after
        it goes to 1e-3 ``gtol`` or the round-off floor.
        """
        result = self.relax(x, gtol=gtol, etol=etol, what=what)
        for escapes in range(MAX_ESCAPES + 1):
            check = stability(result.packing, self.objective.model, self.objective.frozen)
            if check.stable:
                return result, escapes
            if escapes == MAX_ESCAPES:
                break
            assert check.mode is not None
            mode = np.ascontiguousarray(check.mode[self.objective.order]).ravel()
            x = self._leave_saddle(result.x, mode)
            # to round-off: along the channel left by a vanished minimum the gradient is small,
            # and the minimizer would stop there again at the step's tolerance
            floor = force_tolerance(
                self.objective.packing(x, internal=True), self.objective.model, 0.0
            )
            again = self.relax(
                x, gtol=max(floor, 1e-3 * gtol), etol=etol, what=f"{what} (after a saddle)"
            )
            result = _summed(result, again)
        raise ConvergenceError(
            f"{what}: still a saddle after leaving {MAX_ESCAPES} saddles along their negative "
            f"modes (lowest Hessian eigenvalue {check.lowest_eigenvalue:.3e})"
        )

    def relax_balanced(
        self,
        x: NDArray[np.float64],
        *,
        gtol: float,
        rtol: float,
        etol: float = 0.0,
        what: str = "step",
    ) -> Relaxation:
        """:meth:`relax` to ``gtol``, then on until ``max_i |grad_i|`` is also within
        :func:`force_tolerance` (``rtol``) of the result's own forces, or the energy is
        ``<= etol``, all within the minimizer's ``maxiter``: a relaxation stopped relative to
        its start's forces, whose forces fell on the way, is not balanced yet. Raises
        :class:`ConvergenceError` naming ``what`` when the iterations run out."""
        result = self.relax(x, gtol=gtol, etol=etol, what=what)
        model, limit = self.objective.model, self.minimizer.maxiter
        while result.energy > etol:
            own = force_tolerance(result.packing, model, rtol)
            if result.max_gradient <= own:
                break
            if result.iterations >= limit:
                raise ConvergenceError(
                    f"{what}: {self.minimizer.label} used its {limit} iterations before the "
                    "forces balanced to their own mean"
                )
            more = self.relax(
                result.x, gtol=own, etol=etol, what=what, maxiter=limit - result.iterations
            )
            result = _summed(result, more)
        return result

    def _leave_saddle(
        self, x: NDArray[np.float64], mode: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """``x`` moved downhill along ``mode`` (unit norm, internal order): from a move of the
        mean contact overlap (largest particle), in the direction of lower energy, doubled while
        the energy falls, at most a tenth of the mean radius (see :meth:`relax_to_minimum`)."""
        dim = self.objective.dim
        overlaps = find_contacts(self.objective.packing(x, internal=True), self.objective.model)
        largest = float(np.sqrt((mode.reshape(-1, dim) ** 2).sum(axis=1)).max())
        step = (float(overlaps.overlap.mean()) if overlaps.i.size else 1e-8) / largest
        cap = 0.1 * float(self.objective.radii.mean()) / largest
        plus, minus = self.objective(x + step * mode)[0], self.objective(x - step * mode)[0]
        direction = mode if plus <= minus else -mode
        best, best_energy = x + step * direction, min(plus, minus)
        while 2.0 * step <= cap:
            step *= 2.0
            trial = self.objective(x + step * direction)[0]
            if trial >= best_energy:
                break
            best, best_energy = x + step * direction, trial
        return best

    def _go_on(
        self,
        first: Relaxation,
        method: Literal["lbfgs", "fire"],
        label: str,
        precon: Preconditioner | None,
        gtol: float,
        etol: float,
        maxiter: int,
    ) -> Relaxation:
        """Relax on from where ``first`` stopped by ``method`` (called ``label`` in the message)
        with ``precon``, within what is left of ``maxiter``; the result counts both."""
        rest = self._minimize(
            method, first.x, precon, gtol, etol, max(1, maxiter - first.iterations)
        )
        return replace(
            rest,
            message=f"{rest.message} ({label} after: {first.message})",
            method=f"{first.method}+{method}",
            iterations=first.iterations + rest.iterations,
            evaluations=first.evaluations + rest.evaluations,
            seconds=first.seconds + rest.seconds,
            history_energy=np.concatenate([first.history_energy, rest.history_energy[1:]]),
            history_max_gradient=np.concatenate(
                [first.history_max_gradient, rest.history_max_gradient[1:]]
            ),
            neighbor_rebuilds=first.neighbor_rebuilds + rest.neighbor_rebuilds,
            # a preconditioner counts its builds over its life: add the first run's only when
            # it had another one (Newton's own factor, before the Exp of the hand-over)
            precon_builds=rest.precon_builds
            + (first.precon_builds if precon is not self.precon else 0),
            linear_iterations=first.linear_iterations + rest.linear_iterations,
        )

    def _minimize(
        self,
        method: str,
        x: NDArray[np.float64],
        precon: Preconditioner | None,
        gtol: float,
        etol: float,
        maxiter: int,
    ) -> Relaxation:
        """One minimization by ``method`` from ``x`` on this relaxer's engine (``precon`` is
        the CPU engine's; the JAX engine holds its own)."""
        if self.engine is not None:
            return _on_device(self.objective, self.engine, method, x, gtol, etol, maxiter)
        return minimize_objective(
            self.objective,
            cast(Method, method),
            x0=x,
            precon=precon if precon is not None else "none",
            gtol=gtol,
            etol=etol,
            maxiter=maxiter,
        )


def engine_for(objective: Objective, how: Minimizer) -> Any:
    """The JAX engine (:class:`athermal.jaxengine.Engine`) for ``objective`` with the
    preconditioner of ``how``; imported here, when asked for, since JAX is an extra."""
    from . import jaxengine

    if objective.frozen is not None:
        raise InputError(FROZEN_NOT_ON_JAX)
    _, precon = resolve_method(how.method, how.precon)
    return jaxengine.Engine(objective, cast(Literal["none", "exp"], precon), A=how.A)


def _on_device(
    objective: Objective,
    engine: Any,
    method: str,
    x: NDArray[np.float64],
    gtol: float,
    etol: float,
    maxiter: int,
) -> Relaxation:
    """:meth:`athermal.jaxengine.Engine.minimize` by the base ``method`` (``plbfgs`` is
    ``lbfgs`` on an engine with the Exp preconditioner) as a :class:`Relaxation`."""
    base, _ = resolve_method(method)
    rebuilds = engine.n_rebuilds
    result = engine.minimize(base, x, gtol=gtol, etol=etol, maxiter=maxiter)
    return Relaxation.of(result, objective, engine.n_rebuilds - rebuilds)


def _summed(first: Relaxation, then: Relaxation) -> Relaxation:
    """``then``, a relaxation that went on from where ``first`` stopped, counting both runs'
    iterations, evaluations and seconds."""
    return replace(
        then,
        iterations=first.iterations + then.iterations,
        evaluations=first.evaluations + then.evaluations,
        seconds=first.seconds + then.seconds,
    )


def round_off_floor(contacts: Contacts, cell: Cell) -> float:
    """Smallest ``max_i |grad_i|`` a protocol asks for (force units):
    ``ROUND_OFF_MARGIN x eps_mach (L kappa_max + f_max)``.

    An overlap carries an absolute error ``~eps_mach L`` from the coordinates (``L`` the largest
    cell width), which the contact stiffness ``kappa = k (alpha-1) delta^(alpha-2)`` turns into
    a force error, on top of the relative rounding of the force ``f = k delta^(alpha-1)``
    itself. Measured (N = 256, from the jamming point to Delta phi = 1e-2, alpha = 2 and 2.5):
    L-BFGS and FIRE stall at 0.25-0.6 x ``eps (L kappa_max + f_max)``. For Hertzian contacts
    near jamming this is far below a floor in units of ``k <r>^(alpha-1)``: the stiffness
    vanishes with the overlap.
    """
    if contacts.i.size == 0:
        return 0.0
    kappa = contacts.normal_stiffness
    scale = float(cell.widths.max())
    eps = float(np.finfo(np.float64).eps)
    return (
        ROUND_OFF_MARGIN
        * eps
        * (scale * float(kappa.max()) + float(contacts.force_magnitude.max()))
    )


def force_tolerance(packing: Packing, model: ContactModel, rtol: float) -> float:
    """``max(rtol x mean contact force, round_off_floor)`` at ``packing`` (force units): the
    tolerance of a protocol step relative to its own forces."""
    contacts = find_contacts(packing, model)
    mean = float(contacts.force_magnitude.mean()) if contacts.i.size else 0.0
    return max(rtol * mean, round_off_floor(contacts, packing.cell))


def energy_scale(radii: NDArray[np.float64], model: ContactModel) -> float:
    """``k_max <r>^alpha``: the energy of an overlap of one mean radius (energy units)."""
    return float(model.kmat.max()) * float(power(np.mean(radii), model.alpha))


def minimize(
    fun: Callable[[NDArray[np.float64]], tuple[float, NDArray[np.float64]]] | Objective,
    *args: Any,
    **kwargs: Any,
) -> MinimizeResult:
    """``athermal.minimize``: :func:`athermal.minimize.minimize` (``fun(x) -> (f, grad)``,
    ``x0``); the old call on an :class:`~athermal.objective.Objective`, ``minimize(objective,
    method, ...)``, still works for one release, with a DeprecationWarning: it is
    :func:`minimize_objective` (or :func:`relax` on a packing)."""
    if isinstance(fun, Objective):
        warnings.warn(
            "athermal.minimize(objective, method, ...) is deprecated: use "
            "athermal.relax(packing, model, Minimizer(...)) or "
            "athermal.relaxation.minimize_objective(objective, method, ...)",
            DeprecationWarning,
            stacklevel=2,
        )
        return minimize_objective(fun, *args, **kwargs)
    return library.minimize(fun, *args, **kwargs)
