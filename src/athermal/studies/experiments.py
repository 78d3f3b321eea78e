"""The studies built from the protocols, written once: jam -> compress -> fits, shear at a
chosen ``Delta phi``, the paper's iteration experiment and its convergence figure.

``athermal paper``, ``athermal ensemble`` and the scripts in ``benchmarks/`` call these. Specs
are frozen dataclasses (their fields are a run's identity); results are frozen dataclasses.

Seeding, one rule everywhere: the seed of a packing is the integer :func:`random_packing`
takes (``athermal jam --seed s`` uses ``s``); a study with root seed ``S`` gives realization
``k`` the seed :func:`child_seeds` ``(S, ...)[k]``, from the ``k``-th child of
``numpy.random.SeedSequence(S)``, so any realization is rerun alone by its recorded seed.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .._validate import choice
from ..errors import InputError
from ..model.cell import Cell
from ..model.contact import ContactModel
from ..model.objective import Objective
from ..model.packing import POLYDISPERSITY, Packing, SizeDistribution, check_width, random_packing
from ..protocols import (
    DPHI,
    EPSILON,
    JAM_PROTOCOL,
    JAMMING_MINIMIZER,
    CompressionStep,
    JammingResult,
    JammingStep,
    JamProtocol,
    ScalingExponents,
    ShearMode,
    ShearStep,
    compression_steps,
    finite_strain_shear,
    jam,
    log_spaced,
    scaling_exponents,
    shear_steps,
    start_fraction,
)
from ..protocols.compress import FIT_LOWER
from ..protocols.finite_strain import DEFAULT_STRAINS, StepStart
from ..protocols.jamming import JAM_PROTOCOLS, check_epsilon
from ..relaxation import RTOL, Minimizer, relax_objective

ITERATION_METHODS = (
    Minimizer("lbfgs"),
    Minimizer("lbfgs", "exp"),
    Minimizer("lbfgs", "contact"),
    Minimizer("fire"),
    Minimizer("newton"),
)
"""The minimizers of the paper's iteration experiment (plus the contact-stiffness one, FIRE and
the truncated Newton method)."""
CONVERGENCE_METHODS = (
    Minimizer("lbfgs"),
    Minimizer("lbfgs", "exp"),
    Minimizer("cg"),
    Minimizer("cg", "exp"),
    Minimizer("fire"),
    Minimizer("lbfgs", "contact"),
)
"""The minimizers of the paper's convergence figure (plus FIRE and the contact one)."""


def child_seeds(root: int, count: int) -> list[int]:
    """The seeds of realizations ``0 .. count-1`` of a study with root seed ``root``: one
    63-bit integer from each child of ``SeedSequence(root)`` (independent streams, the same
    whatever runs them and in whatever order)."""
    if int(count) != count or count < 0:
        raise InputError(f"realizations: must be an integer >= 0, got {count!r}")
    children = np.random.SeedSequence(root).spawn(int(count))
    return [int(c.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1)) for c in children]


@dataclass(frozen=True)
class JamSpec:
    """A random packing and its jamming (:func:`~athermal.protocols.jam`).

    ``n`` particles in ``dim`` dimensions, bidisperse 1:1 with radius ratio ``size_ratio``
    (or radii from the continuous distribution ``sizes`` of width ``polydispersity``, see
    :func:`~athermal.model.packing.random_packing`), contact exponent ``alpha`` and stiffness
    ``stiffness``, placed at ``phi_init`` (default :func:`~athermal.protocols.start_fraction`),
    grown by ``dphi`` and bisected to ``epsilon`` (packing fraction) by the bisection
    ``protocol`` (``seed`` or ``ohern``), relaxed by ``minimizer``, in the unit cell with walls
    normal to the axes ``walls`` (``"y"``; default none, periodic).
    """

    n: int = 1024
    dim: int = 2
    alpha: float = 2.0
    stiffness: float = 1.0
    size_ratio: float = 1.4
    sizes: SizeDistribution = "bidisperse"
    polydispersity: float = POLYDISPERSITY
    phi_init: float | None = None
    dphi: float = DPHI
    epsilon: float = EPSILON
    protocol: JamProtocol = JAM_PROTOCOL
    minimizer: Minimizer = JAMMING_MINIMIZER
    walls: str = ""

    def __post_init__(self) -> None:
        if int(self.n) != self.n or self.n < 2:
            raise InputError(f"n: need an integer >= 2 particles, got {self.n!r}")
        if self.dim not in (2, 3):
            raise InputError(f"dim: must be 2 or 3, got {self.dim!r}")
        self.cell  # noqa: B018  # validates the walls
        if self.sizes != "bidisperse":
            check_width(self.sizes, self.polydispersity)
        choice(self.protocol, "protocol", JAM_PROTOCOLS)
        check_epsilon(self.epsilon)
        self.model  # noqa: B018  # validates alpha and stiffness

    @property
    def model(self) -> ContactModel:
        """The contact model."""
        return ContactModel(self.alpha, self.stiffness)

    def start(self, seed: int) -> Packing:
        """The random start packing of ``seed``."""
        phi = start_fraction(self.dim, bool(self.walls)) if self.phi_init is None else self.phi_init
        return random_packing(
            self.n,
            phi,
            dim=self.dim,
            seed=seed,
            size_ratio=self.size_ratio,
            sizes=self.sizes,
            polydispersity=self.polydispersity,
            cell=self.cell,
        )

    @property
    def cell(self) -> Cell:
        """The unit cell with the walls of :attr:`walls`."""
        return Cell.unit(self.dim, self.walls)


def jam_packing(
    spec: JamSpec,
    seed: int,
    *,
    resume: Sequence[JammingStep] = (),
    on_step: Callable[[JammingStep], None] | None = None,
) -> JammingResult:
    """Jam the start packing of ``seed`` as ``spec`` says; ``resume`` and ``on_step`` as in
    :func:`~athermal.protocols.jam` (a checkpointed run appends each step)."""
    return jam(
        spec.start(seed),
        spec.model,
        dphi=spec.dphi,
        epsilon=spec.epsilon,
        protocol=spec.protocol,
        minimizer=spec.minimizer,
        resume=resume,
        on_step=on_step,
    )


DELTA_PHI_RANGE = (1e-7, 1e-1)
"""The ``Delta phi`` above jamming the compressions and the iteration experiment span by
default: the paper's."""


@dataclass(frozen=True)
class CompressSpec:
    """Quasi-static compression above jamming: ``per_decade`` log-spaced ``Delta phi`` from
    ``delta_min`` to ``delta_max``, each relaxed to ``rtol`` x the mean contact force by
    ``minimizer``; the scaling laws are fitted over ``Delta phi >= fit_lower``."""

    delta_min: float = DELTA_PHI_RANGE[0]
    delta_max: float = DELTA_PHI_RANGE[1]
    per_decade: int = 4
    rtol: float = RTOL
    minimizer: Minimizer = field(default_factory=Minimizer)
    fit_lower: float = FIT_LOWER

    def delta_phis(self) -> NDArray[np.float64]:
        """The steps' ``Delta phi`` ``(M,)``."""
        return log_spaced(self.delta_min, self.delta_max, self.per_decade)


@dataclass(frozen=True, eq=False)
class Compression:
    """The relaxed states of a compression and the power laws fitted to them."""

    steps: tuple[CompressionStep, ...]
    fits: ScalingExponents

    def nearest(self, delta_phi: float) -> CompressionStep:
        """The state whose ``Delta phi`` is nearest ``delta_phi`` on a log scale."""
        return min(self.steps, key=lambda s: abs(np.log(s.delta_phi / delta_phi)))


def compress(
    jammed: Packing, model: ContactModel, phi_c: float | None, spec: CompressSpec
) -> Compression:
    """Compress ``jammed`` (at its jamming point ``phi_c``; None: its own ``phi``) as ``spec``
    says and fit ``p``, ``G`` and ``z - z_iso`` against ``Delta phi``."""
    steps = tuple(
        compression_steps(
            jammed,
            model,
            phi_c=phi_c,
            delta_phis=spec.delta_phis(),
            minimizer=spec.minimizer,
            rtol=spec.rtol,
        )
    )
    return Compression(steps, scaling_exponents(steps, lower=spec.fit_lower))


@dataclass(frozen=True)
class ShearSpec:
    """Quasi-static shear (``mode`` simple, pure, uniaxial or plane) to ``strain`` in increments
    ``step``, from the compressed state nearest ``delta_phi`` above jamming."""

    mode: ShearMode = "pure"
    strain: float = 0.02
    step: float = 1e-4
    delta_phi: float = 1e-2
    rtol: float = RTOL
    minimizer: Minimizer = field(default_factory=Minimizer)


@dataclass(frozen=True, eq=False)
class Shear:
    """The relaxed states of a shear run and the ``Delta phi`` of its start."""

    steps: tuple[ShearStep, ...]
    delta_phi: float

    @property
    def plastic_events(self) -> int:
        """Steps with a stress drop (:attr:`ShearStep.plastic`)."""
        return sum(int(s.plastic) for s in self.steps)


def shear(compression: Compression, model: ContactModel, spec: ShearSpec) -> Shear:
    """Shear the state of ``compression`` nearest ``spec.delta_phi`` as ``spec`` says."""
    start = compression.nearest(spec.delta_phi)
    steps = shear_steps(
        start.packing,
        model,
        mode=spec.mode,
        strain=spec.strain,
        step=spec.step,
        minimizer=spec.minimizer,
        rtol=spec.rtol,
    )
    return Shear(tuple(steps), start.delta_phi)


@dataclass(frozen=True)
class IterationSpec:
    """The paper's iteration experiment: at each ``delta_phis`` above jamming, the mean number
    of iterations of the quasi-static simple-shear steps ``strains`` by each of ``methods``,
    each relaxation starting from the affinely sheared state (``start``, the paper's; or
    ``"linear"``, see :func:`~athermal.protocols.finite_strain_shear`)."""

    delta_phis: tuple[float, ...] = tuple(float(d) for d in log_spaced(*DELTA_PHI_RANGE, 1))
    methods: tuple[Minimizer, ...] = ITERATION_METHODS
    strains: tuple[float, ...] = tuple(float(s) for s in DEFAULT_STRAINS)
    start: StepStart = "affine"


@dataclass(frozen=True)
class IterationCounts:
    """Per method name: mean iterations and mean seconds per shear step at each
    ``delta_phi`` (the states actually reached, nearest the spec's); NaN at a state the
    compression left unjammed (its ``"unjammed"`` event), which is not ``Delta phi`` above
    jamming and is not sheared."""

    delta_phi: tuple[float, ...]
    iterations: dict[str, tuple[float, ...]]
    seconds: dict[str, tuple[float, ...]]


def iteration_counts(
    jammed: Packing, model: ContactModel, phi_c: float | None, spec: IterationSpec
) -> IterationCounts:
    """Compress ``jammed`` to each ``Delta phi`` of ``spec`` and count, for each method, the
    iterations of the quasi-static shear steps there."""
    names = [m.name for m in spec.methods]
    iterations: dict[str, list[float]] = {name: [] for name in names}
    seconds: dict[str, list[float]] = {name: [] for name in names}
    reached = []
    for state in compression_steps(jammed, model, phi_c=phi_c, delta_phis=spec.delta_phis):
        reached.append(state.delta_phi)
        if "unjammed" in state.events:
            for name in names:
                iterations[name].append(float("nan"))
                seconds[name].append(float("nan"))
            continue
        for name, method in zip(names, spec.methods, strict=True):
            t0 = time.perf_counter()
            fs = finite_strain_shear(
                state.packing, model, spec.strains, minimizer=method, start=spec.start
            )
            iterations[name].append(float(np.mean(fs.iterations)))
            seconds[name].append((time.perf_counter() - t0) / len(spec.strains))
    return IterationCounts(
        tuple(reached),
        {k: tuple(v) for k, v in iterations.items()},
        {k: tuple(v) for k, v in seconds.items()},
    )


@dataclass(frozen=True)
class ConvergenceSpec:
    """The paper's convergence figure: one relaxation after growing the radii of a jammed
    packing by ``1 + growth``, to ``rtol`` x the mean contact force, by each of ``methods``."""

    growth: float = 5e-5
    rtol: float = RTOL
    methods: tuple[Minimizer, ...] = CONVERGENCE_METHODS


@dataclass(frozen=True, eq=False)
class Convergence:
    """``max_i |grad_i|`` per iteration ``(iterations + 1,)`` for each method name, from the
    grown packing ``start``; ``tolerance`` is the force every method ran to."""

    start: Packing
    histories: dict[str, NDArray[np.float64]]
    tolerance: float


def convergence(jammed: Packing, model: ContactModel, spec: ConvergenceSpec) -> Convergence:
    """Relax ``jammed`` grown by ``1 + spec.growth`` with each method of ``spec``."""
    grown = jammed.scale_radii(1.0 + spec.growth)
    histories = {}
    tolerance = float("nan")
    for method in spec.methods:
        result = relax_objective(Objective(grown, model), method, rtol=spec.rtol)
        histories[method.name] = result.history_max_gradient
        tolerance = result.gtol
    return Convergence(grown, histories, tolerance)
