"""B1 supplement: where one iteration's time goes (Table Case 1, N = 4096, pinned).

Each method relaxes Case 1 (alpha = 2 by default) to 1e-9 F0 while the parts of an iteration are
timed by wrappers (about 1 us per call): the compiled energy+gradient kernel, the rest of
``Objective.__call__`` (its bookkeeping), the preconditioner's solve and its builds (assembly,
``mu``, factorization: a cost per build, left out of the ratios), the L-BFGS direction (its
compact form), whole L-BFGS or CG iterations run in compiled code (kernels, searches and
solves included), the line search run from Python (its compiled search included, without the
evaluations by ``Objective.__call__``), and the rest. The floor an
iteration should cost is ``evaluations/iteration x kernel + solves/iteration x solve``, with the
kernel and the solve timed bare, in a loop, on the same configuration, between ``--repeats``
runs of each method (each run takes the mean of the two around it, each row is the run of the
median ratio); the issue's target is
``ms / iteration <= 1.3 x floor``. ``--compare-search K`` also runs each method ``K`` times with
the compiled line search and with the Python one (an objective without ``compiled``), alternating in
one process, and reports their time ratio (FIRE, which has no line search, is the control).

    python -m benchmarks.breakdown                     # N = 4096 Case 1, alpha 2 (~30 s)
    python -m benchmarks.breakdown --compare-search 5  # and the two line searches (~2 min)
    python -m benchmarks.breakdown --name breakdown_before
    python -m benchmarks.breakdown --tile 16 --maxiter 40 --methods L-BFGS P-L-BFGS FR-CG FIRE \
        --name breakdown_n1048576                      # scale.py's start at N = 1048576

``--tile K`` takes ``scale.py``'s start (the Table packing tiled K x K, Case 3's displacements,
Case 1's growth); ``--maxiter`` stops each run early (ms per iteration of its first
iterations).

Results: ``benchmarks/results/<name>.md`` and ``.json``.

A profiler of the minimizers' insides, this is the one benchmark that reaches into them: it
wraps functions and methods of ``athermal.model.objective``, ``athermal.engines.precon`` and
``athermal.minimize.lbfgs`` / ``cg`` with ``unittest.mock.patch.object`` for the run (no public
hook reports where an iteration's time goes) and uses the private name ``_rebuild``;
``benchmarks/README.md`` lists it. It follows those modules when they change.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from contextlib import ExitStack
from importlib import import_module
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np

from athermal.model.contact import ContactModel
from athermal.model.objective import Objective
from athermal.relaxation import RTOL, Minimizer, relax_objective
from athermal.studies.bench import make_case, reference_packing
from benchmarks.machine import ROOT, pin, save

# athermal.minimize is also a function name: the modules by import_module
contact_module = import_module("athermal.model.contact")
cg_module = import_module("athermal.minimize.cg")
lbfgs_module = import_module("athermal.minimize.lbfgs")
objective_module = import_module("athermal.model.objective")
precon_module = import_module("athermal.engines.precon")

METHODS = (
    Minimizer("lbfgs"),
    Minimizer("lbfgs", "exp"),
    Minimizer("lbfgs", "contact"),
    Minimizer("cg"),
    Minimizer("cg", "exp"),
    Minimizer("fire"),
)
PARTS = (
    "kernel",
    "objective",
    "compiled iterations",
    "solve",
    "build",
    "direction",
    "line search",
    "other",
)


class Clock:
    """Accumulated seconds and calls per part; parts nest (an inner part is subtracted)."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(PARTS, 0.0)
        self.calls = dict.fromkeys(PARTS, 0)
        self._stack: list[list[float]] = []

    def wrap(self, part: str, func: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            self._stack.append([time.perf_counter(), 0.0])
            try:
                return func(*args, **kwargs)
            finally:
                start, inner = self._stack.pop()
                spent = time.perf_counter() - start
                self.seconds[part] += spent - inner
                self.calls[part] += 1
                if self._stack:
                    self._stack[-1][1] += spent

        return timed

    def reset(self) -> None:
        """Zero every part's seconds and calls."""
        self.seconds = dict.fromkeys(PARTS, 0.0)
        self.calls = dict.fromkeys(PARTS, 0)


def bare(func: Callable[[], Any], repeats: int = 200) -> float:
    """Median seconds of ``func()`` over ``repeats`` calls, after a warm-up."""
    func()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        func()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def floors(start: Any, model: ContactModel, precons: set[str]) -> dict[str, float]:
    """Bare seconds of one energy+gradient kernel call and one solve of each preconditioner."""
    obj = Objective(start, model)
    x = obj.x0
    obj(x)
    nlist = obj.neighbor_list(x)
    grad = np.empty(obj.n_dof)
    pos = x.reshape(obj.n, obj.dim)
    typeid = model.typeid(start.permuted(obj.order))  # the objective's, in its internal order
    shifts = nlist.shifts(obj.cell)

    def kernel() -> None:
        contact_module.energy_gradient_contacts(
            pos, obj.radii, typeid, shifts, nlist, model, grad.reshape(obj.n, obj.dim)
        )

    repeats = 200 if obj.n <= 65536 else 25  # a bare kernel call at 10^6 drifts by 20 %
    out = {"kernel": bare(kernel, repeats)}
    rng = np.random.default_rng(0)
    for label, precon in (("direction", None), ("direction P", object())):
        memory = lbfgs_module.Memory(10, obj.n_dof, precon)  # a full memory, m = 10
        for _ in range(10):
            step, change = rng.standard_normal(obj.n_dof), rng.standard_normal(obj.n_dof)
            memory.store(x, x + step, grad, grad + step + 0.1 * change, grad, grad + step)
        g = rng.standard_normal(obj.n_dof)
        out[label] = bare(lambda memory=memory, g=g: direction_after_store(memory, g), repeats)
    for name in sorted(precons):
        pre = precon_module.make_preconditioner(name, obj)  # type: ignore[arg-type]
        assert pre is not None
        pre.update(x)
        g = obj(x)[1].copy()
        out[f"solve {name}"] = bare(lambda pre=pre, g=g: pre.solve(g), repeats)
    return out


def direction_after_store(memory: Any, g: np.ndarray) -> None:
    """One L-BFGS direction as the minimizer computes it, right after a pair was stored (the
    newest pair's dot products with the others included)."""
    memory.fresh = True
    memory.direction(g, g)


def profile(start: Any, model: ContactModel, how: Minimizer, maxiter: int) -> dict[str, Any]:
    """One relaxation of ``start`` by ``how`` with every part timed."""
    clock = Clock()
    with ExitStack() as stack:
        stack.enter_context(
            mock.patch.object(
                objective_module,
                "energy_gradient_contacts",
                clock.wrap("kernel", objective_module.energy_gradient_contacts),
            )
        )
        stack.enter_context(
            mock.patch.object(
                objective_module.Objective,
                "__call__",
                clock.wrap("objective", objective_module.Objective.__call__),
            )
        )
        for cls in (precon_module.ExpPreconditioner, precon_module.ContactPreconditioner):
            stack.enter_context(mock.patch.object(cls, "solve", clock.wrap("solve", cls.solve)))
            stack.enter_context(
                mock.patch.object(cls, "_rebuild", clock.wrap("build", cls._rebuild))
            )
        stack.enter_context(
            mock.patch.object(
                lbfgs_module.Memory,
                "direction",
                clock.wrap("direction", lbfgs_module.Memory.direction),
            )
        )
        loop = lbfgs_module.CompiledLoop  # L-BFGS's and CG's compiled iterations
        stack.enter_context(
            mock.patch.object(
                loop, "run", clock.wrap("compiled iterations", counted(clock, loop.run))
            )
        )
        for module in (lbfgs_module, cg_module):
            stack.enter_context(
                mock.patch.object(module, "advance", clock.wrap("line search", module.advance))
            )
        # what every run pays once before its first iteration (its first evaluation, the
        # neighbour list, the tolerance's mean contact force, buffers, the first build): timed
        # by a run stopped there, so that the steady ratio can leave it out
        t0 = time.perf_counter()
        opening = relax_objective(Objective(start, model), how, rtol=RTOL, maxiter=0)
        opening_seconds = time.perf_counter() - t0
        opening_build, opening_solves = clock.seconds["build"], clock.calls["solve"]
        clock.reset()
        obj = Objective(start, model)
        t0 = time.perf_counter()
        result = relax_objective(obj, how, rtol=RTOL, maxiter=maxiter)
        total = time.perf_counter() - t0
    clock.seconds["other"] = total - sum(clock.seconds[p] for p in PARTS if p != "other")
    iters = max(result.iterations, 1)
    return {
        "method": how.name,
        "iterations": result.iterations,
        "evaluations": result.evaluations,
        "solves": clock.calls["solve"],
        "converged": result.converged,
        "seconds": total,
        "ms_per_iteration": 1e3 * total / iters,
        "parts_ms_per_iteration": {p: 1e3 * clock.seconds[p] / iters for p in PARTS},
        "opening": {
            "seconds": opening_seconds,
            "build_seconds": opening_build,
            "evaluations": opening.evaluations,
            "solves": opening_solves,
        },
    }


def counted(clock: Clock, run: Callable[..., Any]) -> Callable[..., Any]:
    """``CompiledLoop.run`` with the run's solves (``counts[4]`` of the loop) added to
    ``clock``'s."""

    def counting(loop: Any, *args: Any) -> Any:
        out = run(loop, *args)
        clock.calls["solve"] += int(loop.counts[4])
        return out

    return counting


class PythonSearch(Objective):
    """The objective without its compiled line search: the minimizers evaluate each trial
    point through ``__call__``, as before the compiled search."""

    def compiled_search(self) -> None:  # type: ignore[override]
        return None


def compare_searches(
    start: Any, model: ContactModel, methods: list[Minimizer], repeats: int, maxiter: int
) -> list[dict[str, Any]]:
    """Each method with the compiled line search and with the Python one, alternating in this
    process ``repeats`` times after a warm-up: the medians and the median of the per-pair
    time ratios (compiled / Python)."""
    out = []
    for how in methods:
        times: dict[str, list[float]] = {"compiled": [], "python": []}
        counts = {}
        for r in range(repeats + 1):
            for name, cls in (("compiled", Objective), ("python", PythonSearch)):
                t0 = time.perf_counter()
                res = relax_objective(cls(start, model), how, rtol=RTOL, maxiter=maxiter)
                if r:  # the first round warms up
                    times[name].append(time.perf_counter() - t0)
                counts[name] = (res.iterations, res.evaluations)
        ratios = [a / b for a, b in zip(times["compiled"], times["python"], strict=True)]
        out.append(
            {
                "method": how.name,
                "iterations": counts,
                "seconds": {k: float(np.median(v)) for k, v in times.items()},
                "ratio": float(np.median(ratios)),
                "ratio_range": [min(ratios), max(ratios)],
            }
        )
        print(f"{how.name}: compiled / python {out[-1]['ratio']:.3f}", file=sys.stderr)
    return out


def rated(row: dict[str, Any], floor: dict[str, float], how: Minimizer) -> dict[str, Any]:
    """``row`` (a :func:`profile`) with its floors and its ratios to them, for the bare
    timings ``floor`` (seconds)."""
    precon = how.precon if how.precon != "none" else None
    solve = floor[f"solve {precon}"] if precon else 0.0
    iters = max(row["iterations"], 1)
    row["floor_ms"] = 1e3 * (
        row["evaluations"] / iters * floor["kernel"] + row["solves"] / iters * solve
    )
    steady = row["ms_per_iteration"] - row["parts_ms_per_iteration"]["build"]
    row["ratio_to_floor"] = steady / row["floor_ms"]
    recursion = floor["direction P" if precon else "direction"] if how.method == "lbfgs" else 0.0
    row["floor_with_recursion_ms"] = row["floor_ms"] + 1e3 * recursion
    row["ratio_to_floor_with_recursion"] = steady / row["floor_with_recursion_ms"]
    # the steady iteration: without the opening (but its build, counted in the builds) and
    # without the opening's evaluations and solves in the floor
    opening = row["opening"]
    once = 1e3 * (opening["seconds"] - opening["build_seconds"]) / iters
    evaluations = row["evaluations"] - opening["evaluations"]
    solves = row["solves"] - opening["solves"]
    steady_floor = evaluations / iters * floor["kernel"] + solves / iters * solve + recursion
    row["steady_ms"] = steady - once
    row["steady_ratio"] = row["steady_ms"] / (1e3 * steady_floor)
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--alpha", type=float, default=2.0)
    parser.add_argument("--case", type=int, default=1)
    parser.add_argument("--name", default="breakdown")
    parser.add_argument("--tile", type=int, default=1, help="scale.py's start, tiled K x K")
    parser.add_argument("--maxiter", type=int, default=50_000)
    parser.add_argument(
        "--repeats", type=int, default=3, help="runs of each method (the median ratio's shown)"
    )
    parser.add_argument("--methods", nargs="+", default=[m.name for m in METHODS])
    parser.add_argument("--output-dir", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument(
        "--compare-search",
        type=int,
        default=0,
        metavar="K",
        help="also run each method K times with the compiled and with the Python line search, "
        "alternating (their time ratio)",
    )
    args = parser.parse_args(argv)
    pin()
    model = ContactModel(args.alpha)
    if args.tile > 1:
        from benchmarks.scale import start_packing

        start = start_packing(args.alpha, args.tile)
        what = f"scale.py's start tiled {args.tile} x {args.tile}"
    else:
        start = make_case(reference_packing(args.alpha), args.case)
        what = f"Table Case {args.case}"
    chosen = [how for how in METHODS if how.name in args.methods]
    precons = {how.precon for how in chosen} - {"none"}
    rows, measured = [], []
    for how in chosen:
        if start.n <= 65536:
            profile(start, model, how, args.maxiter)  # warm-up: compilation, caches
        after = floors(start, model, precons)
        runs = []
        for _ in range(args.repeats):
            before = after
            row = profile(start, model, how, args.maxiter)
            after = floors(start, model, precons)
            measured += [before, after]
            floor = {k: 0.5 * (before[k] + after[k]) for k in before}  # the speed drifts
            runs.append(rated(row, floor, how))
        runs.sort(key=lambda r: r["ratio_to_floor_with_recursion"])
        row = runs[len(runs) // 2]  # the run of the median ratio
        row["ratio_range"] = [runs[0]["ratio_to_floor_with_recursion"]]
        row["ratio_range"].append(runs[-1]["ratio_to_floor_with_recursion"])
        rows.append(row)
        print(f"{how.name}: {row['ms_per_iteration']:.3f} ms/it", file=sys.stderr, flush=True)
    floor = {k: float(np.median([m[k] for m in measured])) for k in measured[0]}
    header = "| method | iterations | evaluations / it | solves / it | ms / it | floor ms / it "
    header += "| ratio | floor + direction | ratio (range) | steady ms / it | steady ratio | "
    header += " | ".join(PARTS) + " |"
    md = [
        f"# Per-iteration breakdown: {what}, alpha = {args.alpha:g}, N = {start.n}",
        "",
        f"Bare kernel (energy+gradient) {1e3 * floor['kernel']:.4f} ms; bare solve: "
        + ", ".join(f"{k[6:]} {1e3 * v:.4f} ms" for k, v in floor.items() if k.startswith("solve"))
        + "; bare "
        f"L-BFGS direction (compact form, m = 10, full memory) {1e3 * floor['direction']:.4f} ms, "
        f"with a preconditioner (P^-1 y kept) {1e3 * floor['direction P']:.4f} ms. "
        f"(medians of the bare timings taken between {args.repeats} runs of each method; each "
        "run's floor takes the mean of the two around it, since this machine's speed drifts; "
        "each row is the run of the median ratio to floor + direction, the range over the "
        "runs in brackets). The steady columns leave out the opening every run pays once "
        "before its first iteration (its first evaluation, the neighbour list, the "
        "tolerance's mean contact force, buffers), timed by a run stopped there, and its "
        "evaluation and solve from the floor. "
        "floor = evaluations/it x kernel + solves/it x solve (the issue's; target ratio <= 1.3); "
        "floor + direction adds the bare direction for the L-BFGS rows; the ratios leave the "
        "builds out. "
        "Parts in ms per iteration (objective: Objective.__call__ without the kernel; "
        "compiled iterations: whole L-BFGS or CG iterations in one compiled call, their "
        "kernels, searches and solves included; "
        "line search: the search run from Python, its compiled part included, without the "
        "evaluations by Objective.__call__).",
        "",
        header,
        "|---|" + "---:|" * (10 + len(PARTS)),
    ]
    for r in rows:
        iters = max(r["iterations"], 1)
        parts = " | ".join(f"{r['parts_ms_per_iteration'][p]:.3f}" for p in PARTS)
        md.append(
            f"| {r['method']} | {r['iterations']}{'' if r['converged'] else ' (stopped)'} | "
            f"{r['evaluations'] / iters:.2f} | "
            f"{r['solves'] / iters:.2f} | {r['ms_per_iteration']:.3f} | {r['floor_ms']:.3f} | "
            f"{r['ratio_to_floor']:.2f} | {r['floor_with_recursion_ms']:.3f} | "
            f"{r['ratio_to_floor_with_recursion']:.2f} ({r['ratio_range'][0]:.2f}-"
            f"{r['ratio_range'][1]:.2f}) | {r['steady_ms']:.3f} | {r['steady_ratio']:.2f} | "
            f"{parts} |"
        )
    md.append("")
    searches = []
    if args.compare_search:
        searches = compare_searches(start, model, chosen, args.compare_search, args.maxiter)
        md += [
            f"The compiled line search against the Python one, the two alternating in this "
            f"process, {args.compare_search} runs each after a warm-up (medians; the Python one "
            "evaluates each trial point through `Objective.__call__`):",
            "",
            "| method | iterations, evaluations (compiled / Python) | compiled s | Python s | "
            "compiled / Python (median of pairs, range) |",
            "|---|---|---:|---:|---:|",
        ]
        for c in searches:
            its = c["iterations"]
            md.append(
                f"| {c['method']} | {its['compiled'][0]}, {its['compiled'][1]} / "
                f"{its['python'][0]}, {its['python'][1]} | {c['seconds']['compiled']:.3f} | "
                f"{c['seconds']['python']:.3f} | {c['ratio']:.2f} "
                f"({c['ratio_range'][0]:.2f}-{c['ratio_range'][1]:.2f}) |"
            )
        md.append("")
    text = "\n".join(md)
    print(text)
    data = {"alpha": args.alpha, "case": args.case, "tile": args.tile, "n": start.n}
    data |= {"maxiter": args.maxiter, "floor_seconds": floor, "rows": rows}
    data |= {"search_comparison": searches}
    save(args.output_dir, args.name, data, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
