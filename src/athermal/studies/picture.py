"""Pictures of 2D packings with their contact forces (lines between centres, width by force),
rattlers marked: one packing (:func:`packing_figure`) or the snapshots of a jamming run
(:func:`jamming_figure`). Each returns a :class:`matplotlib.figure.Figure`; write it with
:func:`athermal.studies.plot.save`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..analysis.observables import rattlers
from ..errors import InputError
from ..model.contact import ContactModel, find_contacts
from ..model.packing import Packing
from .plot import new_figure

if TYPE_CHECKING:
    from matplotlib.artist import Artist
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

MAX_FORCE_WIDTH = 2.0
"""Width (points) of the line of the largest force in a packing of up to 1024 disks drawn
``size = 6`` inches wide; larger packings get ``sqrt(1024 / N)`` of it."""
MIN_FORCE_WIDTH = 0.05
"""Force lines thinner than this (points) are not drawn."""
FORCE_COLOR = "firebrick"


def max_force_width(n: int, size: float = 6.0) -> float:
    """Line width (points) of the force equal to the force scale, for ``n`` disks drawn in a
    panel ``size`` inches wide: :data:`MAX_FORCE_WIDTH` x ``min(1, sqrt(1024 / n))`` x
    ``size / 6``, so lines stay thinner than the disks."""
    return MAX_FORCE_WIDTH * min(1.0, float(np.sqrt(1024.0 / max(n, 1)))) * size / 6.0


def _force_scale(packing: Packing, model: ContactModel) -> float:
    """The largest contact force of ``packing`` (``k l^(alpha-1)``), 0 without contacts."""
    force = find_contacts(packing.wrapped(), model).force_magnitude
    return float(force.max()) if force.size else 0.0


def _check_force_scale(force_scale: float) -> float:
    scale = float(force_scale)
    if not np.isfinite(scale) or scale <= 0.0:
        raise InputError(f"force_scale: must be a finite force > 0, got {force_scale!r}")
    return scale


def _draw_packing(
    ax: Axes,
    packing: Packing,
    model: ContactModel | None,
    force_scale: float | None,
    max_width: float,
) -> tuple[float | None, int]:
    """Draw disks (rattlers white with a dashed grey edge), cell, walls (thick lines, with a
    force line from each centre to the wall it touches) and force lines into ``ax``;
    return the force scale used (None without ``model`` or contacts) and the rattler count
    (0 when every particle is one: an unjammed packing has no network to rattle in)."""
    from matplotlib.collections import EllipseCollection, LineCollection
    from matplotlib.patches import Polygon

    wrapped = packing.wrapped()
    h = packing.cell.h
    walls = packing.cell.walls
    around = [(0,) if axis in walls else (-1, 0, 1) for axis in range(2)]
    images = np.array([(a, b) for a in around[0] for b in around[1]], dtype=np.float64)
    shifts = images @ h.T
    centres = (wrapped.positions[None, :, :] + shifts[:, None, :]).reshape(-1, 2)
    radii = np.tile(wrapped.radii, len(images))
    corners = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]) @ h.T
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    margin = 2.0 * float(radii.max())
    keep = np.all((centres > lo - margin) & (centres < hi + margin), axis=1)
    rattler = np.zeros(packing.n, dtype=bool)
    scale: float | None = None
    segments: NDArray[np.float64] | None = None
    widths: NDArray[np.float64] | None = None
    if model is not None:
        contacts = find_contacts(wrapped, model)
        rattler = rattlers(contacts, packing.n, packing.dim)
        if rattler.all():  # no rigid network (unjammed): every disk drawn alike, none marked
            rattler[:] = False
        # a wall contact's line runs from the centre to the wall
        on_wall = contacts.walls
        first = np.concatenate([contacts.i, [] if on_wall is None else on_wall.particle])
        branch = np.concatenate(
            [contacts.branch, np.zeros((0, 2)) if on_wall is None else on_wall.branch]
        )
        force = np.concatenate(
            [contacts.force_magnitude, [] if on_wall is None else on_wall.force_magnitude]
        )
        if force_scale is not None:
            scale = _check_force_scale(force_scale)
        elif force.size:
            scale = float(force.max())
        if scale is not None and force.size:
            width = np.minimum(max_width * force / scale, max_width)
            visible = width >= MIN_FORCE_WIDTH
            start = wrapped.positions[first[visible].astype(np.int64)]
            pairs = np.stack([start, start - branch[visible]], axis=1)
            segments = np.concatenate([pairs + shift for shift in shifts])
            widths = np.tile(width[visible], len(images))
    tiled = np.tile(rattler, len(images))
    r_min, r_max = packing.radii.min(), packing.radii.max()
    shade = 0.8 - 0.25 * (radii - r_min) / (r_max - r_min if r_max > r_min else 1.0)
    face = np.column_stack([shade, shade, np.full_like(shade, 0.9)])
    for chosen, faces, edge, style, lw in (
        (keep & ~tiled, face[keep & ~tiled], "0.3", "solid", 0.3),
        (keep & tiled, "white", "0.45", "--", 0.6),
    ):
        if chosen.any():
            ax.add_collection(
                EllipseCollection(
                    2 * radii[chosen],
                    2 * radii[chosen],
                    np.zeros(int(chosen.sum())),
                    units="xy",
                    offsets=centres[chosen],
                    offset_transform=ax.transData,
                    facecolors=faces,
                    edgecolors=edge,
                    linewidths=lw,
                    linestyles=style,
                    gid="rattlers" if style == "--" else "disks",
                )
            )
    if segments is not None and widths is not None and widths.size:
        lines = LineCollection(
            list(segments), linewidths=widths, colors=FORCE_COLOR, capstyle="round", zorder=3
        )
        lines.set_gid("forces")
        ax.add_collection(lines)
    ax.add_patch(Polygon(corners, closed=True, fill=False, edgecolor="black", linewidth=1.0))
    pad = np.zeros(2)
    for axis in walls:  # a wall: a thick line on its face, drawn just outside the cell
        pad[axis] = 0.02 * (hi[axis] - lo[axis])
        for face in (lo[axis], hi[axis]):
            ends = np.array([lo, hi], dtype=np.float64)
            ends[:, axis] = face
            ax.plot(ends[:, 0], ends[:, 1], color="black", linewidth=3.0, gid="walls")
    ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
    ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    return scale, int(rattler.sum())


def _packing_key(
    scale: float | None, max_width: float, n_rattlers: int | None
) -> tuple[list[Artist], list[str]]:
    """Legend handles: the force key (a line of ``max_width`` for ``f = scale``, saying that
    each contact's line width is proportional to its force) and the rattler marker (with its
    count when ``n_rattlers`` is given)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Artist] = []
    labels: list[str] = []
    if scale is not None:
        handles.append(Line2D([], [], color=FORCE_COLOR, linewidth=max_width))
        labels.append(
            rf"contact force (width $\propto f$; this line: $f$ = {scale:.2e} "
            rf"$k\,\ell^{{\alpha-1}}$)"
        )
    if n_rattlers is None or n_rattlers > 0:
        handles.append(Patch(facecolor="white", edgecolor="0.45", linestyle="--"))
        labels.append("rattler" if n_rattlers is None else f"rattler ({n_rattlers})")
    return handles, labels


def packing_figure(
    packing: Packing,
    model: ContactModel | None = None,
    *,
    title: str = "",
    size: float = 6.0,
    force_scale: float | None = None,
    ax: Axes | None = None,
) -> Figure:
    """The disks of a 2D ``packing`` drawn to scale in its unit cell, periodic images included
    (none across walls, which are drawn as thick lines with the lines of their contact forces),
    shaded by radius (the smallest light, the largest dark). With ``model``: every contact force
    ``f`` as a line between the centres of width
    ``w = max_force_width(N, size) x min(1, f / force_scale)`` points (lines with
    ``w <`` :data:`MIN_FORCE_WIDTH` omitted), rattlers (the rule of
    :func:`athermal.analysis.observables.rattlers`) white with a dashed grey edge, and a key.

    ``force_scale`` (``k l^(alpha-1)``) defaults to this packing's largest force; pass one
    shared value to compare packings. ``size``: figure width in inches (with ``ax``, the panel
    width, used for line widths only). With ``ax``, draws into it and returns its figure.
    """
    if packing.dim != 2:
        raise InputError(f"packing_figure: draws 2D packings, got dim = {packing.dim}")
    if ax is None:
        fig = new_figure(size, size)
        ax = fig.add_subplot()
    else:
        from matplotlib.figure import Figure

        owner = ax.get_figure()
        root = owner if owner is None or isinstance(owner, Figure) else owner.figure
        if not isinstance(root, Figure):
            raise InputError("packing_figure: ax belongs to no figure")
        fig = root
    width = max_force_width(packing.n, size)
    scale, n_rattlers = _draw_packing(ax, packing, model, force_scale, width)
    if model is not None:
        handles, labels = _packing_key(scale, width, n_rattlers)
        if handles:
            ax.legend(
                handles,
                labels,
                loc="upper center",
                bbox_to_anchor=(0.5, 0.0),
                ncols=len(handles),
                frameon=False,
                fontsize="small",
            )
    ax.set_title(title or f"N = {packing.n}, phi = {packing.phi:.6f}")
    return fig


def jamming_figure(
    snapshots: Sequence[tuple[str, Packing]], model: ContactModel, *, title: str = ""
) -> Figure:
    """The paper's jamming figure: one panel per ``(label, packing)`` (e.g. initial,
    intermediate, jammed) side by side, titled ``(a) label``, ``(b) label``, ...; all force
    lines on ONE absolute scale, the largest force over all snapshots, with one key."""
    if not snapshots:
        raise InputError("jamming_figure: needs at least one snapshot")
    panel = 4.0
    fig = new_figure(panel * len(snapshots), panel + 0.9)
    axes = fig.subplots(1, len(snapshots), squeeze=False)[0]
    forces = [_force_scale(packing, model) for _, packing in snapshots]
    shared = max(forces)
    width = max_force_width(max(packing.n for _, packing in snapshots), panel)
    for k, (ax, (label, packing)) in enumerate(zip(axes, snapshots, strict=True)):
        if packing.dim != 2:
            raise InputError(f"jamming_figure: draws 2D packings, got dim = {packing.dim}")
        _, n_rattlers = _draw_packing(ax, packing, model, shared if shared > 0 else None, width)
        ax.set_title(f"({chr(ord('a') + k)}) {label}")
        note = f"{n_rattlers} rattlers of {packing.n}" if n_rattlers else "no rigid network"
        ax.set_xlabel(note if model is not None else "", fontsize="small")
    handles, labels = _packing_key(shared if shared > 0 else None, width, None)
    fig.legend(handles, labels, loc="outside lower center", ncols=len(handles), frameon=False)
    if title:
        fig.suptitle(title)
    return fig
