"""Relaxing a packing: how (:class:`Minimizer`, the paper's method names and the force tolerance
:data:`RTOL`) and doing it (:func:`relax`), on the minimizers of :mod:`athermal.minimize`.

The physics above the minimizer library: the tolerance relative to the mean contact force
(``rtol``), the preconditioners by name (:mod:`athermal.engines.precon`), the hooks of an
:class:`~athermal.model.objective.Objective` (particles of ``d`` coordinates, the step cap, the
round-off of the contact energy, its compiled line search, FIRE's curvature bound) and the
packing at the result (:class:`Relaxation`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from . import engines
from ._validate import choice
from .analysis.moduli import stability
from .engines.numba import run
from .engines.precon import PRECONDITIONERS, PreconName, make_preconditioner
from .errors import ConvergenceError, InputError
from .linalg import SOLVERS, SolverName
from .minimize import NEWTON_TAKES_NO_PRECON, MinimizeResult, Preconditioner, Status
from .model.cell import Cell
from .model.contact import ContactModel, Contacts, find_contacts
from .model.objective import Objective
from .model.packing import Packing

Method = Literal["lbfgs", "cg", "fire", "newton", "plbfgs", "pcg"]
METHODS: tuple[str, ...] = ("lbfgs", "cg", "fire", "newton", "plbfgs", "pcg")
_ALIASES: dict[str, tuple[str, PreconName]] = {"plbfgs": ("lbfgs", "exp"), "pcg": ("cg", "exp")}
_NAMES = {"lbfgs": "L-BFGS", "cg": "FR-CG", "fire": "FIRE", "newton": "Newton-CG"}
RTOL = 1e-9
"""The paper's tolerance: ``max_i |grad_i| <= RTOL`` x the mean contact force at the start of a
relaxation (the Table, every quasi-static step)."""
MAXITER = 1_000_000
"""Iteration limit of one relaxation unless the caller gives another (every door)."""


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
    maxiter : iteration limit of one relaxation (default :data:`MAXITER`); a protocol that
        reaches it stops with a :class:`~athermal.errors.ConvergenceError`.
    backend : the engine's name (:mod:`athermal.engines`): ``numba`` (CPU, every method) or
        ``jax`` (the extra ``athermal[jax]``), or one registered by the user; what the engine
        cannot do is refused here, by its capabilities.
    """

    method: Method = "lbfgs"
    precon: PreconName = "none"
    A: float = 0.0
    solver: SolverName = "auto"
    maxiter: int = MAXITER
    backend: str = engines.DEFAULT

    def __post_init__(self) -> None:
        choice(self.solver, "solver", SOLVERS)
        base, precon = self.base, self.preconditioner
        if int(self.maxiter) != self.maxiter or self.maxiter < 1:
            raise InputError(f"maxiter: must be an integer >= 1, got {self.maxiter!r}")
        if not self.A >= 0.0:
            raise InputError(f"A: must be >= 0, got {self.A!r}")
        if self.A != 0.0 and precon != "exp":
            raise InputError(f"A: the Exp preconditioner's parameter, and the precon is {precon}")
        if self.solver != "auto" and precon == "none":
            raise InputError("solver: the preconditioner's linear solver, and the precon is none")
        engines.check(self.backend, base, precon, self.solver)

    @cached_property
    def _resolved(self) -> tuple[str, PreconName]:
        """:func:`resolve_method` of ``method`` and ``precon``, once."""
        return resolve_method(self.method, self.precon)

    @property
    def base(self) -> str:
        """The base method: ``lbfgs``, ``cg``, ``fire`` or ``newton``."""
        return self._resolved[0]

    @property
    def preconditioner(self) -> PreconName:
        """The preconditioner's name, with the one ``plbfgs`` and ``pcg`` imply."""
        return self._resolved[1]

    @property
    def engine(self) -> engines.Engine:
        """The engine named ``backend``."""
        return engines.engine(self.backend)

    def machine_dependence(self, n: int, dim: int) -> str:
        """Empty when this minimizer's relaxations of ``n`` particles in ``dim`` dimensions are
        the same bits on every CPU, else what makes them this machine's: a solver that sums in
        its BLAS's order, or another engine (``docs/decisions.md``, "Same input, same bits")."""
        return self.engine.machine_dependence(self.preconditioner, self.solver, n, dim)

    @property
    def label(self) -> str:
        """Machine label ``method`` or ``method+precon``, e.g. ``lbfgs+exp`` (``--json``), with
        ``/engine`` on another engine than the default (``lbfgs+exp/jax``)."""
        base, precon = self._resolved
        label = base if precon == "none" else f"{base}+{precon}"
        return label if self.backend == engines.DEFAULT else f"{label}/{self.backend}"

    @property
    def name(self) -> str:
        """Display name as in the paper: ``L-BFGS``, ``P-L-BFGS``, ``P-FR-CG``, ``contact
        P-L-BFGS``, ``FIRE``; a non-zero ``A`` or a chosen solver is added in brackets."""
        base, precon = self._resolved
        name = _NAMES[base]
        if precon == "exp":
            name = f"P-{name}"
        elif precon == "contact":
            name = f"contact P-{name}"
        extras = [f"A={self.A:g}"] if precon == "exp" and self.A != 0.0 else []
        if precon != "none" and self.solver != "auto":
            extras.append(self.solver)
        if self.backend != engines.DEFAULT:
            extras.append(self.backend)
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
    maxiter: int = MAXITER,
    etol: float = 0.0,
    memory: int = 10,
    cg_variant: Literal["fr", "pr+"] = "fr",
) -> Relaxation:
    """Relax ``objective`` from ``x0`` to ``max_i |grad_i| <= gtol`` on the numba engine,
    without the hand-overs of :class:`Relaxer`.

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
    rebuilds = objective.n_rebuilds
    result = run(
        objective,
        base,
        start,
        pre,
        gtol=tol,
        etol=etol,
        maxiter=maxiter,
        memory=memory,
        cg_variant=cg_variant,
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
    """One minimization of ``objective`` from ``x0`` (default ``objective.x0``) by ``how`` on
    its engine, to ``gtol`` or ``rtol`` as in :func:`minimize_objective`, within ``maxiter``
    iterations (default the minimizer's), without the hand-overs of :class:`Relaxer`."""
    start = objective.x0 if x0 is None else np.asarray(x0, dtype=np.float64)
    tol = objective.tolerance(gtol, rtol, start)
    relaxer = Relaxer(objective, how)
    limit = how.maxiter if maxiter is None else maxiter
    return relaxer._minimize(relaxer.method, start, None, tol, 0.0, limit)


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


def relax_once(
    packing: Packing,
    model: ContactModel,
    how: Minimizer | None = None,
    *,
    gtol: float | None = None,
    rtol: float | None = None,
) -> Relaxation:
    """One minimization of ``packing`` by ``how`` alone (default L-BFGS; no hand-over: what it
    reaches is the method's own) to ``max_i |grad_i| <= gtol``, or ``rtol`` x the start's mean
    contact force floored at round-off (:func:`force_tolerance`; default :data:`RTOL` when
    neither is given): a packing at its jamming point, whose forces lie below what float64
    resolves at its overlaps, is then already relaxed. Raises :class:`InputError` for two
    coincident particles before any work."""
    how = how or Minimizer()
    if gtol is not None and rtol is not None:
        raise InputError("give at most one of gtol (absolute) and rtol (x mean contact force)")
    floored = force_tolerance(packing, model, RTOL if rtol is None else rtol)
    return relax_objective(Objective(packing, model), how, gtol=floored if gtol is None else gtol)


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
    converged in :data:`NEWTON_PATIENCE` iterations goes on with P-L-BFGS (Exp); each on an
    engine that runs it (its capabilities). The result counts every part.
    """

    def __init__(self, objective: Objective, minimizer: Minimizer) -> None:
        self.objective = objective
        self.minimizer = minimizer
        self.method = minimizer.base
        engine = engines.check(
            minimizer.backend,
            walls=bool(objective.cell.walls),
            frozen=objective.frozen is not None,
        )
        self.session = engine.bind(
            objective, minimizer.preconditioner, A=minimizer.A, solver=minimizer.solver
        )
        caps = engine.capabilities
        self.to_fire = "fire" in caps.methods
        """Whether a failed line search goes on with FIRE (the engine runs it)."""
        self.to_plbfgs = "lbfgs" in caps.methods and "exp" in caps.preconditioners
        """Whether a crawling Newton-CG goes on with P-L-BFGS (the engine runs it)."""

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
        patience = NEWTON_PATIENCE if self.method == "newton" and self.to_plbfgs else maxiter
        result = self._minimize(self.method, x, None, gtol, etol, min(patience, maxiter))
        if result.status is Status.ITERATION_LIMIT and patience < maxiter:
            result = self._go_on(result, "lbfgs", "P-L-BFGS", "exp", gtol, etol, maxiter)
        if result.status is Status.LINE_SEARCH_FAILED and self.to_fire:
            result = self._go_on(result, "fire", "FIRE", None, gtol, etol, maxiter)
        return result

    def relax_to_minimum(
        self, x: NDArray[np.float64], *, gtol: float, etol: float = 0.0, what: str = "step"
    ) -> tuple[Relaxation, int]:
        """:meth:`relax`, then check that the result is a local minimum
        (:func:`~athermal.analysis.moduli.stability`); a saddle is left along its negative mode and
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
        precon: str | None,
        gtol: float,
        etol: float,
        maxiter: int,
    ) -> Relaxation:
        """Relax on from where ``first`` stopped by ``method`` (called ``label`` in the message)
        with the preconditioner named ``precon`` (None: the relaxer's own), within what is left
        of ``maxiter``; the result counts both."""
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
            precon_builds=rest.precon_builds + (first.precon_builds if precon is not None else 0),
            linear_iterations=first.linear_iterations + rest.linear_iterations,
        )

    def _minimize(
        self,
        method: str,
        x: NDArray[np.float64],
        precon: str | None,
        gtol: float,
        etol: float,
        maxiter: int,
    ) -> Relaxation:
        """One minimization by the base ``method`` from ``x`` on this relaxer's engine, with
        its own preconditioner (``precon`` None) or a fresh one named ``precon``."""
        rebuilds = self.session.n_rebuilds
        result = self.session.minimize(
            method, x, gtol=gtol, etol=etol, maxiter=maxiter, precon=precon
        )
        return Relaxation.of(result, self.objective, self.session.n_rebuilds - rebuilds)


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
    cell width), which the contact stiffness ``kappa = E''(delta)`` turns into a force error, on
    top of the relative rounding of the force ``f(delta)`` itself (where L-BFGS and FIRE stall
    against it: ``docs/decisions.md``, section "Protocol constants"). For Hertzian contacts
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
    """The law's energy unit at ``k_max`` and an overlap of one mean radius (``k_max
    <r>^alpha`` for a power law; energy units)."""
    return model.law.energy_unit(float(model.kmat.max()), float(np.mean(radii)))
