"""Figures: force-line widths and scale, rattler marking, panels, legends, ticks, PNG output,
the construction of omega* on the spectra figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import EllipseCollection, LineCollection
from matplotlib.figure import Figure

import athermal
from athermal.analysis.fitting import fit_power_law
from athermal.analysis.observables import rattlers
from athermal.errors import InputError
from athermal.studies import picture, plot

MODEL = athermal.ContactModel()


@pytest.fixture(scope="module")
def jammed() -> athermal.Packing:
    """A small packing above jamming, relaxed so its contact forces are balanced."""
    start = athermal.random_packing(64, 0.9, seed=1)
    return athermal.relax(start, MODEL).packing


@pytest.fixture(scope="module")
def unjammed(jammed: athermal.Packing) -> athermal.Packing:
    """``jammed`` with its radii shrunk until only residual overlaps (forces < 1e-8) remain."""
    c = athermal.find_contacts(jammed, MODEL)
    shrink = float(np.min(c.distance / (jammed.radii[c.i] + jammed.radii[c.j]))) * (1 + 1e-9)
    packing = jammed.scale_radii(shrink)
    force = athermal.find_contacts(packing, MODEL).force_magnitude
    assert force.size and force.max() < 1e-8
    return packing


@pytest.fixture(scope="module")
def partial() -> athermal.Packing:
    """An unrelaxed packing: a few force-bearing clusters among many rattlers."""
    return athermal.random_packing(64, 0.8, seed=3)


def _forces(fig: Figure) -> list[LineCollection]:
    return [c for ax in fig.axes for c in ax.collections if c.get_gid() == "forces"]


def _widths(fig: Figure) -> np.ndarray:
    lines = _forces(fig)
    return np.concatenate([c.get_linewidths() for c in lines]) if lines else np.zeros(0)


def _legend_texts(fig: Figure) -> list[str]:
    legends = [ax.get_legend() for ax in fig.axes] + list(fig.legends)
    return [t.get_text() for legend in legends if legend is not None for t in legend.get_texts()]


def _png(fig: Figure, path: Path) -> None:
    out = plot.save(fig, path)
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    assert not list(path.parent.glob(".*"))  # no temporary left behind


def test_force_widths_capped_and_keyed(jammed: athermal.Packing, tmp_path: Path) -> None:
    fig = picture.packing_figure(jammed, MODEL)
    widths = _widths(fig)
    cap = picture.max_force_width(jammed.n)
    assert cap == picture.MAX_FORCE_WIDTH
    assert widths.size and widths.max() <= cap + 1e-12
    assert widths.max() == pytest.approx(cap)  # the largest force sets the default scale
    assert widths.min() >= picture.MIN_FORCE_WIDTH
    fmax = athermal.find_contacts(jammed, MODEL).force_magnitude.max()
    assert any(f"$f$ = {fmax:.2e}" in t for t in _legend_texts(fig))
    _png(fig, tmp_path / "jammed.png")


def test_force_scale_clips_and_large_n_is_thinner(jammed: athermal.Packing) -> None:
    fmax = athermal.find_contacts(jammed, MODEL).force_magnitude.max()
    widths = _widths(picture.packing_figure(jammed, MODEL, force_scale=fmax / 10))
    assert widths.max() == pytest.approx(picture.MAX_FORCE_WIDTH)  # clipped, not 10x wider
    assert picture.max_force_width(4096) == pytest.approx(picture.MAX_FORCE_WIDTH / 2)
    with pytest.raises(InputError, match="force_scale"):
        picture.packing_figure(jammed, MODEL, force_scale=0.0)


def test_shared_scale_hides_residual_forces(
    jammed: athermal.Packing, unjammed: athermal.Packing
) -> None:
    fmax = athermal.find_contacts(jammed, MODEL).force_magnitude.max()
    assert np.all(_widths(picture.packing_figure(unjammed, MODEL, force_scale=fmax)) < 0.05)
    # on its own scale the same residual forces would be drawn at full width
    assert _widths(picture.packing_figure(unjammed, MODEL)).max() == pytest.approx(
        picture.MAX_FORCE_WIDTH
    )


@pytest.mark.parametrize("which", ["jammed", "unjammed", "partial"])
def test_rattlers_marked(which: str, request: pytest.FixtureRequest) -> None:
    packing: athermal.Packing = request.getfixturevalue(which)
    expected = int(rattlers(athermal.find_contacts(packing, MODEL), packing.n, 2).sum())
    expected = 0 if expected == packing.n else expected  # no network: nothing is marked
    fig = picture.packing_figure(packing, MODEL)
    marked = [c for c in fig.axes[0].collections if c.get_gid() == "rattlers"]
    texts = [t for t in _legend_texts(fig) if t.startswith("rattler")]
    if expected:
        assert texts == [f"rattler ({expected})"]
        assert isinstance(marked[0], EllipseCollection)
        # the marked disks, folded back into the cell, are exactly the rattlers' centres
        frac = packing.cell.wrap(marked[0].get_offsets()) @ np.linalg.inv(packing.cell.h).T
        keys = {tuple(np.round(f, 9)) for f in frac}
        assert len(keys) == expected
    else:
        assert not texts and not marked
    if which == "partial":
        assert 0 < expected < packing.n  # the case exercises both disk kinds


def test_packing_into_given_axes(jammed: athermal.Packing) -> None:
    fig = Figure()
    ax = fig.add_subplot(1, 2, 2)
    assert picture.packing_figure(jammed, MODEL, ax=ax, title="panel") is fig
    assert ax.get_title() == "panel" and len(fig.axes) == 1
    with pytest.raises(InputError, match="2D"):
        picture.packing_figure(athermal.random_packing(8, 0.3, dim=3, seed=0))


def test_jamming_figure_panels_share_scale(
    jammed: athermal.Packing, unjammed: athermal.Packing, partial: athermal.Packing, tmp_path: Path
) -> None:
    snapshots = [("initial", partial), ("unjammed", unjammed), ("jammed", jammed)]
    fig = picture.jamming_figure(snapshots, MODEL, title="N = 64")
    assert [ax.get_title() for ax in fig.axes] == ["(a) initial", "(b) unjammed", "(c) jammed"]
    shared = max(athermal.find_contacts(p, MODEL).force_magnitude.max() for _, p in snapshots)
    keys = [t for t in _legend_texts(fig) if t.startswith("contact force")]
    assert keys == [  # one key for the figure, saying what the line stands for
        rf"contact force (width $\propto f$; this line: $f$ = {shared:.2e} $k\,\ell^{{\alpha-1}}$)"
    ]
    assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
    per_panel = [[c for c in ax.collections if c.get_gid() == "forces"] for ax in fig.axes]
    assert not per_panel[1]  # residual forces invisible on the shared scale
    cap = max(float(np.max(c.get_linewidths())) for panel in per_panel for c in panel)
    assert cap <= picture.max_force_width(64, 4.0) + 1e-12
    _png(fig, tmp_path / "jamming.png")


def test_convergence_tolerance_line(tmp_path: Path) -> None:
    history = np.geomspace(1.0, 1e-12, 40)
    fig = plot.convergence_figure({"lbfgs": history}, title="alpha = 2, N = 64", tolerance=1e-10)
    ax = fig.axes[0]
    tol = [line for line in ax.get_lines() if line.get_label() == "tolerance"]
    assert len(tol) == 1 and np.allclose(tol[0].get_ydata(), 1e-10)
    assert tol[0].get_linestyle() == "--"
    assert r"\alpha-1" in ax.get_ylabel()
    assert not [
        ln
        for ln in plot.convergence_figure({"x": history}).axes[0].get_lines()
        if ln.get_label() == "tolerance"
    ]
    _png(fig, tmp_path / "convergence.png")


def test_scaling_reference_and_window(tmp_path: Path) -> None:
    x = np.geomspace(1e-6, 1e-1, 12)
    y = 2.0 * x**1.1
    fit = fit_power_law(x, y, lower=1e-5, upper=1e-2)
    args = ({"alpha = 2": x}, {"alpha = 2": y}, {"alpha = 2": fit})
    fig = plot.scaling_figure(
        *args, ylabel=r"$p$ ($k\,\ell^{\alpha-d}$)", reference_slopes={"alpha = 2": 1.0}
    )
    ax = fig.axes[0]
    refs = [line for line in ax.get_lines() if line.get_gid() == "reference"]
    assert len(refs) == 1 and "slope 1 (expected" in str(refs[0].get_label())
    rx, ry = refs[0].get_xdata(), refs[0].get_ydata()
    slope = np.log(ry[-1] / ry[0]) / np.log(rx[-1] / rx[0])
    assert slope == pytest.approx(1.0)
    assert len(ax.patches) == 1  # the shaded fit window
    x0, x1 = ax.patches[0].get_extents().x0, ax.patches[0].get_extents().x1
    assert x0 < x1
    assert ax.get_xlabel().startswith(r"$\phi - \phi_c$")
    assert "jamming protocol" in ax.get_xlabel()
    plain = plot.scaling_figure(*args, ylabel="p", phi_c_note="ensemble mean")
    assert not [ln for ln in plain.axes[0].get_lines() if ln.get_gid() == "reference"]
    assert "ensemble mean" in plain.axes[0].get_xlabel()
    _png(fig, tmp_path / "scaling.png")


def test_iterations_error_kinds(tmp_path: Path) -> None:
    counts = {"lbfgs": [[10.0, 12.0, 14.0, 16.0], [30.0, 34.0, 38.0, 42.0]]}
    bars = {}
    for error in ("sd", "stderr"):
        fig = plot.iterations_figure([1e-4, 1e-2], counts, error=error)
        ax = fig.axes[0]
        assert f"mean ± {error}" in ax.get_ylabel()
        segments = ax.collections[0].get_segments()
        bars[error] = np.array([s[1, 1] - s[0, 1] for s in segments]) / 2
    sd = np.std([10.0, 12.0, 14.0, 16.0], ddof=1)
    assert bars["sd"][0] == pytest.approx(sd)
    assert np.allclose(bars["stderr"], bars["sd"] / 2)  # sqrt(4 realizations)
    ticks = [t for t in ax.get_yticks() if ax.get_ylim()[0] <= t <= ax.get_ylim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks)
    with pytest.raises(InputError, match="error"):
        plot.iterations_figure([1e-4], {"a": [[1.0]]}, error="var")
    _png(fig, tmp_path / "iterations.png")
    # a realization unjammed at a Delta phi (NaN) is left out of that point
    unjammed = {"lbfgs": [[10.0, 12.0, np.nan, 14.0], [30.0, 34.0, 38.0, 42.0]]}
    line = plot.iterations_figure([1e-4, 1e-2], unjammed).axes[0].lines[0]
    assert line.get_ydata()[0] == pytest.approx(12.0)


def test_shear_grid_single_legend(tmp_path: Path) -> None:
    strain = np.linspace(0.0, 0.02, 11)
    curves = {
        f"step {d:g}": {
            "strain": strain,
            "stress_iso": 1e-3 + 0.01 * strain,
            "stress_dev": 1e-4 * np.sin(200 * strain),
            "fabric_iso": 2.0 + strain,
            "fabric_dev": 0.01 * strain,
        }
        for d in (1e-3, 1e-4)
    }
    fig = plot.shear_figure(curves, title="pure shear")
    assert len(fig.axes) == 4
    assert all(len(ax.get_lines()) == 2 for ax in fig.axes)
    assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
    assert _legend_texts(fig) == ["step 0.001", "step 0.0001"]
    ylabels = [ax.get_ylabel() for ax in fig.axes]
    assert all(r"\alpha-d" in label for label in ylabels[:2])
    assert all("strain" in ax.get_xlabel() for ax in fig.axes[2:])
    _png(fig, tmp_path / "shear.png")
    offset = fig.axes[1].yaxis.get_offset_text().get_text()
    assert "10^{" in offset and "4}" in offset  # scientific notation on the deviatoric stress


def _integer_ticks(fig: Figure) -> bool:
    return all(
        float(t).is_integer() for ax in fig.axes if ax.get_visible() for t in ax.get_yticks()
    )


def test_histogram_integer_ticks_mean_sd(tmp_path: Path) -> None:
    values = [0.8401, 0.8412, 0.8398, 0.8405, 0.8420, 0.8391]
    fig = plot.histogram_figure(values, xlabel=r"$\phi_c$")
    assert _integer_ticks(fig)
    (text,) = _legend_texts(fig)
    assert text.startswith("mean ± sd") and f"{np.mean(values):.5g}" in text
    assert f"{np.std(values, ddof=1):.2g}" in text
    _png(fig, tmp_path / "histogram.png")


def test_summary_panels(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    panels = {
        r"$\phi_c$": list(0.84 + 1e-3 * rng.standard_normal(7)),
        r"$z - z_{iso}$": list(rng.standard_normal(7)),
        r"$p / \epsilon^{\alpha-1}$ ($k\,\ell^{\alpha-d}$)": list(rng.random(7)),
        "G": list(rng.random(7)),
    }
    fig = plot.summary_figure(panels, title="ensemble")
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_xlabel() for ax in visible] == list(panels)
    assert all(ax.get_ylabel() == "realizations" for ax in visible)
    assert _integer_ticks(fig)
    assert sum(t.startswith("mean ± sd") for t in _legend_texts(fig)) == 4
    with pytest.raises(InputError):
        plot.summary_figure({})
    _png(fig, tmp_path / "summary.png")


def test_modes_figure_draws_what_decided_omega_star(tmp_path: Path) -> None:
    from athermal.analysis.modes import Modes, plateau_edge

    u = (np.arange(1000) + 0.5) / 1000  # D ~ omega up to 0.1, then flat up to 2
    omega = np.where(u < 0.05 / 1.95, np.sqrt(0.39 * u), 1.95 * u + 0.05)
    values = np.concatenate([[0.0, 0.0], omega**2])  # and two translations
    modes = Modes(
        eigenvalues=values,
        vectors=np.zeros((0, 501, 2)),
        vector_index=np.zeros(0, np.intp),
        participation=np.full(values.size, 0.5),
        n_rattlers=0,
        dofs=values.size,
        tolerance=1e-12,
        complete=True,
    )
    edge = plateau_edge(omega)
    fig = plot.modes_figure({"known edge": modes})
    dos_ax, count_ax, _ = fig.axes
    for ax in (dos_ax, count_ax):  # omega* as a vertical line, its error as a band
        assert any(np.allclose(line.get_xdata(), edge.omega_star) for line in ax.get_lines())
        (band,) = ax.patches
        assert band.get_x() == pytest.approx(edge.omega_star - edge.error)
        assert band.get_x() + band.get_width() == pytest.approx(edge.omega_star + edge.error)
    # the count, the plateau's line D_p omega and half of it, crossing the count at omega*
    slopes = {
        round(float(np.median(line.get_ydata() / line.get_xdata())) / edge.plateau, 3)
        for line in count_ax.get_lines()[1:3]
    }
    assert slopes == {1.0, 0.5}
    crossing = [edge.omega_star, edge.plateau * edge.omega_star / 2]
    assert any(np.allclose(line.get_xydata(), [crossing]) for line in count_ax.get_lines())
    assert f"{edge.omega_star:.3g} $\\pm$ {edge.error:.2g}" in _legend_texts(fig)[0]
    assert f"{edge.modes_below} of 1000 modes below" in _legend_texts(fig)[1]
    _png(fig, tmp_path / "modes.png")


def test_gap_exponent_figure_draws_each_local_fit(tmp_path: Path) -> None:
    from athermal.certify.criticality import GAMMA, WeakForcesAndGaps, local_exponents

    rng = np.random.default_rng(3)

    def sample(size: int) -> WeakForcesAndGaps:
        gaps = (1e-6**0.6 + rng.uniform(size=size) * (1e-1**0.6 - 1e-6**0.6)) ** (1 / 0.6)
        return WeakForcesAndGaps(
            forces=np.ones(3),
            localized=np.zeros(3, bool),
            gaps=gaps,
            gap_localized=np.zeros(size, bool),
            n_live=2 * size,
            bucklers=0,
            touching=0,
            jamming_strain=0.0,
        )

    series = {"small": [sample(3000), sample(3000)], "large": [sample(20000)]}
    fig = plot.gap_exponent_figure(series, (1e-6, 1e-1), per_decade=1)
    count_ax, local_ax, size_ax = fig.axes
    for k, samples in enumerate(series.values()):
        gaps = np.concatenate([s.gaps for s in samples])
        fits = local_exponents(gaps, (1e-6, 1e-1), 1)
        for ax in (local_ax, size_ax):
            drawn = ax.containers[k].lines[0]  # the errorbar's line through its points
            y = np.asarray(drawn.get_ydata(), float)
            np.testing.assert_allclose(y, [1 - f.a for f in fits])
        held = np.asarray(size_ax.containers[k].lines[0].get_xdata(), float)
        np.testing.assert_allclose(held, [f.points / len(samples) for f in fits])
        y = count_ax.get_lines()[k].get_ydata()  # per non-rattler: half of each gap count
        assert y[-1] == pytest.approx(gaps.size / sum(s.n_live for s in samples))
    for ax in (local_ax, size_ax):
        dotted = [line for line in ax.get_lines() if line.get_linestyle() == ":"]
        assert len(dotted) == 1 and np.allclose(np.asarray(dotted[0].get_ydata(), float), GAMMA)
    assert "small" in _legend_texts(fig)
    _png(fig, tmp_path / "gaps.png")
