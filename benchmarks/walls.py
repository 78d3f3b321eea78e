"""Packings jammed between flat walls: the boundary layer the paper's periodic cell avoids.

For each seed a bidisperse packing of N disks is jammed
(:func:`athermal.studies.experiments.jam_packing`,
the defaults: ``ohern``, epsilon = 1e-6) in the unit cell with walls normal to y, and, for the
reference, in the periodic unit cell from the same seed. Reported:

* the packing-fraction profile ``phi(h)`` against the distance ``h`` from the nearer wall, in
  mean diameters: each disk's exact area inside each slab of width ``--slab`` (circle-slab
  intersections), summed over the packings and both walls, over the slabs' area;
* ``phi_c`` between walls and periodic, and the interior's packing fraction (``h`` > 5 mean
  diameters);
* the checks: every packing passes ``jam``'s checks, its ``N_c - N_iso`` with
  ``N_iso = d N' - t + 1`` (``t`` = 1 periodic axis), and the force per unit length on each
  wall against ``sigma_yy``.

Run from the repository root::

    python -m benchmarks.walls                 # N = 1024, 20 seeds (~3 min)
    python -m benchmarks.walls --quick         # N = 256, 4 seeds

Results: ``benchmarks/results/walls.md`` and ``walls.json``; figure
``docs/figures/walls_profile.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from athermal.analysis.observables import stress
from athermal.model.contact import find_contacts
from athermal.model.walls import wall_pressures
from athermal.studies.experiments import JamSpec, jam_packing
from benchmarks.machine import ROOT, pin, save

INTERIOR = 5.0
"""Slabs farther than this many mean diameters from both walls are the interior."""


def below(t: NDArray[np.float64], r: NDArray[np.float64]) -> NDArray[np.float64]:
    """Area of a disk of radius ``r`` below the line ``t`` above its centre (``t`` clipped to
    ``[-r, r]``)."""
    s = np.clip(t, -r, r)
    return s * np.sqrt(r * r - s * s) + r * r * np.arcsin(s / r) + 0.5 * np.pi * r * r


def profile(
    y: NDArray[np.float64], r: NDArray[np.float64], gap: float, slab: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Disk area ``(S,)`` in slabs of width ``slab`` at distance ``h`` from the lower wall
    (``y = -gap / 2``) and from the upper one, folded together, and the slabs' lower edges."""
    edges = np.arange(0.0, 0.5 * gap, slab)
    area = np.zeros(edges.size)
    for distance in (y + 0.5 * gap, 0.5 * gap - y):  # from each wall
        for k, h in enumerate(edges):
            area[k] += float((below(h + slab - distance, r) - below(h - distance, r)).sum())
    return area, edges


def one(n: int, seed: int, slab_diameters: float) -> dict[str, Any]:
    """Jam one packing between walls and one periodic; the rows and the profile."""
    rows: dict[str, Any] = {"seed": seed}
    for walls in ("y", ""):
        spec = JamSpec(n=n, walls=walls)
        t0 = time.perf_counter()
        result = jam_packing(spec, seed)
        seconds = time.perf_counter() - t0
        key = "walls" if walls else "periodic"
        rows[key] = {
            "phi_c": result.phi_c,
            "passed": result.check.passed,
            "excess_contacts": result.check.excess_contacts,
            "z": result.observables.z,
            "n_rattlers": result.observables.n_rattlers,
            "seconds": seconds,
        }
        if walls:
            p = result.packing
            contacts = find_contacts(p, spec.model)
            sigma = stress(contacts, p.cell)
            on_walls = wall_pressures(contacts.walls, p.cell)
            rows[key]["wall_pressure"] = on_walls
            rows[key]["sigma_yy"] = float(sigma[1, 1])
            rows[key]["wall_vs_sigma"] = max(abs(v / sigma[1, 1] - 1.0) for v in on_walls.values())
            diameter = 2.0 * float(p.radii.mean())
            area, edges = profile(
                p.positions[:, 1], p.radii, p.cell.h[1, 1], slab_diameters * diameter
            )
            rows["profile"] = {
                "h": (edges / diameter).tolist(),
                "area": area.tolist(),
                "slab_area": 2.0 * p.cell.h[0, 0] * slab_diameters * diameter,
            }
    return rows


def figure(h: NDArray[np.float64], phi: NDArray[np.float64], phi_c: float, path: Any) -> None:
    """``phi(h)`` against the distance from the wall, with the periodic ``phi_c``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6), constrained_layout=True)
    ax.plot(h, phi, color="tab:blue", linewidth=1.2, label="between walls (slabs)")
    ax.axhline(phi_c, color="0.3", linestyle="--", linewidth=1.0, label="periodic $\\phi_c$")
    ax.set_xlabel("distance from the wall $h$ (mean diameters)")
    ax.set_ylabel("local packing fraction $\\phi(h)$")
    ax.set_xlim(0.0, 8.0)
    ax.legend(loc="lower right", frameon=False)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1024)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--slab", type=float, default=0.05, help="slab width, mean diameters")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--figure-dir", type=Path, default=ROOT / "docs" / "figures")
    args = parser.parse_args()
    n, seeds = (256, 4) if args.quick else (args.n, args.seeds)
    pinned = pin(args.core)
    jam_packing(JamSpec(n=64, walls="y"), 0)  # compile first
    rows = [one(n, seed, args.slab) for seed in range(1, seeds + 1)]
    length = min(len(r["profile"]["area"]) for r in rows)
    area = np.sum([r["profile"]["area"][:length] for r in rows], axis=0)
    phi = area / (len(rows) * rows[0]["profile"]["slab_area"])
    h = np.asarray(rows[0]["profile"]["h"][:length]) + 0.5 * args.slab
    interior = float(phi[h > INTERIOR].mean())
    walled = np.array([r["walls"]["phi_c"] for r in rows])
    periodic = np.array([r["periodic"]["phi_c"] for r in rows])
    error = np.sqrt(len(rows))
    summary = {
        "n": n,
        "seeds": len(rows),
        "phi_c_walls": [float(walled.mean()), float(walled.std(ddof=1) / error)],
        "phi_c_periodic": [float(periodic.mean()), float(periodic.std(ddof=1) / error)],
        "phi_interior": interior,
        "phi_first_layer": float(phi[h < 0.5].mean()),
        "all_passed": all(r[k]["passed"] for r in rows for k in ("walls", "periodic")),
        "excess_contacts_walls": sorted(int(r["walls"]["excess_contacts"]) for r in rows),
        "worst_wall_vs_sigma": max(r["walls"]["wall_vs_sigma"] for r in rows),
        "jam_seconds_walls": float(np.median([r["walls"]["seconds"] for r in rows])),
        "jam_seconds_periodic": float(np.median([r["periodic"]["seconds"] for r in rows])),
    }
    figure(h, phi, float(periodic.mean()), args.figure_dir / "walls_profile.png")
    lines = [
        "# Packings jammed between walls (benchmarks/walls.py)",
        "",
        f"N = {n} bidisperse disks, alpha = 2, epsilon = 1e-6, {len(rows)} seeds; walls normal "
        "to y in the unit cell, and the periodic unit cell from the same seeds.",
        "",
        "| quantity | between walls | periodic |",
        "|---|---|---|",
        f"| phi_c (mean ± s.e.) | {walled.mean():.5f} ± {walled.std(ddof=1) / error:.5f} | "
        f"{periodic.mean():.5f} ± {periodic.std(ddof=1) / error:.5f} |",
        f"| interior phi (h > {INTERIOR:g} diameters) | {interior:.5f} | |",
        f"| first layer phi (h < 0.5 diameter) | {summary['phi_first_layer']:.4f} | |",
        f"| every packing passes jam's checks | {summary['all_passed']} | |",
        f"| N_c - N_iso (N_iso = 2 N' - 1 + 1) | {summary['excess_contacts_walls']} | |",
        "| worst abs(wall force per length / sigma_yy - 1) | "
        f"{summary['worst_wall_vs_sigma']:.1e} | |",
        f"| jam time, median (s) | {summary['jam_seconds_walls']:.2f} | "
        f"{summary['jam_seconds_periodic']:.2f} |",
        "",
        "Profile phi(h), h the distance from the nearer wall in mean diameters (slab centres, "
        "every other slab to 3 diameters), both walls folded together:",
        "",
        "| h | phi |",
        "|---|---|",
        *(f"| {a:.3f} | {b:.4f} |" for a, b in zip(h[:60:2], phi[:60:2], strict=False)),
        "",
        "Figure: `docs/figures/walls_profile.png`.",
        "",
    ]
    for r in rows:  # each packing's slab areas are summed into the profile
        del r["profile"]
    data = {"summary": summary, "rows": rows, "profile": {"h": h.tolist(), "phi": phi.tolist()}}
    save(args.output_dir, "walls", {**data, "pinned": pinned}, "\n".join(lines))


if __name__ == "__main__":
    main()
