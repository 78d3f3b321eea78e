"""The runs whose bits every CPU must reproduce (``tests/test_portable.py``): jams in 2D (both
protocols, alpha 2 and 2.5, and a certified one) and 3D, a compression and a shear of a jammed
packing, a relaxation with each portable preconditioner solver and with Newton-CG. Run as
``python tests/golden.py`` it prints one JSON object: each run's ``phi`` or energy (``repr``) and
a SHA-256 of its exact float64 positions, radii and cell; ``--write`` stores it as
``tests/data/golden.json``, the values every machine must print."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

import athermal as at
from athermal.certify import certify

GOLDEN = Path(__file__).parent / "data" / "golden.json"


def digest(packing: at.Packing, *extra: np.ndarray) -> str:
    """SHA-256 (first 16 hex digits) of the exact positions, radii and cell of ``packing`` and of
    the arrays ``extra``."""
    h = hashlib.sha256()
    for array in (packing.positions, packing.radii, packing.cell.h, *extra):
        h.update(np.ascontiguousarray(array, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def runs() -> dict[str, list[str]]:
    """Each run's ``[repr(phi), digest]`` (``phi`` the jamming point for a jam, the packing
    fraction of the last state otherwise)."""
    out: dict[str, list[str]] = {}
    harmonic, hertz = at.ContactModel(2.0), at.ContactModel(2.5)
    jammed = None
    for seed in (1, 2):
        for protocol in ("ohern", "seed"):
            result = at.jam(at.random_packing(64, 0.8, seed=seed), harmonic, protocol=protocol)
            out[f"jam 2d {protocol} seed {seed}"] = [repr(result.phi_c), digest(result.packing)]
            if seed == 1 and protocol == "ohern":
                jammed = result
    hertzian = at.jam(at.random_packing(64, 0.8, seed=3), hertz)
    out["jam 2d alpha 2.5 seed 3"] = [repr(hertzian.phi_c), digest(hertzian.packing)]
    spheres = at.jam(at.random_packing(32, 0.55, dim=3, seed=1), harmonic)
    out["jam 3d seed 1"] = [repr(spheres.phi_c), digest(spheres.packing)]
    assert jammed is not None
    certified = certify(jammed.packing, harmonic)
    out["certify 2d seed 1"] = [
        repr(certified.packing.phi),
        digest(certified.packing, certified.position_lo),
    ]
    steps = list(
        at.compression_steps(jammed.packing, harmonic, delta_phis=at.log_spaced(1e-5, 1e-2, 1))
    )
    out["compress 2d seed 1"] = [repr(steps[-1].packing.phi), digest(steps[-1].packing)]
    sheared = list(at.shear_steps(steps[-1].packing, harmonic, strain=3e-3, step=1e-3))
    out["shear 2d seed 1"] = [repr(sheared[-1].packing.phi), digest(sheared[-1].packing)]
    start = at.random_packing(256, 0.86, seed=1)
    for solver in ("direct", "ic0"):  # AMG is this machine's (docs/decisions.md)
        relaxed = at.relax(start, hertz, at.Minimizer("lbfgs", "exp", solver=solver), rtol=1e-9)
        out[f"relax lbfgs exp {solver}"] = [repr(relaxed.energy), digest(relaxed.packing)]
    newton = at.relax(start, hertz, at.Minimizer("newton"), rtol=1e-12)
    out["relax newton"] = [repr(newton.energy), digest(newton.packing)]
    return out


if __name__ == "__main__":
    result = runs()
    text = json.dumps(result, indent=1, sort_keys=True)
    if "--write" in sys.argv:
        GOLDEN.write_text(text + "\n")
    print(text)
