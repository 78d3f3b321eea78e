"""The analysis subcommands: ``modes`` (vibrational modes of a configuration), ``moduli`` (its
bulk and shear moduli) and ``certify`` (its force balance beyond float64)."""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np

from ..analysis.modes import plateau_edge, save_modes, vibrational_modes
from ..analysis.moduli import linear_response
from ..analysis.observables import measure
from ..certify import LOG_PREFIX, certify
from ..certify.criticality import (
    GAMMA,
    THETA_E,
    critical_exponents,
    local_exponents,
    weak_forces_and_gaps,
)
from ..errors import InputError
from ..io import count_frames, read_gsd, write_gsd
from ..model.contact import ContactModel
from ..model.objective import Objective
from ..model.packing import Packing
from ..protocols.finite_strain import finite_strain_bulk, finite_strain_shear
from ..protocols.jamming import energy_threshold
from ..relaxation import energy_scale
from ..studies.plot import criticality_figure, modes_figure, save
from .common import check_certified, model_from
from .printer import emit

MODES_BITS = "this machine's: LAPACK's and ARPACK's eigensolvers sum in their BLAS's order"
"""The ``bits`` of ``modes`` (docs/decisions.md, "Same input, same bits")."""
FAST_BITS = "this machine's: CHOLMOD factors on cvxopt's BLAS (--fast)"
"""The ``bits`` of ``certify --fast`` (``portable`` without it)."""


def modes(args: argparse.Namespace) -> None:
    """``athermal modes``: eigenpairs of the stiffness matrix, D(omega), omega*."""
    t0 = time.perf_counter()
    frame = read_gsd(args.input, frame=args.frame)
    model = model_from(args, frame.model)
    _warn_unless_relaxed(frame.packing, model, args.frame % count_frames(args.input), "modes")
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
        "bootstrap_seed": args.seed if edge else None,
        "mean_participation": float(np.mean(found.participation)),
        "bits": MODES_BITS,
        "output": args.output,
    }
    if args.figure != "none" and found.complete:
        picture = Path(args.figure or Path(args.output).with_suffix(".png"))
        index = args.frame % count_frames(args.input)  # as the file counts them, not -1
        title = f"{Path(args.input).name}, frame {index}: N = {frame.packing.n}"
        spectra = {f"phi = {frame.packing.phi:.6f}": found}
        save(modes_figure(spectra, title=title, seed=args.seed), picture)
        out["figure"] = str(picture)
    out["seconds"] = round(time.perf_counter() - t0, 3)
    emit(out, args.json)


FINITE_STEPS = 10
"""Quasi-static steps of ``moduli --finite-strain S``: strains ``S/10, 2S/10, ..., S`` (the
paper's 1e-6 to 1e-5 in 10 steps for ``S = 1e-5``)."""
FINITE_RTOL = 1e-12
"""Force tolerance of those steps, x the mean contact force (floored at round-off): tight
enough that a step of a small strain leaves its linear start (``docs/decisions.md``,
"Finite-strain moduli")."""


def moduli(args: argparse.Namespace) -> None:
    """``athermal moduli``: bulk and shear moduli of frames by exact linear response (and by
    quasi-static finite strain on request)."""
    t0 = time.perf_counter()
    count = count_frames(args.input)
    if count == 0:
        read_gsd(args.input)  # its one line: the file has no frames
    frames = range(count) if args.all_frames else [args.frame]
    rows = []
    for k in frames:
        frame = read_gsd(args.input, frame=k)  # refuses a frame the file has not
        model = model_from(args, frame.model)
        packing = frame.packing
        if args.finite_strain is not None and {0, 1} & set(packing.cell.walls):
            raise InputError(
                "--finite-strain: its simple shear would tilt the walls of this packing; "
                "between walls normal to x or y the shear modulus is the biaxial one (drop it)"
            )
        _warn_unless_relaxed(packing, model, k % count, "moduli")
        lr = linear_response(packing, model)
        logged = frame.log.get("delta_phi")
        p = measure(packing, model).pressure  # every contact, as compress's
        row: dict[str, object] = {
            "frame": k % count,
            "phi": packing.phi,
            "delta_phi": None if logged is None else float(logged),
            "pressure": p,
            "bulk": lr.bulk,
            # along growing radii, as compress's bulk_modulus: B + (alpha - d) p / d
            "bulk_phi": lr.bulk + (model.alpha - packing.dim) * p / packing.dim,
            "shear": lr.shear,
            "bulk_affine": lr.bulk_affine,
            "shear_affine": lr.shear_affine,
            "n_rattlers": lr.n_rattlers,
            "residual": lr.residual,
        }
        if args.finite_strain is not None:
            strains = (
                np.linspace(1.0, FINITE_STEPS, FINITE_STEPS) * args.finite_strain / FINITE_STEPS
            )
            shear = finite_strain_shear(packing, model, strains, rtol=FINITE_RTOL)
            bulk = finite_strain_bulk(packing, model, -strains, rtol=FINITE_RTOL)
            row |= {
                "shear_finite": shear.modulus,
                "shear_finite_err": shear.stderr,
                "bulk_finite": bulk.modulus,
                "bulk_finite_err": bulk.stderr,
            }
        rows.append(row)
    out = {
        "input": args.input,
        "frames": rows,
        "finite_strain": args.finite_strain,
        "seconds": round(time.perf_counter() - t0, 3),
    }
    emit(out, args.json)


UNRELAXED = 1e-6
""":func:`moduli` warns about a frame whose largest force exceeds this times its mean contact
force (linear response is exact at an energy minimum only)."""


def _warn_unless_relaxed(packing: Packing, model: ContactModel, index: int, what: str) -> None:
    """A warning when frame ``index`` is unjammed (its energy below the jamming protocol's
    threshold: ``what`` is zero up to round-off) or not at an energy minimum
    (:data:`UNRELAXED`)."""
    objective = Objective(packing, model)
    energy, grad = objective(objective.x0)
    threshold = (
        energy_threshold(packing.dim, model.alpha) * packing.n * energy_scale(packing.radii, model)
    )
    if energy <= threshold:
        warnings.warn(
            f"frame {index} is unjammed (E = {energy:.1e}, below the jamming threshold "
            f"{threshold:.1e}): it has no rigid contact network, and its {what} are those of "
            "round-off",
            stacklevel=2,
        )
        return
    mean = objective.mean_contact_force(objective.x0)
    largest = objective.max_gradient(grad)
    if largest > UNRELAXED * mean:
        warnings.warn(
            f"frame {index} is not relaxed (largest force {largest / mean:.1e} of the mean "
            f"contact force): its {what} assume an energy minimum; relax it first",
            stacklevel=2,
        )


def certify_file(args: argparse.Namespace) -> None:
    """``athermal certify``: a jammed packing refined in double-double, with its certificate."""
    t0 = time.perf_counter()
    frame = read_gsd(args.input, frame=args.frame)
    model = model_from(args, frame.model)
    done = certify(
        frame.packing, model, frame.position_lo, target=args.target, portable=not args.fast
    )
    kept = {k: v for k, v in frame.log.items() if not k.startswith(LOG_PREFIX)}
    write_gsd(
        args.output,
        done.packing,
        model=model,
        seed=frame.seed,
        observables={**kept, **done.certificate.log()},
        position_lo=done.position_lo,
    )
    out = {
        "input": args.input,
        "frame": args.frame % count_frames(args.input),
        **dataclasses.asdict(done.certificate),
        "output": args.output,
        "seconds": round(time.perf_counter() - t0, 3),
        "bits": FAST_BITS if args.fast else "portable",
    }
    emit(out, args.json)
    check_certified(done.certificate)


def criticality(args: argparse.Namespace) -> None:
    """``athermal criticality``: weak forces and small gaps pooled over files, their
    exponents."""
    t0 = time.perf_counter()
    samples, certified = [], 0
    for path in args.inputs:
        frame = read_gsd(path)
        model = model_from(args, frame.model)
        samples.append(weak_forces_and_gaps(frame.packing, model, frame.position_lo))
        certified += frame.position_lo is not None
    if certified < len(samples):
        warnings.warn(
            f"{len(samples) - certified} of {len(samples)} files are not certified (athermal "
            "certify): their smallest forces and gaps carry float64's round-off",
            stacklevel=1,
        )
    found = critical_exponents(samples, tuple(args.force_window), tuple(args.gap_window))
    out: dict[str, object] = {
        "packings": found.packings,
        "certified": certified,
        "non_rattlers": sum(s.n_live for s in samples),
        "bucklers": sum(s.bucklers for s in samples),
        "contacts": found.contacts,
        "localized_contacts": found.localized_contacts,
        "gaps": found.gaps,
        "touching": sum(s.touching for s in samples),
    }
    for name, fit, value, mean_field in (
        ("theta_e", found.extended, found.theta_e, THETA_E),
        ("theta_l", found.localized, found.theta_l, None),
        ("gamma", found.gap, found.gamma, GAMMA),
    ):
        out[name] = {
            "value": value,
            "stderr": fit.stderr,
            "points": fit.points,
            "window": list(fit.window),
            "mean_field": mean_field,
        }
    gaps = np.concatenate([s.gaps for s in samples])
    out["gamma_local"] = [
        {
            "window": list(fit.window),
            "value": 1.0 - fit.a,
            "stderr": fit.stderr,
            "points": fit.points,
            "per_packing": fit.points / len(samples),
        }
        for fit in local_exponents(gaps, found.gap.window, per_decade=1)
    ]
    if args.figure is not None:
        save(criticality_figure(samples, found), args.figure)
        out["figure"] = args.figure
    out["seconds"] = round(time.perf_counter() - t0, 3)
    emit(out, args.json)
