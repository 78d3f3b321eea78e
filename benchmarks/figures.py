"""The benchmark figures of the documentation site, drawn from the results files.

    python -m benchmarks.figures            # writes docs/figures/benchmarks-*.png

``table.png``: the Table (B1, ``results/table1.json``): seconds per case for each method, alpha 2
and 2.5, LAMMPS's ``min cg`` of the same run beside them. ``scale.png``: B4
(``results/scale.json``): iterations and seconds against N for P-L-BFGS, L-BFGS and FIRE. Each
figure's title names the machine and date of its results file; nothing is measured here.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import matplotlib.ticker

from benchmarks.machine import line

RESULTS = Path(__file__).resolve().parent / "results"
FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
TABLE_METHODS = {
    "FIRE": ("FIRE",),
    "L-BFGS": ("L-BFGS",),
    "FR-CG": ("FR-CG",),
    "P-L-BFGS": ("P-L-BFGS",),
    "P-FR-CG": ("P-FR-CG",),
    "Newton-CG": ("Newton-CG",),
    "LAMMPS min cg": ("LAMMPS min cg (harmonic/cut)", "LAMMPS min cg (lepton)"),
}
"""The Table's methods drawn, in this order, and their names in the results file (LAMMPS's pair
style is harmonic/cut at alpha = 2, lepton at 2.5; scipy's L-BFGS-B, the in-run reference, stops
by its own criterion before 1e-9 and is left out)."""
SCALE_METHODS = {"P-L-BFGS (direct)": "o-", "L-BFGS": "s--", "FIRE": "^:"}
"""B4's methods drawn, and their line styles."""


def _load(name: str) -> dict[str, Any]:
    with open(RESULTS / f"{name}.json") as file:
        return json.load(file)  # type: ignore[no-any-return]


def table_figure() -> plt.Figure:
    """Seconds per case and method, one panel per alpha."""
    data = _load("table1")
    rows = data["rows"]
    alphas = sorted({r["alpha"] for r in rows})
    fig, axes = plt.subplots(1, len(alphas), figsize=(11, 4.2), sharey=True)
    width = 0.8 / len(TABLE_METHODS)
    for ax, alpha in zip(axes, alphas, strict=True):
        for k, (label, names) in enumerate(TABLE_METHODS.items()):
            found = {r["case"]: r for r in rows if r["alpha"] == alpha and r["method"] in names}
            cases = sorted(found)
            seconds = [
                found[c]["seconds"] if found[c]["converged"] else float("nan") for c in cases
            ]
            offset = (k - len(TABLE_METHODS) / 2 + 0.5) * width
            ax.bar([c + offset for c in cases], seconds, width, color=f"C{k}", label=label)
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.set_xticks(sorted({r["case"] for r in rows}))
        ax.set_xlabel("case")
        ax.set_title(f"alpha = {alpha:g}")
    axes[0].set_ylabel("seconds to 1e-9 of the mean contact force")
    axes[0].legend(fontsize=7, loc="upper right", ncols=2)
    fig.suptitle(f"The paper's Table, N = 4096, one core\n{line(data['machine'])}", fontsize=8)
    fig.tight_layout()
    return fig


def scale_figure() -> plt.Figure:
    """Iterations and seconds against N."""
    data = _load("scale")
    rows = data["rows"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    for method, style in SCALE_METHODS.items():
        done = sorted(
            (r for r in rows if r["method"] == method and r["converged"]), key=lambda r: r["n"]
        )
        n = [r["n"] for r in done]
        left.loglog(n, [r["iterations"] for r in done], style, label=method)
        right.loglog(n, [r["seconds"] for r in done], style, label=method)
    left.set_ylabel("iterations")
    right.set_ylabel("seconds")
    for ax in (left, right):
        ax.set_xlabel("N")
        ax.legend(fontsize=8)
    fig.suptitle(
        f"B4, to 1e-9 of the mean contact force, one core\n{line(data['machine'])}", fontsize=8
    )
    fig.tight_layout()
    return fig


def main(argv: list[str] | None = None) -> int:
    """Draw the figures into ``--output-dir`` (default ``docs/figures``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output-dir", type=Path, default=FIGURES)
    args = parser.parse_args(argv)
    for name, draw in (("table", table_figure), ("scale", scale_figure)):
        fig = draw()
        fig.savefig(args.output_dir / f"benchmarks-{name}.png", dpi=110)
        plt.close(fig)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
