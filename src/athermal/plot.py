"""Figures of the seed paper with matplotlib: packings with contact forces, convergence,
scaling laws, iteration counts and shear curves. Each function returns a
:class:`matplotlib.figure.Figure` (no global pyplot state); :func:`save` writes one atomically.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from .contact import ContactModel, find_contacts
from .errors import InputError
from .fitting import PowerLaw
from .packing import Packing

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def _figure(width: float = 5.0, height: float = 4.0) -> Figure:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - matplotlib is a core dependency
        raise ImportError("athermal's figures need matplotlib: pip install matplotlib") from exc
    return Figure(figsize=(width, height), layout="constrained")


def save(figure: Figure, path: str | os.PathLike[str], *, dpi: int = 150) -> Path:
    """Write ``figure`` to ``path`` (format from the suffix), replacing it atomically."""
    target = Path(path)
    temporary = target.with_name(f".{target.stem}.{uuid.uuid4().hex}{target.suffix}")
    try:
        figure.savefig(temporary, dpi=dpi)
        os.replace(temporary, target)
    finally:
        temporary.unlink(missing_ok=True)
    return target


def packing_figure(
    packing: Packing, model: ContactModel | None = None, *, title: str = "", size: float = 6.0
) -> Figure:
    """The disks of a 2D ``packing`` drawn to scale in its cell, periodic images included, and
    (with ``model``) every contact force as a line between the centres whose width follows the
    force. Small disks light, large dark."""
    if packing.dim != 2:
        raise InputError(f"packing_figure: draws 2D packings, got dim = {packing.dim}")
    from matplotlib.collections import EllipseCollection, LineCollection
    from matplotlib.patches import Polygon

    fig = _figure(size, size)
    ax = fig.add_subplot()
    wrapped = packing.wrapped()
    h = packing.cell.h
    images = np.array([(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)], dtype=float)
    centres = (wrapped.positions[None, :, :] + (images @ h.T)[:, None, :]).reshape(-1, 2)
    radii = np.tile(wrapped.radii, len(images))
    corners = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]) @ h.T
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    margin = 2.0 * float(radii.max())
    keep = np.all((centres > lo - margin) & (centres < hi + margin), axis=1)
    shade = np.where(radii[keep] > np.median(packing.radii), 0.55, 0.8)
    disks = EllipseCollection(
        2 * radii[keep],
        2 * radii[keep],
        np.zeros(int(keep.sum())),
        units="xy",
        offsets=centres[keep],
        offset_transform=ax.transData,
        facecolors=np.column_stack([shade, shade, np.full_like(shade, 0.9)]),
        edgecolors="0.3",
        linewidths=0.3,
    )
    ax.add_collection(disks)
    if model is not None:
        contacts = find_contacts(wrapped, model)
        if contacts.i.size:
            force = contacts.force_magnitude
            start = wrapped.positions[contacts.i]
            segments = np.stack([start, start - contacts.branch], axis=1)
            segments = np.concatenate([segments + shift for shift in images @ h.T])
            widths = np.tile(0.3 + 3.0 * force / force.max(), len(images))
            lines = LineCollection(list(segments), linewidths=widths, colors="firebrick")
            ax.add_collection(lines)
    ax.add_patch(Polygon(corners, closed=True, fill=False, edgecolor="black", linewidth=1.0))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title or f"N = {packing.n}, phi = {packing.phi:.6f}")
    return fig


def convergence_figure(histories: Mapping[str, NDArray[np.float64]], *, title: str = "") -> Figure:
    """``max_i |grad_i|`` (the l-infinity gradient norm) against the iteration, one line per
    method (the seed's convergence figure)."""
    fig = _figure()
    ax = fig.add_subplot()
    for label, history in histories.items():
        ax.semilogy(np.arange(len(history)), history, label=label, linewidth=1.0)
    ax.set_xlabel("iteration")
    ax.set_ylabel(r"$\max_i |\nabla_i E|$")
    ax.set_title(title)
    ax.legend()
    return fig


def _loglog(
    ax: Axes, x: Sequence[float], y: Sequence[float], fit: PowerLaw | None, label: str
) -> None:
    """Points (filled where fitted, open outside the fit's range) and the fit over its range."""
    xs, ys = np.asarray(x), np.asarray(y)
    ok = (xs > 0) & (ys > 0)
    inside = ok if fit is None else ok & (xs >= fit.x_min) & (xs <= fit.x_max)
    (line,) = ax.loglog(xs[inside], ys[inside], "o", markersize=3, label=label)
    ax.loglog(
        xs[ok & ~inside], ys[ok & ~inside], "o", markersize=3, mfc="none", color=line.get_color()
    )
    if fit is not None:
        grid = np.geomspace(fit.x_min, fit.x_max, 50)
        ax.loglog(
            grid,
            fit(grid),
            "-",
            color=line.get_color(),
            linewidth=0.8,
            label=f"slope {fit.exponent:.2f} ± {fit.stderr:.2f} ({fit.points} points, "
            f"{fit.x_min:.0e} ... {fit.x_max:.0e})",
        )


def scaling_figure(
    delta_phi: Mapping[str, Sequence[float]],
    values: Mapping[str, Sequence[float]],
    fits: Mapping[str, PowerLaw | None],
    *,
    ylabel: str,
    title: str = "",
) -> Figure:
    """``values[label]`` against ``delta_phi[label]`` on log-log axes with the fitted slope,
    one series per label (e.g. ``alpha = 2`` and ``alpha = 2.5``); open markers lie outside the
    fit (below its window, or dropped)."""
    fig = _figure()
    ax = fig.add_subplot()
    for label in values:
        _loglog(ax, delta_phi[label], values[label], fits.get(label), label)
    ax.set_xlabel(r"$\phi - \phi_c$ ($\phi_c$ of the jamming protocol)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize="small")
    return fig


def iterations_figure(
    delta_phi: Sequence[float],
    counts: Mapping[str, Sequence[Sequence[float]]],
    *,
    title: str = "",
) -> Figure:
    """Mean iteration count against ``delta_phi`` with standard-deviation error bars, one
    series per method; ``counts[label][k]`` are the realizations at ``delta_phi[k]``."""
    fig = _figure()
    ax = fig.add_subplot()
    for label, per_point in counts.items():
        means = [float(np.mean(v)) for v in per_point]
        sds = [float(np.std(v, ddof=1)) if len(v) > 1 else 0.0 for v in per_point]
        ax.errorbar(delta_phi, means, yerr=sds, marker="o", markersize=3, capsize=2, label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(r"$\phi - \phi_c$")
    ax.set_ylabel("iterations per step")
    ax.set_title(title)
    ax.legend(fontsize="small")
    return fig


def shear_figure(curves: Mapping[str, Mapping[str, Sequence[float]]], *, title: str = "") -> Figure:
    """The seed's shear-test figure: stress (left) and fabric (right), isotropic and deviatoric
    parts against strain; ``curves[label]`` has ``strain``, ``stress_iso``, ``stress_dev``,
    ``fabric_iso``, ``fabric_dev`` (one curve per strain increment)."""
    fig = _figure(10.0, 4.0)
    stress_ax, fabric_ax = fig.subplots(1, 2)
    for label, c in curves.items():
        (iso,) = stress_ax.plot(c["strain"], c["stress_iso"], "-", label=f"iso, {label}")
        stress_ax.plot(
            c["strain"], c["stress_dev"], "--", color=iso.get_color(), label=f"dev, {label}"
        )
        (fiso,) = fabric_ax.plot(c["strain"], c["fabric_iso"], "-", label=f"iso, {label}")
        fabric_ax.plot(
            c["strain"], c["fabric_dev"], "--", color=fiso.get_color(), label=f"dev, {label}"
        )
    from matplotlib.ticker import MaxNLocator

    for ax in (stress_ax, fabric_ax):
        ax.xaxis.set_major_locator(MaxNLocator(5))
    stress_ax.set_xlabel(r"strain $\gamma$")
    stress_ax.set_ylabel(r"stress $\sigma$")
    fabric_ax.set_xlabel(r"strain $\gamma$")
    fabric_ax.set_ylabel("fabric $F$")
    stress_ax.legend(fontsize="x-small")
    fabric_ax.legend(fontsize="x-small")
    fig.suptitle(title)
    return fig


def histogram_figure(values: Sequence[float], *, xlabel: str, title: str = "") -> Figure:
    """A histogram of ``values`` (e.g. phi_c over realizations) with their mean marked."""
    fig = _figure()
    ax = fig.add_subplot()
    data = np.asarray(values, dtype=np.float64)
    ax.hist(data, bins=max(5, int(np.sqrt(data.size)) + 1), color="steelblue", edgecolor="white")
    ax.axvline(float(data.mean()), color="firebrick", label=f"mean {data.mean():.5f}")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("realizations")
    ax.set_title(title)
    ax.legend()
    return fig
