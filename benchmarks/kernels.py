"""B2 kernel benchmark: neighbour-list build and energy+gradient per call, numba vs numpy.

Measures, on bidisperse random packings (``random_packing(N, phi, dim=d, seed=1)``, already sorted
along a space-filling curve; phi = 0.84 in 2D, phi = 0.64 in 3D; k = 1):

1. ``build_neighbor_list(positions, radii, cell)`` with the default skin, seconds per build;
2. ``energy_gradient(...)`` (the compiled path), ms per call, ns per listed pair and per contact;
3. the best vectorized numpy version of the same energy+gradient on the same neighbour list
   (gather, mask, scatter with ``np.bincount``), and the ratio numpy / numba.

Both energy+gradient versions are checked against each other (energy to 1e-12 relative, gradient
to 1e-12 of max |grad|) before anything is timed; the run aborts on a mismatch. Each timing is the
median of ``--repeats`` repeats after a warm-up; a repeat runs enough calls to last >= 0.2 s.

Run from the repository root (pinned to one core where the OS allows it)::

    python -m benchmarks.kernels            # full: 2D N = 4096 ... 1048576, 3D N = 4096, 262144
    python -m benchmarks.kernels --quick    # smoke test: 2D N = 4096, 16384, 3D N = 4096

Results: ``benchmarks/results/kernels.md`` (markdown table) and ``kernels.json`` (same rows).
Compare numbers only within one run (ratios): the machines are shared and noisy.
"""

from __future__ import annotations

import os

# One thread for every library, set before numpy is imported: the run is pinned to one core and
# an extra BLAS thread on that core would only add noise.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import gc  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from dataclasses import asdict, dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from athermal.model.contact import ContactModel, energy_gradient  # noqa: E402
from athermal.model.neighbors import NeighborList, build_neighbor_list  # noqa: E402
from athermal.model.packing import Packing, random_packing  # noqa: E402
from benchmarks.machine import ROOT, pin, save  # noqa: E402

SIZES_2D = (4096, 65536, 262144, 1048576)
SIZES_3D = (4096, 262144)
QUICK_2D = (4096, 16384)
QUICK_3D = (4096,)
ALPHAS = (2.0, 2.5)
PHI = {2: 0.84, 3: 0.64}
SEED = 1
MIN_REPEAT_SECONDS = 0.2
ENERGY_RTOL = 1e-12
GRADIENT_RTOL = 1e-12

# The targets. The per-N ones are for 2D packings; the speed-up applies to every row.
TARGET_EG_MS = {(2, 4096): 0.15, (2, 262144): 12.0, (2, 1048576): 50.0}
TARGET_NLIST_S = {(2, 1048576): 0.4}
TARGET_SPEEDUP = 3.0
TARGETS_LINE = (
    "energy+gradient at N = 4096 <= 0.15 ms, at N = 262144 <= 12 ms, at N = 1048576 <= 50 ms; "
    "neighbour list at N = 1048576 <= 0.4 s (these per-N targets are checked on 2D rows); "
    f"numba >= {TARGET_SPEEDUP:g}x faster than numpy (every row)"
)

COLUMNS = (
    "dim",
    "N",
    "alpha",
    "pairs",
    "contacts",
    "nlist build (s)",
    "E+grad numba (ms)",
    "ns/pair",
    "ns/contact",
    "numpy (ms)",
    "numpy/numba",
    "target",
    "status",
)


class KernelMismatch(RuntimeError):
    """The compiled and the numpy energy+gradient disagree."""


@dataclass
class Row:
    """One benchmark row (times in seconds, as measured; formatting happens at output)."""

    dim: int
    n: int
    phi: float
    alpha: float
    pairs: int
    contacts: int
    nlist_s: float
    numba_s: float
    numpy_s: float
    numba_calls_per_repeat: int
    numpy_calls_per_repeat: int
    nlist_calls_per_repeat: int
    energy: float
    energy_rel_diff: float
    gradient_rel_diff: float
    target: str
    status: str

    @property
    def ns_per_pair(self) -> float:
        return 1e9 * self.numba_s / max(self.pairs, 1)

    @property
    def ns_per_contact(self) -> float:
        return 1e9 * self.numba_s / max(self.contacts, 1)

    @property
    def ratio(self) -> float:
        return self.numpy_s / self.numba_s

    def cells(self) -> list[str]:
        return [
            str(self.dim),
            str(self.n),
            f"{self.alpha:g}",
            str(self.pairs),
            str(self.contacts),
            f"{self.nlist_s:.4g}",
            f"{1e3 * self.numba_s:.4g}",
            f"{self.ns_per_pair:.1f}",
            f"{self.ns_per_contact:.1f}",
            f"{1e3 * self.numpy_s:.4g}",
            f"{self.ratio:.2f}",
            self.target,
            self.status,
        ]

    def as_json(self) -> dict[str, object]:
        out: dict[str, object] = asdict(self)
        out.update(
            numba_ms=1e3 * self.numba_s,
            numpy_ms=1e3 * self.numpy_s,
            ns_per_pair=self.ns_per_pair,
            ns_per_contact=self.ns_per_contact,
            numpy_over_numba=self.ratio,
        )
        return out


# --------------------------------------------------------------------------------------------
# numpy reference
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PairIndex:
    """The neighbour list's index arrays as ``intp``, made once per list (as a list is built once
    and used for many evaluations), so that ``np.take`` and ``np.bincount`` do not convert them on
    every call."""

    first: NDArray[np.intp]
    second: NDArray[np.intp]
    code: NDArray[np.intp]

    @classmethod
    def of(cls, nlist: NeighborList) -> PairIndex:
        return cls(
            nlist.first.astype(np.intp), nlist.second.astype(np.intp), nlist.code.astype(np.intp)
        )


def numpy_energy_gradient(
    x: NDArray[np.float64],
    radii: NDArray[np.float64],
    typeid: NDArray[np.int32],
    shifts: NDArray[np.float64],
    pairs: PairIndex,
    kmat: NDArray[np.float64],
    alpha: float,
) -> tuple[float, NDArray[np.float64]]:
    """Energy ``sum k delta^alpha / alpha`` and its gradient ``(N, d)``, vectorized numpy.

    Separations ``x_i - x_j + shift`` per axis (1-D ``take`` on contiguous columns is faster than
    gathering rows of ``x``), overlaps clipped at 0 so that non-contacts get zero force (cheaper
    than compressing to the contacts when most listed pairs overlap), and a scatter per axis with
    ``np.bincount`` (``np.add.at`` is about 2x slower).
    """
    n, d = x.shape
    fi, se = pairs.first, pairs.second
    cols = np.ascontiguousarray(x.T)
    shift_cols = np.ascontiguousarray(shifts.T)
    seps = []
    for a in range(d):
        s = cols[a].take(fi)
        s -= cols[a].take(se)
        s += shift_cols[a].take(pairs.code)
        seps.append(s)
    dist = seps[0] * seps[0]
    for a in range(1, d):
        dist += seps[a] * seps[a]
    np.sqrt(dist, out=dist)
    delta = radii.take(fi)
    delta += radii.take(se)
    delta -= dist
    np.maximum(delta, 0.0, out=delta)
    if alpha == 2.0:
        force = delta.copy()
    elif alpha == 2.5:
        force = np.sqrt(delta)
        force *= delta
    elif alpha == 3.0:
        force = delta * delta
    else:
        force = delta ** (alpha - 1.0)
    if kmat.shape == (1, 1):
        k = float(kmat[0, 0])
        if k != 1.0:
            force *= k
    else:
        force *= kmat[typeid.take(fi), typeid.take(se)]
    energy = float(np.dot(force, delta)) / alpha
    force /= dist  # force magnitude over distance: the factor of the separation vector
    grad = np.empty((n, d))
    for a in range(d):
        fa = force * seps[a]
        grad[:, a] = np.bincount(se, fa, n)
        grad[:, a] -= np.bincount(fi, fa, n)
    return energy, grad


def count_contacts(
    x: NDArray[np.float64],
    radii: NDArray[np.float64],
    shifts: NDArray[np.float64],
    pairs: PairIndex,
) -> int:
    """Listed pairs that overlap (``|sep| < r_i + r_j``, the kernel's own test)."""
    sep = x[pairs.first] - x[pairs.second] + shifts[pairs.code]
    d2 = np.einsum("ij,ij->i", sep, sep)
    reach = radii[pairs.first] + radii[pairs.second]
    return int(np.count_nonzero(d2 < reach * reach))


# --------------------------------------------------------------------------------------------
# timing
# --------------------------------------------------------------------------------------------


def time_per_call(fn: Callable[[], object], repeats: int) -> tuple[float, int]:
    """Median seconds per call of ``fn`` over ``repeats`` repeats, and the calls per repeat.

    One warm-up call (numba compiles or loads its cache there), then the calls per repeat are
    found by doubling until a batch lasts >= ``MIN_REPEAT_SECONDS`` (at least one call).
    """
    fn()
    calls = 1
    gc_was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        while True:
            t0 = time.perf_counter()
            for _ in range(calls):
                fn()
            elapsed = time.perf_counter() - t0
            if elapsed >= MIN_REPEAT_SECONDS:
                break
            guess = math.ceil(calls * 1.2 * MIN_REPEAT_SECONDS / max(elapsed, 1e-9))
            calls = min(max(2 * calls, guess), 100 * calls)
        samples = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(calls):
                fn()
            samples.append((time.perf_counter() - t0) / calls)
    finally:
        if gc_was_enabled:
            gc.enable()
    return statistics.median(samples), calls


# --------------------------------------------------------------------------------------------
# one configuration
# --------------------------------------------------------------------------------------------


def check_agreement(
    dim: int,
    n: int,
    alpha: float,
    e_numba: float,
    g_numba: NDArray[np.float64],
    e_numpy: float,
    g_numpy: NDArray[np.float64],
) -> tuple[float, float]:
    """Relative energy and gradient differences; raises :class:`KernelMismatch` beyond tolerance."""
    scale_e = max(abs(e_numba), abs(e_numpy))
    e_rel = abs(e_numba - e_numpy) / scale_e if scale_e > 0 else 0.0
    scale_g = max(float(np.abs(g_numba).max()), float(np.abs(g_numpy).max()))
    diff_g = float(np.abs(g_numba - g_numpy).max())
    g_rel = diff_g / scale_g if scale_g > 0 else diff_g
    finite = np.isfinite(e_numba) and bool(np.all(np.isfinite(g_numba)))
    if not finite or e_rel > ENERGY_RTOL or g_rel > GRADIENT_RTOL:
        raise KernelMismatch(
            f"energy_gradient (numba) and the numpy reference disagree for dim={dim}, N={n}, "
            f"alpha={alpha:g}: energy {e_numba!r} vs {e_numpy!r} (relative difference {e_rel:.3g},"
            f" tolerance {ENERGY_RTOL:g}); max |grad difference| {diff_g:.3g} = {g_rel:.3g} x "
            f"max |grad| (tolerance {GRADIENT_RTOL:g}); finite: {finite}"
        )
    return e_rel, g_rel


def judge(dim: int, n: int, nlist_s: float, numba_s: float, numpy_s: float) -> tuple[str, str]:
    """The applicable targets of a row as text, and PASS / FAIL (naming what failed)."""
    targets: list[str] = []
    failed: list[str] = []
    eg = TARGET_EG_MS.get((dim, n))
    if eg is not None:
        targets.append(f"E+g<={eg:g}ms")
        if 1e3 * numba_s > eg:
            failed.append("E+g")
    nl = TARGET_NLIST_S.get((dim, n))
    if nl is not None:
        targets.append(f"nlist<={nl:g}s")
        if nlist_s > nl:
            failed.append("nlist")
    targets.append(f"np/nb>={TARGET_SPEEDUP:g}")
    if numpy_s / numba_s < TARGET_SPEEDUP:
        failed.append("np/nb")
    status = "PASS" if not failed else "FAIL (" + ", ".join(failed) + ")"
    return ", ".join(targets), status


def bench_packing(dim: int, n: int, alphas: Sequence[float], repeats: int) -> list[Row]:
    """All rows of one packing (the neighbour list is timed once: it does not depend on alpha)."""
    phi = PHI[dim]
    p: Packing = random_packing(n, phi, dim=dim, seed=SEED)
    x, r, cell = p.positions, p.radii, p.cell
    nlist_s, nlist_calls = time_per_call(lambda: build_neighbor_list(x, r, cell), repeats)
    nlist = build_neighbor_list(x, r, cell)
    shifts = nlist.shifts(cell)
    pairs = PairIndex.of(nlist)
    contacts = count_contacts(x, r, shifts, pairs)
    rows = []
    for alpha in alphas:
        model = ContactModel(alpha=alpha)
        typeid = model.typeid(p)
        grad = np.empty_like(x)
        e_numba = energy_gradient(x, r, typeid, shifts, nlist, model, grad)
        e_numpy, g_numpy = numpy_energy_gradient(x, r, typeid, shifts, pairs, model.kmat, alpha)
        e_rel, g_rel = check_agreement(dim, n, alpha, e_numba, grad, e_numpy, g_numpy)
        del g_numpy

        def call_numba(
            model: ContactModel = model,
            typeid: NDArray[np.int32] = typeid,
            grad: NDArray[np.float64] = grad,
        ) -> float:
            return energy_gradient(x, r, typeid, shifts, nlist, model, grad)

        def call_numpy(model: ContactModel = model, typeid: NDArray[np.int32] = typeid) -> object:
            return numpy_energy_gradient(x, r, typeid, shifts, pairs, model.kmat, model.alpha)

        numba_s, numba_calls = time_per_call(call_numba, repeats)
        numpy_s, numpy_calls = time_per_call(call_numpy, repeats)
        target, status = judge(dim, n, nlist_s, numba_s, numpy_s)
        rows.append(
            Row(
                dim=dim,
                n=n,
                phi=phi,
                alpha=alpha,
                pairs=nlist.n_pairs,
                contacts=contacts,
                nlist_s=nlist_s,
                numba_s=numba_s,
                numpy_s=numpy_s,
                numba_calls_per_repeat=numba_calls,
                numpy_calls_per_repeat=numpy_calls,
                nlist_calls_per_repeat=nlist_calls,
                energy=e_numba,
                energy_rel_diff=e_rel,
                gradient_rel_diff=g_rel,
                target=target,
                status=status,
            )
        )
        print(
            f"  dim={dim} N={n} alpha={alpha:g}: nlist {nlist_s:.4g} s, numba "
            f"{1e3 * numba_s:.4g} ms, numpy {1e3 * numpy_s:.4g} ms -> {status}",
            file=sys.stderr,
            flush=True,
        )
    return rows


# --------------------------------------------------------------------------------------------
# output
# --------------------------------------------------------------------------------------------


def markdown(meta: dict[str, object], rows: Sequence[Row]) -> str:
    lines = [
        "# B2 — kernel benchmarks (neighbour list, energy+gradient)",
        "",
        f"- packings: `random_packing(N, phi, dim=d, seed={SEED})` (bidisperse 1:1, size ratio 1.4,"
        " uniformly random positions, sorted along a Z-order curve, k = 1); "
        "**phi = 0.84 in 2D, phi = 0.64 in 3D**; default Verlet skin (0.2 x mean radius)",
        f"- timing: median of {meta['repeats']} repeats after a warm-up, each repeat >= "
        f"{MIN_REPEAT_SECONDS:g} s of back-to-back calls (`time.perf_counter`); the neighbour-list "
        "time is per packing (the same in both alpha rows)",
        "- ns/pair and ns/contact: numba energy+gradient time over listed pairs "
        "(`nlist.n_pairs`) and over overlapping pairs",
        "- numpy: vectorized reference on the same list (per-axis `take`, clipped overlaps, "
        "`np.bincount` scatter); agrees with numba to "
        f"{ENERGY_RTOL:g} (energy, relative) and {GRADIENT_RTOL:g} x max|grad| (gradient), "
        "checked before timing",
        f"- targets (issue): {TARGETS_LINE}",
    ]
    notes = meta["notes"]
    assert isinstance(notes, list)
    lines += [f"- note: {note}" for note in notes]
    lines += ["", table(rows), ""]
    return "\n".join(lines)


def table(rows: Sequence[Row]) -> str:
    out = [
        "| " + " | ".join(COLUMNS) + " |",
        "|" + "|".join("---" if c in ("target", "status") else "---:" for c in COLUMNS) + "|",
    ]
    out += ["| " + " | ".join(row.cells()) + " |" for row in rows]
    return "\n".join(out)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="B2: neighbour-list build and energy+gradient per call (numba vs numpy)."
    )
    parser.add_argument(
        "--sizes",
        type=int,
        nargs="+",
        default=None,
        help=f"2D particle numbers (default {' '.join(map(str, SIZES_2D))})",
    )
    parser.add_argument(
        "--sizes-3d",
        type=int,
        nargs="*",
        default=None,
        help=f"3D particle numbers (default {' '.join(map(str, SIZES_3D))}; give none to skip 3D)",
    )
    parser.add_argument(
        "--alphas",
        type=float,
        nargs="+",
        default=list(ALPHAS),
        help="contact exponents (default 2 2.5)",
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="repeats per timing, median reported (default 5; >= 3)",
    )
    parser.add_argument("--core", type=int, default=0, help="core to pin to (default 0)")
    parser.add_argument(
        "--output-dir",
        type=Path,
        default=ROOT / "benchmarks" / "results",
        help="where kernels.md and kernels.json go (default benchmarks/results in the repository)",
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke test: 2D N = 4096 16384, 3D N = 4096, 3 repeats"
    )
    args = parser.parse_args(argv)
    if args.sizes is None:
        args.sizes = list(QUICK_2D if args.quick else SIZES_2D)
    if args.sizes_3d is None:
        args.sizes_3d = list(QUICK_3D if args.quick else SIZES_3D)
    if args.repeats is None:
        args.repeats = 3 if args.quick else 5
    if args.repeats < 3:
        parser.error(f"--repeats: need at least 3 for a median, got {args.repeats}")
    if any(n < 2 for n in [*args.sizes, *args.sizes_3d]):
        parser.error("--sizes/--sizes-3d: need at least 2 particles")
    if any(not a >= 2.0 for a in args.alphas):
        parser.error("--alphas: contact exponents must be >= 2")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    pinned = pin(args.core)
    notes = []
    if pinned != [args.core]:
        notes.append(f"not pinned to core {args.core} (allowed cores {pinned or 'unknown'})")
        print(f"note: {notes[-1]}; timings will be noisier", file=sys.stderr)
    meta: dict[str, object] = {
        "repeats": args.repeats,
        "phi": {"2": PHI[2], "3": PHI[3]},
        "seed": SEED,
        "min_repeat_seconds": MIN_REPEAT_SECONDS,
        "targets": TARGETS_LINE,
        "notes": notes,
    }
    print(
        f"B2 kernels: 2D N = {args.sizes} (phi = {PHI[2]}), 3D N = {args.sizes_3d} "
        f"(phi = {PHI[3]}), alpha = {args.alphas}, {args.repeats} repeats, pinned core: "
        f"{pinned}",
        file=sys.stderr,
        flush=True,
    )
    rows: list[Row] = []
    try:
        for dim, sizes in ((2, args.sizes), (3, args.sizes_3d)):
            for n in sizes:
                rows += bench_packing(dim, n, args.alphas, args.repeats)
    except KernelMismatch as exc:
        print(f"ABORTED: {exc}", file=sys.stderr)
        return 1
    out_dir: Path = args.output_dir
    data = {"meta": meta, "rows": [row.as_json() for row in rows]}
    save(out_dir, "kernels", data, markdown(meta, rows))
    print(table(rows))
    print(f"wrote {out_dir / 'kernels.md'} and {out_dir / 'kernels.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
