"""The analysis subcommand ``modes``: vibrational modes of a configuration."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ..io import read_gsd
from ..modes import plateau_edge, save_modes, vibrational_modes
from ..plot import modes_figure, save
from .common import model_from
from .printer import emit


def modes(args: argparse.Namespace) -> None:
    """``athermal modes``: eigenpairs of the stiffness matrix, D(omega), omega*."""
    t0 = time.perf_counter()
    frame = read_gsd(args.input, frame=args.frame)
    model = model_from(args, frame.model)
    found = vibrational_modes(frame.packing, model, args.lowest, vectors=args.vectors)
    save_modes(args.output, found, seed=args.seed)
    omega = found.frequencies
    edge = plateau_edge(omega, seed=args.seed) if found.complete else None
    out = {
        "n": frame.packing.n,
        "dim": frame.packing.dim,
        "dofs": found.dofs,
        "n_rattlers": found.n_rattlers,
        "modes": int(found.eigenvalues.size),
        "zero_modes": found.zero_modes,
        "negative_modes": found.negative_modes,
        "lowest_eigenvalue": float(found.eigenvalues[0]),
        "lowest_frequency": float(omega[0]) if omega.size else None,
        "omega_star": edge.omega_star if edge else None,
        "omega_star_err": edge.error if edge else None,
        "omega_star_modes": edge.modes_below if edge else None,
        "plateau_density": edge.plateau if edge else None,
        "seed": args.seed,
        "mean_participation": float(np.mean(found.participation)),
        "output": args.output,
    }
    if args.figure != "none" and found.complete:
        picture = Path(args.figure or Path(args.output).with_suffix(".png"))
        title = f"{Path(args.input).name}, frame {args.frame}: N = {frame.packing.n}"
        spectra = {f"phi = {frame.packing.phi:.6f}": found}
        save(modes_figure(spectra, title=title, seed=args.seed), picture)
        out["figure"] = str(picture)
    out["seconds"] = round(time.perf_counter() - t0, 3)
    emit(out, args.json)
