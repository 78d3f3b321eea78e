"""Sparse Cholesky factorizations of the networks of 3D packings (issue 54): cholespy's CHOLMOD
(its wheel's reference BLAS: the same bits on every CPU) against CHOLMOD's supernodal factor
through cvxopt (its optimized OpenBLAS: the machine's bits), in CHOLMOD's AMD order alone and
with ``athermal.linalg.dissection_order`` offered beside it (CHOLMOD keeps the order of less
fill). The march of a certified jamming factors such matrices (``docs/decisions.md``,
"Factorizations on the machine's BLAS").

For each N: ``random_packing(N, PHI, dim=3, seed=1)`` relaxed to 1e-4 of its mean contact force
(about 0.01 above jamming, z ~ 6.5), the Hessian of its non-rattlers with the first pinned,
shifted by ``SHIFT`` I so that it is positive definite. Per factorization: seconds (median of
``--repeats``), the nonzeros of L (cvxopt's), one solve's milliseconds and its relative
residual. Ratios are against cholespy in the same run, one pinned core.

    python -m benchmarks.factorization --n 1024 4096 16384
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from athermal import ContactModel, random_packing, relax
from athermal.analysis.moduli import pinned_hessian
from athermal.analysis.observables import rattlers
from athermal.linalg import CholeskyFactor, Factor, SupernodalFactor, dissection_order, row_order
from athermal.model.contact import find_contacts
from benchmarks.machine import ROOT, pin, save

PHI = 0.655
"""Packing fraction of the relaxed packings (3D jams near 0.645 for this mixture)."""
SHIFT = 0.1
"""Added to the Hessian's diagonal (stiffness k = 1): a packing this far above jamming keeps
negative eigenvalues of its pre-stress of order -0.02."""


def network(n: int) -> tuple[sp.csr_matrix, np.ndarray, int]:
    """The shifted pinned Hessian of the relaxed packing of ``n`` particles, the particles' rank
    by nested dissection over its rows, and its contacts."""
    model = ContactModel()
    packing = relax(random_packing(n, PHI, dim=3, seed=1), model, rtol=1e-4).packing
    contacts = find_contacts(packing, model)
    h, dofs = pinned_hessian(contacts, rattlers(contacts, packing.n, 3), 3)
    widths = packing.cell.widths
    points = np.mod(packing.cell.fractional(packing.positions), 1.0) * widths
    rank = dissection_order(points, widths, contacts.i, contacts.j)
    shifted = (h + SHIFT * sp.identity(h.shape[0])).tocsr()
    return shifted, row_order(rank, dofs, 3), int(contacts.i.size)


def timed(build: Callable[[], Factor], h: sp.csr_matrix, repeats: int) -> dict[str, Any]:
    """Seconds of ``build`` (median of ``repeats``), one solve's ms, its residual, fill."""
    seconds = []
    for _ in range(repeats):
        t = time.perf_counter()
        factor = build()
        seconds.append(time.perf_counter() - t)
    b = np.random.default_rng(0).standard_normal((h.shape[0], 1))
    t = time.perf_counter()
    x = factor.solve(b)
    solve = time.perf_counter() - t
    return {
        "seconds": float(np.median(seconds)),
        "solve_ms": 1e3 * solve,
        "residual": float(np.linalg.norm(h @ x - b) / np.linalg.norm(b)),
        "nonzeros": factor.nonzeros if isinstance(factor, SupernodalFactor) else None,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[1024, 4096, 16384])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--core", type=int, default=None)
    parser.add_argument("--output-dir", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    pinned = pin(args.core)
    rows = []
    for n in args.n:
        h, order, contacts = network(n)
        row = {"n": n, "rows": h.shape[0], "nonzeros_h": int(h.nnz), "contacts": contacts}
        row["cholespy"] = timed(lambda h=h: CholeskyFactor(h), h, args.repeats)
        row["supernodal_amd"] = timed(lambda h=h: SupernodalFactor(h), h, args.repeats)
        row["supernodal_dissection"] = timed(
            lambda h=h, o=order: SupernodalFactor(h, o), h, args.repeats
        )
        print(row, flush=True)
        rows.append(row)
    lines = [
        "# Sparse Cholesky factorizations of 3D packings' networks",
        "",
        f"`random_packing(N, {PHI}, dim=3, seed=1)` relaxed to 1e-4 of its mean contact force; "
        f"the Hessian of its non-rattlers, first pinned, + {SHIFT} I. Seconds: median of "
        f"{args.repeats}; one pinned core ({pinned}); ratio: cholespy's seconds over this one's.",
        "",
        "| N | rows | nnz(H) | cholespy s | solve ms | supernodal, AMD s | nnz(L) | solve ms "
        "| ratio | with dissection s | nnz(L) | solve ms | ratio |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        c, a, d = r["cholespy"], r["supernodal_amd"], r["supernodal_dissection"]
        lines.append(
            f"| {r['n']} | {r['rows']} | {r['nonzeros_h']} | {c['seconds']:.3f} | "
            f"{c['solve_ms']:.1f} | {a['seconds']:.3f} | {a['nonzeros']} | {a['solve_ms']:.1f} | "
            f"{c['seconds'] / a['seconds']:.1f} | {d['seconds']:.3f} | {d['nonzeros']} | "
            f"{d['solve_ms']:.1f} | {c['seconds'] / d['seconds']:.1f} |"
        )
    largest = max(
        max(r[k]["residual"] for k in ("cholespy", "supernodal_amd", "supernodal_dissection"))
        for r in rows
    )
    lines += ["", f"Largest relative residual of a solve: {largest:.1e}."]
    save(Path(args.output_dir), "factorization", {"rows": rows}, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
