"""Figures of the paper with matplotlib: convergence, scaling laws, iteration counts, shear
curves, ensemble histograms, force distributions, spectra, criticality and the gap exponent
along the gaps (packings with their contact forces: :mod:`athermal.studies.picture`). Each
function returns a :class:`matplotlib.figure.Figure` (no global pyplot state); :func:`save`
writes one atomically.

Units: the unit cell, stiffness ``k = 1``; energies ``k l^alpha``, stresses, pressures and
moduli ``k l^(alpha-d)``, forces and gradients ``k l^(alpha-1)`` (``l`` a length).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..analysis.fitting import PowerLaw
from ..atomic import replacing
from ..errors import InputError

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from ..analysis.modes import Modes
    from ..certify.criticality import CriticalExponents, WeakForcesAndGaps

GRADIENT_UNITS = r"($k\,\ell^{\alpha-1}$)"
STRESS_UNITS = r"($k\,\ell^{\alpha-d}$)"


def new_figure(width: float = 5.0, height: float = 4.0) -> Figure:
    """An empty figure ``width`` x ``height`` inches, laid out by matplotlib's constrained
    layout."""
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - matplotlib is a core dependency
        raise ImportError("athermal's figures need matplotlib: pip install matplotlib") from exc
    return Figure(figsize=(width, height), layout="constrained")


def save(figure: Figure, path: str | os.PathLike[str], *, dpi: int = 150) -> Path:
    """Write ``figure`` to ``path`` (format from the suffix), replacing it atomically."""
    with replacing(path) as temporary:
        figure.savefig(temporary, dpi=dpi)
    return Path(path)


def convergence_figure(
    histories: Mapping[str, NDArray[np.float64]],
    *,
    title: str = "",
    tolerance: float | None = None,
    ylabel: str = r"$\max_i |\nabla_i E|$ " + GRADIENT_UNITS,
) -> Figure:
    """``max_i |grad_i E|`` (l-infinity gradient norm, ``k l^(alpha-1)``) against the
    iteration, one line per method (the paper's convergence figure); ``tolerance`` (the same
    units) as a dashed horizontal line. Put alpha and N in ``title``."""
    fig = new_figure(7.0, 4.0)
    ax = fig.add_subplot()
    for label, history in histories.items():
        ax.semilogy(np.arange(len(history)), history, label=label, linewidth=0.8)
    if tolerance is not None:
        ax.axhline(float(tolerance), color="0.3", linestyle="--", linewidth=0.8, label="tolerance")
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(nbins=5, integer=True))
    ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))
    ax.set_xlabel("iteration")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    fig.legend(loc="outside right upper", fontsize="small", frameon=False)
    return fig


def _loglog(
    ax: Axes,
    x: Sequence[float],
    y: Sequence[float],
    fit: PowerLaw | None,
    label: str,
    reference: float | None,
    used: Sequence[bool] | None = None,
) -> None:
    """Points (filled where ``used`` by the fit, default: inside the fit's range; open
    otherwise), the fit over its range with its window shaded, and (``reference``) a dotted line
    of that slope a factor 2 below the middle fitted point."""
    xs, ys = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    ok = (xs > 0) & (ys > 0)
    if used is not None:
        inside = ok & np.asarray(used, dtype=bool)
    else:
        inside = ok if fit is None else ok & (xs >= fit.x_min) & (xs <= fit.x_max)
    (line,) = ax.loglog(xs[inside], ys[inside], "o", markersize=3, label=label)
    color = line.get_color()
    ax.loglog(xs[ok & ~inside], ys[ok & ~inside], "o", markersize=3, mfc="none", color=color)
    if fit is not None:
        ax.axvspan(fit.x_min, fit.x_max, color=color, alpha=0.07, linewidth=0)
        grid = np.geomspace(fit.x_min, fit.x_max, 50)
        ax.loglog(
            grid,
            fit(grid),
            "-",
            color=color,
            linewidth=0.8,
            label=f"fit: slope {fit.exponent:.2f} ± {fit.stderr:.2f} ({fit.points} points, "
            f"shaded {fit.x_min:.0e} ... {fit.x_max:.0e})",
        )
    if reference is not None:
        anchor = inside if inside.any() else ok
        if anchor.any():
            order = np.argsort(xs[anchor])
            x0 = float(xs[anchor][order][order.size // 2])
            y0 = float(ys[anchor][order][order.size // 2]) / 2.0
            span = np.geomspace(float(xs[ok].min()), float(xs[ok].max()), 2)
            ax.loglog(
                span,
                y0 * (span / x0) ** reference,
                ":",
                color="0.5",
                linewidth=1.0,
                label=f"slope {reference:g} (expected, {label})",
                gid="reference",
            )


def scaling_figure(
    delta_phi: Mapping[str, Sequence[float]],
    values: Mapping[str, Sequence[float]],
    fits: Mapping[str, PowerLaw | None],
    *,
    ylabel: str,
    title: str = "",
    reference_slopes: Mapping[str, float] | None = None,
    phi_c_note: str | None = None,
    used: Mapping[str, Sequence[bool]] | None = None,
) -> Figure:
    """``values[label]`` against ``delta_phi[label]`` on log-log axes, one series per label
    (e.g. ``alpha = 2``): fitted points filled (those ``used[label]`` marks, default: those in
    the fit's range), the others open, the fit over its (shaded) window, and a grey dotted line
    of slope ``reference_slopes[label]`` (the expected exponent) where given. ``ylabel`` should
    carry units; ``phi_c_note`` explains phi_c."""
    fig = new_figure(6.4, 4.8)
    ax = fig.add_subplot()
    slopes = reference_slopes or {}
    for label in values:
        mask = None if used is None else used.get(label)
        _loglog(
            ax, delta_phi[label], values[label], fits.get(label), label, slopes.get(label), mask
        )
    note = r"$\phi_c$ of the jamming protocol" if phi_c_note is None else phi_c_note
    ax.set_xlabel(r"$\phi - \phi_c$" + (f" ({note})" if note else ""))
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize="x-small")
    return fig


def iterations_figure(
    delta_phi: Sequence[float],
    counts: Mapping[str, Sequence[Sequence[float]]],
    *,
    title: str = "",
    error: str = "sd",
) -> Figure:
    """Mean iteration count against ``delta_phi``, one series per method;
    ``counts[label][k]`` are the realizations at ``delta_phi[k]`` (NaN ones, unjammed there, left
    out). Error bars: the sample
    standard deviation (``error="sd"``) or the standard error of the mean (``"stderr"``),
    named in the y label and legend title. Tick labels are plain integers."""
    if error not in ("sd", "stderr"):
        raise InputError(f"error: expected 'sd' or 'stderr', got {error!r}")
    from matplotlib.ticker import FuncFormatter, MaxNLocator, NullFormatter

    fig = new_figure(7.5, 4.0)
    ax = fig.add_subplot()
    every: list[float] = []
    for label, per_point in counts.items():
        means, bars = [], []
        for v in per_point:
            data = np.asarray(v, dtype=np.float64)
            data = data[np.isfinite(data)]
            sd = float(np.std(data, ddof=1)) if data.size > 1 else 0.0
            means.append(float(np.mean(data)) if data.size else np.nan)
            bars.append(sd / np.sqrt(data.size) if error == "stderr" and data.size else sd)
        every.extend(m for m in means if np.isfinite(m) and m > 0)
        ax.errorbar(delta_phi, means, yerr=bars, marker="o", markersize=3, capsize=2, label=label)
    ax.set_xscale("log")
    if every and max(every) > 10.0 * min(every):
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(NullFormatter())
    else:
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(r"$\phi - \phi_c$")
    ax.set_ylabel(f"iterations per step (mean ± {error})")
    ax.set_title(title)
    ax.legend(  # beside the axes: with five methods no corner inside is free
        fontsize="small",
        title=f"mean ± {error} over realizations",
        title_fontsize="small",
        loc="upper left",
        bbox_to_anchor=(1.02, 1.0),
    )
    return fig


def shear_figure(curves: Mapping[str, Mapping[str, Sequence[float]]], *, title: str = "") -> Figure:
    """The paper's shear-test figure on a 2 x 2 grid against the strain (dimensionless):
    isotropic and deviatoric stress (``k l^(alpha-d)``, top) and fabric (dimensionless,
    bottom), one line per curve; ``curves[label]`` (label: the strain increment) has
    ``strain``, ``stress_iso``, ``stress_dev``, ``fabric_iso``, ``fabric_dev``. One legend."""
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    fig = new_figure(8.0, 6.0)
    axes = fig.subplots(2, 2, sharex=True)
    panels = (
        ("stress_iso", r"$\sigma_{iso}$ " + STRESS_UNITS),
        ("stress_dev", r"$\sigma_{dev}$ " + STRESS_UNITS),
        ("fabric_iso", r"$F_{iso}$"),
        ("fabric_dev", r"$F_{dev}$"),
    )
    for ax, (key, ylabel) in zip(axes.flat, panels, strict=True):
        for label, c in curves.items():
            ax.plot(c["strain"], c[key], "-", linewidth=1.0, label=label)
        formatter = ScalarFormatter(useMathText=True)
        formatter.set_powerlimits((-2, 3))
        ax.yaxis.set_major_formatter(formatter)
        ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.set_ylabel(ylabel)
    for ax in axes[1]:
        ax.set_xlabel(r"strain $\gamma$")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if handles:
        fig.legend(
            handles,
            labels,
            loc="outside right upper",
            title="strain increment",
            fontsize="small",
        )
    if title:
        fig.suptitle(title)
    return fig


def _histogram(ax: Axes, values: Sequence[float], xlabel: str) -> None:
    """Histogram of ``values`` with integer counts, the mean (line) and mean ± sd (band)."""
    from matplotlib.ticker import MaxNLocator

    data = np.asarray(values, dtype=np.float64)
    if data.size == 0:
        raise InputError(f"histogram: no values for {xlabel!r}")
    mean = float(data.mean())
    sd = float(data.std(ddof=1)) if data.size > 1 else 0.0
    heights, _, _ = ax.hist(
        data, bins=max(5, int(np.sqrt(data.size)) + 1), color="steelblue", edgecolor="white"
    )
    if sd > 0:
        ax.axvspan(mean - sd, mean + sd, color="firebrick", alpha=0.12, linewidth=0, zorder=0)
    ax.axvline(mean, color="firebrick", label=f"mean ± sd = {mean:.5g} ± {sd:.2g}")
    ax.set_ylim(0.0, 1.3 * float(np.max(heights)))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("realizations")
    ax.legend(fontsize="small")


def histogram_figure(values: Sequence[float], *, xlabel: str, title: str = "") -> Figure:
    """A histogram of ``values`` (e.g. phi_c over realizations; ``xlabel`` with units) with
    integer counts and the mean ± sample sd marked (line and band)."""
    fig = new_figure()
    ax = fig.add_subplot()
    _histogram(ax, values, xlabel)
    ax.set_title(title)
    return fig


def summary_figure(panels: Mapping[str, Sequence[float]], *, title: str = "") -> Figure:
    """The ensemble summary: one histogram per quantity (key: its axis label with units, e.g.
    ``phi_c``, ``z - z_iso``, ``p / eps^(alpha-1)``), integer counts of realizations and the
    mean ± sd marked in each; up to 3 panels a row."""
    if not panels:
        raise InputError("summary_figure: needs at least one quantity")
    columns = min(3, len(panels))
    rows = -(-len(panels) // columns)
    fig = new_figure(4.0 * columns, 3.4 * rows)
    axes: Any = fig.subplots(rows, columns, squeeze=False)
    for ax, (label, values) in zip(axes.flat, panels.items(), strict=False):
        _histogram(ax, values, label)
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title)
    return fig


def force_distribution_figure(
    histograms: Mapping[str, tuple[NDArray[np.int64], int]], *, title: str = ""
) -> Figure:
    """The contact-force distribution ``P(f / <f>)``: one curve per histogram (label ->
    ``(counts, overflow)`` on :data:`athermal.analysis.forces.EDGES`), on a logarithmic axis (left,
    with each fitted exponential tail dashed and its decay in the legend) and a linear one (right,
    the small forces)."""
    from ..analysis.forces import EDGES, exponential_tail, histogram_density

    centres = (EDGES[:-1] + EDGES[1:]) / 2.0
    fig = new_figure(9.0, 3.8)
    log_ax, lin_ax = fig.subplots(1, 2)
    for label, (counts, overflow) in histograms.items():
        density = histogram_density(counts, overflow)
        seen = counts > 0
        tail = exponential_tail(counts, overflow)
        text = label if tail is None else f"{label}: decay {tail.decay:.2f} ± {tail.stderr:.2f}"
        (line,) = log_ax.semilogy(centres[seen], density[seen], "o", markersize=3, label=text)
        lin_ax.plot(centres, density, "-", color=line.get_color(), linewidth=1.0)
        if tail is not None:
            x = np.array([tail.x_min, tail.x_max])
            fitted = np.exp(tail.log_prefactor - tail.decay * x)
            log_ax.semilogy(x, fitted, "--", color=line.get_color())
    log_ax.set_xlabel(r"$f / \langle f \rangle$")
    log_ax.set_ylabel(r"$P(f / \langle f \rangle)$")
    log_ax.legend(fontsize="small")
    lin_ax.set_xlim(0.0, 4.0)
    lin_ax.set_ylim(bottom=0.0)
    lin_ax.set_xlabel(r"$f / \langle f \rangle$")
    lin_ax.set_ylabel(r"$P(f / \langle f \rangle)$ (linear)")
    if title:
        fig.suptitle(title)
    return fig


def modes_figure(spectra: Mapping[str, Modes], *, title: str = "", seed: int = 0) -> Figure:
    """Vibrational spectra, one colour per packing (label ->
    :class:`~athermal.analysis.modes.Modes` of a
    full spectrum), with what decided each ``omega*``
    (:func:`~athermal.analysis.modes.plateau_edge`):
    the density of states ``D(omega)`` on log-log axes with the plateau level over its window
    (solid), half of it (dashed) and ``omega*`` with its bootstrap error band (left); the
    cumulative count of modes ``N(omega) / M`` with the plateau's line ``D_p omega`` (dotted)
    and the line of half the plateau, ``D_p omega / 2`` (dashed), whose crossing with the count
    is ``omega*`` (middle); the participation ratio of every mode against its frequency
    (right). Frequencies in ``sqrt(k l^(alpha-2) / m)``; ``seed`` is the bootstrap's."""
    from ..analysis.modes import PLATEAU_FRACTION, cumulative_count, density_of_states, plateau_edge

    fig = new_figure(13.0, 4.0)
    dos_ax, count_ax, pr_ax = fig.subplots(1, 3)
    for label, modes in spectra.items():
        omega = modes.frequencies
        edges, density = density_of_states(omega)
        centres = np.sqrt(edges[:-1] * edges[1:])
        seen = density > 0
        edge = plateau_edge(omega, seed=seed)
        star, half = edge.omega_star, PLATEAU_FRACTION * edge.plateau
        (line,) = dos_ax.loglog(
            centres[seen],
            density[seen],
            "o-",
            markersize=3,
            linewidth=1.0,
            label=rf"{label}: $\omega^*$ = {star:.3g} $\pm$ {edge.error:.2g}",
        )
        color = line.get_color()
        dos_ax.hlines(edge.plateau, *edge.window, color=color, linewidth=2.0, alpha=0.6)
        dos_ax.hlines(half, omega.min(), edge.window[1], color=color, linestyle="--")
        sorted_omega, fraction = cumulative_count(omega)
        count_ax.loglog(
            sorted_omega,
            fraction,
            drawstyle="steps-mid",
            color=color,
            linewidth=1.0,
            label=rf"{label}: {edge.modes_below} of {edge.modes} modes below $\omega^*$",
        )
        count_ax.loglog(sorted_omega, edge.plateau * sorted_omega, ":", color=color)
        count_ax.loglog(sorted_omega, half * sorted_omega, "--", color=color)
        count_ax.plot(star, half * star, "o", color=color, markerfacecolor="none")
        for ax in (dos_ax, count_ax):
            ax.axvline(star, color=color, linestyle=":", linewidth=1.0)
            ax.axvspan(
                max(star - edge.error, omega.min()), star + edge.error, color=color, alpha=0.12
            )
        vibrating = modes.eigenvalues > modes.tolerance
        pr_ax.semilogx(omega, modes.participation[vibrating], ".", markersize=2, color=color)
    dos_ax.set_title(r"solid: plateau $D_p$ over its window; dashed: $D_p / 2$", fontsize="small")
    dos_ax.set_xlabel(r"$\omega$")
    dos_ax.set_ylabel(r"$D(\omega)$")
    dos_ax.legend(fontsize="small")
    count_ax.set_title(r"dotted: $D_p\,\omega$; dashed: $D_p\,\omega / 2$", fontsize="small")
    count_ax.set_xlabel(r"$\omega$")
    count_ax.set_ylabel(r"$N(\omega) / M$ (modes below $\omega$)")
    count_ax.legend(fontsize="small", loc="upper left")
    pr_ax.set_xlabel(r"$\omega$")
    pr_ax.set_ylabel("participation ratio")
    pr_ax.set_ylim(0.0, 1.0)
    if title:
        fig.suptitle(title)
    return fig


def _cumulative(
    values: NDArray[np.float64], per: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]]:
    """``values`` sorted, the count at or below each over ``per``, and the indices of ~300 of
    them spread evenly in log (the points a log-log plot draws)."""
    x = np.sort(values)
    count = np.arange(1, x.size + 1) / per
    return x, count, np.unique(np.geomspace(1, x.size, 300).astype(int)) - 1


def criticality_figure(
    samples: Sequence[WeakForcesAndGaps], exponents: CriticalExponents, *, title: str = ""
) -> Figure:
    """The cumulative distributions of the pooled weak forces (extended and localized, left) and
    gaps (right) against ``f / <f>`` and ``h`` on log-log axes, as counts per non-rattler: the
    fitted windows shaded, each fit (solid, over its window) and the mean-field slopes
    ``1 + theta_e`` and ``1 - gamma`` (dotted) through the fit's middle."""
    from ..certify.criticality import GAMMA, THETA_E

    live = sum(s.n_live for s in samples)
    forces = np.concatenate([s.forces for s in samples])
    localized = np.concatenate([s.localized for s in samples])
    gaps = np.concatenate([s.gaps for s in samples])
    fig = new_figure(10.0, 4.2)
    force_ax, gap_ax = fig.subplots(1, 2)
    curves = (
        (force_ax, forces[~localized], exponents.extended, "extended", 1.0 + THETA_E, "theta_e"),
        (force_ax, forces[localized], exponents.localized, "localized (bucklers)", None, ""),
        (gap_ax, gaps, exponents.gap, "gaps", 1.0 - GAMMA, "gamma"),
    )
    for ax, values, fit, label, mean_field, name in curves:
        x, count, shown = _cumulative(values, live)
        exponent = fit.a - 1.0 if name != "gamma" else 1.0 - fit.a
        symbol = {"theta_e": r"\theta_e", "gamma": r"\gamma", "": r"\theta_l"}[name]
        (line,) = ax.loglog(
            x[shown],
            count[shown],
            ".",
            markersize=3,
            label=f"{label}: ${symbol}$ = {exponent:.3f} ± {fit.stderr:.3f}",
        )
        low, high = fit.window
        middle = np.sqrt(low * high)
        at_middle = float(np.interp(np.log(middle), np.log(x), np.log(count)))
        grid = np.geomspace(low, high, 20)
        ax.loglog(grid, np.exp(at_middle) * (grid / middle) ** fit.a, "-", color=line.get_color())
        if mean_field is not None:
            ax.loglog(
                grid,
                np.exp(at_middle) * (grid / middle) ** mean_field,
                ":",
                color="black",
                label=f"mean field, slope {mean_field:.4f}",
            )
        ax.axvspan(low, high, color=line.get_color(), alpha=0.06)
    force_ax.set_xlabel(r"$f / \langle f \rangle$")
    force_ax.set_ylabel("contacts below, per non-rattler")
    gap_ax.set_xlabel(r"$h = r_{ij} / (r_i + r_j) - 1$")
    gap_ax.set_ylabel("gaps below, per non-rattler")
    for ax in (force_ax, gap_ax):
        ax.legend(fontsize="small", loc="upper left")
    fig.suptitle(title or f"{exponents.packings} packings, {live} non-rattlers")
    return fig


def gap_exponent_figure(
    series: Mapping[str, Sequence[WeakForcesAndGaps]],
    window: tuple[float, float],
    *,
    per_decade: int = 2,
    title: str = "",
) -> Figure:
    """For each label's pooled packings, the cumulative distribution of the gaps per
    non-rattler (left, log-log) and the local exponent ``gamma`` fitted over windows of
    ``1 / per_decade`` decade across ``window``
    (:func:`~athermal.certify.criticality.local_exponents`) with its standard error, against
    the window's centre (middle) and against the gaps a packing holds in the window (right,
    the variable of finite size: ``docs/criticality.md``), the mean-field ``gamma`` dotted."""
    from ..certify.criticality import GAMMA, local_exponents

    fig = new_figure(14.0, 4.2)
    count_ax, local_ax, size_ax = fig.subplots(1, 3)
    for k, (label, samples) in enumerate(series.items()):
        gaps, count, shown = _cumulative(
            np.concatenate([s.gaps for s in samples]), sum(s.n_live for s in samples)
        )
        (line,) = count_ax.loglog(gaps[shown], count[shown], ".", markersize=3, label=label)
        fits = local_exponents(gaps, window, per_decade)
        centre = np.array([np.sqrt(f.window[0] * f.window[1]) for f in fits])
        shift = 10.0 ** (0.03 * (k - (len(series) - 1) / 2))  # keep the error bars apart
        held = np.array([f.points for f in fits]) / len(samples)
        for ax, x in ((local_ax, centre * shift), (size_ax, held)):
            ax.errorbar(
                x,
                [1.0 - f.a for f in fits],
                yerr=[f.stderr for f in fits],
                fmt="o-",
                markersize=4,
                capsize=2,
                color=line.get_color(),
                label=label,
            )
    count_ax.axvspan(*window, color="grey", alpha=0.06)
    for ax in (local_ax, size_ax):
        ax.set_xscale("log")
        ax.axhline(GAMMA, color="black", linestyle=":", label=f"mean field {GAMMA}")
        ax.set_ylabel(rf"$\gamma$ over {1 / per_decade:g} decade")
    count_ax.set_xlabel(r"$h = r_{ij} / (r_i + r_j) - 1$")
    count_ax.set_ylabel("gaps below, per non-rattler")
    local_ax.set_xlabel(r"$h$ (centre of the window)")
    size_ax.set_xlabel("gaps in the window, per packing")
    count_ax.legend(fontsize="small", loc="upper left")
    size_ax.legend(fontsize="small", loc="lower right")
    if title:
        fig.suptitle(title)
    return fig


def _drops(ax: Axes, sizes: Mapping[str, Sequence[float]], xlabel: str) -> None:
    """Log-binned densities of each label's sizes, with the fitted power law with cutoff
    (:func:`~athermal.analysis.avalanches.power_law_tail`) dashed and its exponent labelled."""
    from ..analysis.avalanches import log_binned, power_law_tail

    for k, (label, values) in enumerate(sizes.items()):
        centres, density, _ = log_binned(values)
        seen = density > 0
        fit = power_law_tail(values)
        text = label if fit is None else rf"{label}: $\tau$ = {fit.exponent:.2f} ± {fit.stderr:.2f}"
        marker = "os^Dv"[(k // 10) % 5]  # a new marker each time the ten colours come round
        (line,) = ax.loglog(centres[seen], density[seen], marker, markersize=3, label=text)
        if fit is not None:
            s = np.logspace(np.log10(fit.s_min), np.log10(max(values)), 50)
            ax.loglog(s, fit.density(s), "--", color=line.get_color(), linewidth=1.0)
    from matplotlib.ticker import NullFormatter

    ax.xaxis.set_minor_formatter(NullFormatter())  # labelled minor ticks crowd a short range
    ax.set_xlabel(xlabel)
    ax.set_ylabel("probability density")
    if sizes:
        ax.legend(fontsize="small", loc="lower left")  # below the falling densities


def events_figure(
    curve: Mapping[str, Sequence[float]],
    events: Mapping[str, Sequence[float]],
    *,
    title: str = "",
) -> Figure:
    """An AQS run with exact plastic events: the driven stress against strain (``curve``:
    ``strain``, ``tau``) with each event marked where it starts (``events``: ``strain``,
    ``tau_before``, ``stress_drop``, ``energy_drop``), and the distributions of the stress and
    energy drops (log bins, fitted power law with cutoff dashed)."""
    fig = new_figure(12.0, 3.8)
    stress, drops, energy = fig.subplots(1, 3)
    stress.plot(curve["strain"], curve["tau"], "-", linewidth=0.8)
    stress.plot(events["strain"], events["tau_before"], "v", markersize=3, label="events")
    stress.set_xlabel(r"strain $\gamma$")
    stress.set_ylabel(r"driven stress $\tau$ " + STRESS_UNITS)
    stress.legend(fontsize="small")
    _drops(drops, {"events": events["stress_drop"]}, r"stress drop $\Delta\tau$ " + STRESS_UNITS)
    _drops(energy, {"events": events["energy_drop"]}, r"energy drop $\Delta E$ ($k\,\ell^\alpha$)")
    if title:
        fig.suptitle(title)
    return fig


def avalanche_figure(
    drops: Mapping[str, Mapping[str, Sequence[float]]], *, title: str = ""
) -> Figure:
    """The stress and energy drops of several ensembles (label -> ``stress_drop``,
    ``energy_drop``, in the particles' units as
    :func:`~athermal.studies.avalanches.pooled_drops` gives them): their densities in log bins
    with their fitted power laws."""
    fig = new_figure(9.0, 3.8)
    stress, energy = fig.subplots(1, 2)
    stress_label = r"stress drop $\Delta\tau$ ($k\,d^{\alpha-d}$, $d$ the mean diameter)"
    energy_label = r"energy drop $\Delta E$ ($k\,d^{\alpha}$)"
    _drops(stress, {k: v["stress_drop"] for k, v in drops.items()}, stress_label)
    _drops(energy, {k: v["energy_drop"] for k, v in drops.items()}, energy_label)
    if title:
        fig.suptitle(title)
    return fig


def yielding_figure(
    sweeps: Mapping[str, Sequence[Mapping[str, Any]]], *, title: str = ""
) -> Figure:
    """Cyclic shear against its amplitude, one line per sweep (label -> the rows of
    :func:`~athermal.studies.avalanches.yielding`'s ``amplitudes``): the fraction of packings
    that reached a limit cycle, and the cycles it took them (mean and standard error)."""
    fig = new_figure(9.0, 3.6)
    fraction, cycles = fig.subplots(1, 2)
    for label, rows in sweeps.items():
        amplitude = [r["amplitude"] for r in rows]
        (line,) = fraction.plot(amplitude, [r["fraction_reached"] for r in rows], "o-", label=label)
        reached = [r for r in rows if r["fraction_reached"] > 0.0]
        cycles.errorbar(
            [r["amplitude"] for r in reached],
            [r["cycles_to_reach"] for r in reached],
            yerr=[r["cycles_to_reach_stderr"] for r in reached],
            fmt="o-",
            capsize=2,
            color=line.get_color(),
            label=label,
        )
    fraction.set_xlabel("amplitude A")
    fraction.set_ylabel("fraction reaching a limit cycle")
    fraction.set_ylim(-0.05, 1.05)
    cycles.set_xlabel("amplitude A")
    cycles.set_ylabel("cycles to reach it")
    fraction.legend(fontsize="small")
    if title:
        fig.suptitle(title)
    return fig
