"""Quasi-static shear: simple or pure shear, uniaxial compression or plane shear between rough
walls, in small steps, each relaxed (seed 4.3).

Each step maps positions and cell by the increment of the deformation (simple shear
``x += gamma y``, the paper's area-preserving pure shear ``D = diag(1 + gamma, 1/(1 + gamma))``,
stretching x and compressing y, or uniaxial compression ``D = diag(1, ..., 1 - gamma)`` of the
last axis: between walls normal to it, a wall moving in) and relaxes the packing. A step
reports the stress and fabric tensors with their isotropic and deviatoric parts (the paper's
eigenvalue definitions), the driven stress ``tau`` (the stress work-conjugate to the strain:
``-sigma_01`` for simple shear, ``(sigma_11 - sigma_00) / 2`` for pure shear, ``sigma_ee`` of
the compressed axis, positive when loaded) and whether ``tau`` dropped: a plastic event.

With walls (:attr:`Cell.walls <athermal.model.cell.Cell.walls>`) pure shear is the biaxial test
(walls normal to y move in as the periodic x stretches) and uniaxial compression moves the walls
normal to the last axis; simple shear tilts the cell, which frictionless flat walls cannot carry,
and is refused (:func:`check_mode`). Plane shear needs walls normal to one axis ``g`` other than
x: the particles within ``wall_layer`` of each wall are glued to it (rough walls,
:func:`~athermal.model.walls.wall_layers`; frozen in the relaxations,
:class:`~athermal.model.objective.
Objective`), and each step moves the upper wall and its layer along x by ``Delta gamma L_g``,
the free particles affinely (``x += Delta gamma (x_g + L_g / 2)``); the cell does not change.
``tau`` is then the shear force per unit area on the walls (:func:`plane_tractions`).

The cell changes at every step, so each relaxation starts from a fresh objective and
preconditioner: a step depends on its start configuration alone.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from .._records import Value, as_row
from .._validate import choice, positive_scalar
from ..analysis.observables import Observables, measure
from ..errors import InputError
from ..model.cell import AXES, Cell, pure_shear, simple_shear
from ..model.contact import ContactModel, find_contacts, gradient
from ..model.objective import Objective
from ..model.packing import Packing
from ..model.walls import wall_layers
from ..relaxation import RTOL, Minimizer, Relaxer, force_tolerance

ShearMode = Literal["simple", "pure", "uniaxial", "plane"]
SHEAR_MODES: tuple[str, ...] = ("simple", "pure", "uniaxial", "plane")
"""The modes: simple shear (``x += gamma y``), pure shear (volume-preserving
``D = diag(1 + gamma, 1 / (1 + gamma))``), uniaxial compression of the last axis
(``D = diag(1, ..., 1 - gamma)``) and plane shear (the upper rough wall moved along x by
``gamma L_g``); ``docs/quantities.md`` gives each one's ``tau``."""
DROP_TOL = 1e-6
"""A plastic event is a drop of ``tau`` by more than ``DROP_TOL`` x the pressure."""
ROW_OBSERVABLES: tuple[str, ...] = (
    "energy",
    "pressure",
    "stress_iso",
    "stress_dev",
    "fabric_iso",
    "fabric_dev",
    "contacts",
    "z",
    "n_rattlers",
)
"""The observables a shear step's row holds (:meth:`ShearStep.row`), in its column order."""


def deformation(mode: ShearMode, gamma: float, dim: int) -> NDArray[np.float64]:
    """The total deformation ``D(gamma)`` ``(d, d)`` of ``mode`` at strain ``gamma`` (plane
    shear deforms no cell: :func:`plane_shift`)."""
    _not_plane(mode)
    if mode == "simple":
        return simple_shear(gamma, dim)
    if mode == "pure":
        return pure_shear(gamma, dim)
    d_mat = np.eye(dim)
    d_mat[-1, -1] = 1.0 - gamma
    return d_mat


def driven_stress(mode: ShearMode, sigma: NDArray[np.float64]) -> float:
    """``tau``: ``-sigma_01`` (simple), ``(sigma_11 - sigma_00) / 2`` (pure shear) or
    ``sigma_ee`` of the last axis (uniaxial compression); plane shear's is the walls'
    (:func:`plane_tractions`)."""
    _not_plane(mode)
    if mode == "simple":
        return float(-sigma[0, 1])
    if mode == "pure":
        return 0.5 * float(sigma[1, 1] - sigma[0, 0])
    return float(sigma[-1, -1])


def _not_plane(mode: ShearMode) -> None:
    if mode == "plane":
        raise InputError("mode: plane shear moves rough walls, not the cell (plane_shift)")


def _check_plane(cell: Cell) -> None:
    if len(cell.walls) != 1 or cell.walls[0] == 0:
        named = ", ".join(AXES[a] for a in cell.walls) or "none"
        raise InputError(
            "mode: plane shear moves a wall along x, so it needs walls normal to one axis other "
            f"than x (y, or z in 3D) and x periodic; this cell's walls: {named}"
        )


def strain_steps(strain: float, step: float) -> int:
    """The number of increments ``step`` to the final ``strain`` (the last one may be shorter);
    :class:`InputError` for an increment beyond the strain."""
    strain = positive_scalar(strain, "strain")
    step = positive_scalar(step, "step")
    if step > strain:
        raise InputError(f"step: the increment {step:g} exceeds the final strain {strain:g}")
    return int(np.ceil(strain / step - 1e-9))


def check_mode(mode: ShearMode, strain: float, cell: Cell, wall_layer: float | None = None) -> None:
    """Refuse (:class:`InputError`) a ``mode`` the cell's walls cannot take (simple shear
    tilts x along y; plane shear needs walls normal to one axis other than x), a uniaxial
    ``strain`` that leaves no cell (>= 1) and a ``wall_layer`` with a mode other than plane
    shear."""
    choice(mode, "mode", SHEAR_MODES)
    if mode == "plane":
        _check_plane(cell)
    elif wall_layer is not None:
        raise InputError("wall_layer: only plane shear glues particles to walls")
    if mode == "simple" and {0, 1} & set(cell.walls):
        raise InputError(
            "mode: simple shear (x += gamma y) would tilt a cell with walls normal to "
            f"{'x' if 0 in cell.walls else 'y'}, and flat frictionless walls carry no shear "
            "stress; use pure shear, uniaxial compression, or plane shear between rough walls "
            "(mode plane)"
        )
    if mode == "uniaxial" and not strain < 1.0:
        raise InputError(f"strain: uniaxial compression needs a strain < 1, got {strain:g}")


def plane_tractions(
    packing: Packing, model: ContactModel, lower: NDArray[np.bool_], upper: NDArray[np.bool_]
) -> NDArray[np.float64]:
    """The force per unit area ``(2, d)`` that the rest of the packing exerts on the lower and
    on the upper wall of plane shear, each wall being its flat face and its glued layer
    (masks ``lower``, ``upper`` ``(N,)``): on the upper one ``-(sum of the gradient over its
    layer) - (the flat wall's forces on the particles touching it)``, the layer's contacts with
    its own flat wall taken out and those of free particles with the flat wall put in; the
    lower likewise. At mechanical equilibrium of the free particles the two are opposite;
    ``tau`` is ``-t_upper,x`` (= ``t_lower,x``), positive when it resists the upper wall's
    motion along +x, and ``t_upper,g`` (= ``-t_lower,g``) the normal stress on the walls,
    positive when the packing pushes them apart."""
    contacts = find_contacts(packing, model)
    grad = gradient(contacts, packing.n)
    axis = packing.cell.walls[0]
    area = packing.cell.volume / packing.cell.h[axis, axis]
    out = np.zeros((2, packing.dim))
    walls = contacts.walls
    for k, (layer, side) in enumerate(((lower, 1.0), (upper, -1.0))):
        out[k] = -grad[layer].sum(axis=0)
        if walls is not None:
            on = (walls.axis == axis) & (walls.side == side)
            out[k] -= walls.force[on].sum(axis=0)
    return out / area


def plane_shift(
    packing: Packing, upper: NDArray[np.bool_], frozen: NDArray[np.bool_], dgamma: float
) -> Packing:
    """``packing`` with its upper rough wall ``upper`` moved along x by ``dgamma L_g`` and the
    free particles (not ``frozen``) by ``dgamma (x_g + L_g / 2)``, the lower wall fixed."""
    axis = packing.cell.walls[0]
    width = packing.cell.h[axis, axis]
    positions = packing.positions.copy()
    free = ~frozen
    positions[free, 0] += dgamma * (positions[free, axis] + 0.5 * width)
    positions[upper, 0] += dgamma * width
    return Packing(positions, packing.radii, packing.cell)


@dataclass(frozen=True, eq=False)
class ShearStep:
    """One relaxed state of the shear (step 0: the start, relaxed, at zero strain).

    ``observables`` holds stress, fabric, their iso/dev parts, pressure, contacts and z;
    ``tau`` the driven shear stress; ``plastic`` is True when ``tau`` dropped since the
    previous step by more than ``DROP_TOL`` x the pressure (``stress_drop`` > 0 is the drop);
    ``saddles`` how many saddles the relaxation left along their negative modes.
    """

    index: int
    strain: float
    tau: float
    stress_drop: float
    plastic: bool
    saddles: int
    observables: Observables
    iterations: int
    evaluations: int
    seconds: float
    packing: Packing

    def row(self) -> dict[str, Value]:
        """The step's numbers, for tables and checkpoints.

        No packing; of the observables, those of :data:`ROW_OBSERVABLES`."""
        obs = self.observables
        return as_row(self, after={"observables": {k: getattr(obs, k) for k in ROW_OBSERVABLES}})


def shear_steps(
    start: Packing,
    model: ContactModel,
    *,
    mode: ShearMode = "pure",
    strain: float = 0.02,
    step: float = 1e-4,
    minimizer: Minimizer | None = None,
    rtol: float = RTOL,
    resume: Sequence[ShearStep] = (),
    wall_layer: float | None = None,
) -> Iterator[ShearStep]:
    """Shear ``start`` quasi-statically to ``strain`` in increments ``step``, yielding steps.

    Parameters
    ----------
    start : a packing, relaxed first (step 0); usually jammed or compressed above jamming.
    model : contact law.
    mode : ``"pure"`` (the paper's shear test), ``"simple"``, ``"uniaxial"`` or ``"plane"``
        (:func:`check_mode`).
    strain, step : final strain and increment (dimensionless, > 0); the last increment is
        shortened to end exactly at ``strain``.
    minimizer : how each step is relaxed (default L-BFGS).
    rtol : tolerance relative to the mean contact force at each step's start (floored at
        round-off, :func:`~athermal.relaxation.round_off_floor`). Every step is checked to
        be a local minimum; a saddle is left along its negative mode (``saddles``).
    resume : the steps already done by an interrupted run with the same arguments; the run
        continues after the last one, bit for bit as an uninterrupted run.
    wall_layer : plane shear: the particles of ``start`` whose centres lie within this distance
        of a wall are glued to it (length units; default the largest diameter); refused with
        another mode.
    """
    strain = positive_scalar(strain, "strain")
    check_mode(mode, strain, start.cell, wall_layer)
    n_steps = strain_steps(strain, step)
    strains = np.minimum(np.arange(n_steps + 1) * step, strain)
    config = minimizer or Minimizer()
    frozen, lower, upper = None, np.zeros(0, bool), np.zeros(0, bool)
    if mode == "plane":
        lower, upper = rough_walls(start, wall_layer)
        frozen = lower | upper
    packing, tau_prev, gamma_prev, first = start, np.nan, 0.0, 0
    if resume:
        if [s.index for s in resume] != list(range(len(resume))) or len(resume) > strains.size:
            raise InputError("resume: steps must be this run's steps 0, 1, ... in order")
        last = resume[-1]
        packing, tau_prev, gamma_prev, first = last.packing, last.tau, last.strain, len(resume)
    layers = None if frozen is None else (lower, upper)
    for index in range(first, strains.size):
        gamma = float(strains[index])
        t0 = time.perf_counter()
        if index:
            packing = strained(packing, mode, gamma_prev, gamma, layers)
        objective = Objective(packing, model, frozen=frozen)
        result, saddles = Relaxer(objective, config).relax_to_minimum(
            objective.x0,
            gtol=force_tolerance(packing, model, rtol),
            what=f"shear step {index} (strain {gamma:g})",
        )
        packing = result.packing
        obs, tau = step_stress(packing, model, mode, layers)
        drop = tau_prev - tau if index else 0.0
        yield ShearStep(
            index=index,
            strain=gamma,
            tau=tau,
            stress_drop=drop,
            plastic=bool(index and drop > DROP_TOL * abs(obs.pressure)),
            saddles=saddles,
            observables=obs,
            iterations=result.iterations,
            evaluations=result.evaluations,
            seconds=time.perf_counter() - t0,
            packing=packing,
        )
        tau_prev, gamma_prev = tau, gamma


Layers = tuple[NDArray[np.bool_], NDArray[np.bool_]]
"""Plane shear's rough walls: the masks ``(N,)`` of the particles glued to the lower and to the
upper wall (:func:`rough_walls`)."""


def strained(
    packing: Packing, mode: ShearMode, old: float, new: float, layers: Layers | None = None
) -> Packing:
    """``packing``, at strain ``old`` of ``mode``, taken to strain ``new``: its positions and
    cell deformed by ``D(new) D(old)^-1``, or in plane shear (``layers``) its upper wall moved
    (:func:`plane_shift`)."""
    if layers is not None:
        lower, upper = layers
        return plane_shift(packing, upper, lower | upper, new - old)
    total_new = deformation(mode, new, packing.dim)
    total_old = deformation(mode, old, packing.dim)
    return packing.deform(total_new @ np.linalg.inv(total_old))


def step_stress(
    packing: Packing, model: ContactModel, mode: ShearMode, layers: Layers | None = None
) -> tuple[Observables, float]:
    """The observables of a relaxed shear state (the glued particles of ``layers`` never
    rattlers) and its driven stress ``tau`` (:func:`driven_stress`, or in plane shear the walls'
    shear traction, :func:`plane_tractions`)."""
    if layers is None:
        obs = measure(packing, model)
        return obs, driven_stress(mode, obs.stress)
    lower, upper = layers
    obs = measure(packing, model, lower | upper)
    traction = plane_tractions(packing, model, lower, upper)
    return obs, 0.5 * float(traction[0, 0] - traction[1, 0])


def rough_walls(
    start: Packing, wall_layer: float | None = None
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Plane shear's rough walls in ``start``: the masks ``(N,)`` of its particles within
    ``wall_layer`` (default the largest diameter) of the lower and of the upper wall
    (:func:`~athermal.model.walls.wall_layers`). Refused (:class:`InputError`) when the cell cannot
    be plane-sheared (:func:`check_mode`), a layer is empty, the layers meet or they leave no
    particle free."""
    _check_plane(start.cell)
    width = 2.0 * float(start.radii.max())
    if wall_layer is not None:
        width = positive_scalar(wall_layer, "wall_layer")
    lower, upper = wall_layers(start.positions, start.cell, start.cell.walls[0], width)
    if not lower.any() or not upper.any() or (lower & upper).any() or (lower | upper).all():
        raise InputError(
            f"wall_layer: a layer of {width:.6g} glues {int(lower.sum())} particles to the lower "
            f"wall and {int(upper.sum())} to the upper one, of {start.n}; each wall needs some, "
            "the layers may not meet, and some particles must stay free"
        )
    return lower, upper
