"""Many realizations of a protocol on Dask (``dask.distributed``), reproducible and resumable.

Realization ``k`` of an ensemble with root seed ``S`` uses the ``k``-th child of
``numpy.random.SeedSequence(S)``, so its result does not depend on the number of workers or on
the order in which realizations finish. Each realization writes, into the ensemble directory,
its trajectory (``realization-KKKK.gsd``: one frame per completed step) and, once complete,
its result (``realization-KKKK.json``, written atomically). A realization whose result exists is
skipped (resume); one interrupted with its worker (killed, lost) is retried by Dask and
continues from its trajectory, so no realization is lost or counted twice.

The default engine is a local cluster started in-process (``LocalCluster`` with one process
per worker, one thread each); ``scheduler`` connects to an existing cluster instead. Without the
``dask`` extra the realizations run one after another in this process, with the same results.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import engines
from ..analysis.fitting import sample_stats
from ..analysis.forces import (
    EDGES,
    exponential_tail,
    histogram_density,
)
from ..errors import InputError, one_line
from ..io import claim
from ..protocols.compress import pooled_fit
from .avalanches import avalanche_statistics, pooled_drops, yielding
from .experiments import child_seeds
from .realization import (
    CompressionRecord,
    EnsembleSpec,
    ForceRecord,
    Realization,
    run_realization,
    write_json,
)

INSTALL_HINT = (
    "Dask is not installed (pip install 'dask[distributed]', or pip install -e '.[dask]' in "
    "athermal's checkout)"
)
CONNECT_TIMEOUT = 5.0
"""Seconds an existing scheduler (``scheduler``, ``--scheduler``) has to answer."""


@dataclass(frozen=True)
class EnsembleResult:
    """The realizations (by index), which of them this call computed, and the summary."""

    realizations: list[Realization]
    computed: list[int]
    summary: dict[str, Any]
    engine: str
    seconds: float
    files: dict[str, str] = field(default_factory=dict)


def pooled_exponent(records: list[CompressionRecord], column: str) -> dict[str, Any] | None:
    """The power law of ``column`` (``"pressure"``, ``"shear_modulus"``, ``"z_excess"``) against
    ``Delta phi`` fitted to all ``records``' rows pooled
    (:func:`~athermal.protocols.compress.pooled_fit`): its exponent, standard error, the number
    of points and their ``Delta phi`` range; None with too few points."""
    try:
        pooled = pooled_fit((c.rows for c in records), column)
    except InputError:
        return None
    return {
        "exponent": pooled.exponent,
        "stderr": pooled.stderr,
        "points": pooled.points,
        "delta_phi_range": [pooled.x_min, pooled.x_max],
    }


def summarize(spec: EnsembleSpec, realizations: list[Realization]) -> dict[str, Any]:
    """Mean, standard deviation and standard error of the realizations' numbers, and fits of
    all realizations' compression steps pooled (``Delta phi`` against each one's own phi_c)."""
    summary: dict[str, Any] = {
        "realizations": len(realizations),
        "phi_c": sample_stats([r.phi_c for r in realizations]),
        "z_minus_z_iso": sample_stats([r.z - r.z_iso for r in realizations]),
        "pressure": sample_stats([r.pressure for r in realizations]),
        "n_rattlers": sample_stats([float(r.n_rattlers) for r in realizations]),
        "checks_passed": sum(int(r.checks_passed) for r in realizations),
        "iterations": sample_stats([float(r.iterations) for r in realizations]),
    }
    compressed = [r.compression for r in realizations if r.compression is not None]
    if compressed:
        for key, column in (("p", "pressure"), ("G", "shear_modulus"), ("z", "z_excess")):
            values = [c.exponents[key] for c in compressed]
            summary[f"exponent_{key}"] = sample_stats([v for v in values if v is not None])
            pooled = pooled_exponent(compressed, column)
            if pooled is not None:
                summary[f"pooled_exponent_{key}"] = pooled
    networks = [r.forces for r in realizations if r.forces is not None]
    if networks:
        counts, overflow = pooled_forces(networks)
        tail = exponential_tail(counts, overflow)
        summary["forces"] = {
            "realizations": len(networks),
            "pooled_tail": None if tail is None else asdict(tail),
            "tail_decay": sample_stats(
                [f.tail_decay for f in networks if f.tail_decay is not None]
            ),
            "contact_anisotropy": sample_stats([f.contact_anisotropy for f in networks]),
            "force_anisotropy": sample_stats([f.force_anisotropy for f in networks]),
            "edges": EDGES.tolist(),
            "pooled_density": histogram_density(counts, overflow).tolist(),
        }
    runs = [r.events for r in realizations if r.events is not None]
    if runs:
        summary["avalanches"] = avalanche_statistics(runs, spec.events.transient)
    cycled = [r.cycles for r in realizations if r.cycles is not None]
    if cycled:
        summary["yielding"] = yielding(cycled)
    sheared = [r.shear for r in realizations if r.shear is not None]
    if sheared:
        summary["plastic_events"] = sample_stats([float(h.plastic_events) for h in sheared])
    counted = [r.iteration_counts for r in realizations if r.iteration_counts is not None]
    if counted:
        summary["delta_phi"] = list(counted[0].delta_phi)
        summary["iterations_per_step"] = {
            name: [  # a realization unjammed there (NaN) is left out
                sample_stats([v for c in counted if np.isfinite(v := c.iterations[name][k])])
                for k in range(len(counted[0].delta_phi))
            ]
            for name in counted[0].iterations
        }
    return summary


def pooled_forces(networks: list[ForceRecord]) -> tuple[NDArray[np.int64], int]:
    """The force histograms of several jammed packings added up: counts ``(B,)``, overflow."""
    counts = np.sum([np.asarray(f.counts, dtype=np.int64) for f in networks], axis=0)
    return counts, sum(f.overflow for f in networks)


def run_ensemble(
    spec: EnsembleSpec,
    directory: str | os.PathLike[str],
    realizations: int,
    *,
    seed: int = 0,
    workers: int | None = None,
    scheduler: str | None = None,
    retries: int = 3,
    progress: Callable[[str], None] | None = None,
    batch: int | None = None,
) -> EnsembleResult:
    """Run ``realizations`` realizations of ``spec`` (root ``seed``) into ``directory``.

    Parameters
    ----------
    spec : the protocol and its parameters.
    directory : where realizations and the summary go; reusing it resumes (finished
        realizations are skipped; it must hold realizations of the same spec and seed).
    realizations : how many (realization ``k`` uses the ``k``-th child seed).
    workers : worker processes of the local cluster (default: the cores available).
    scheduler : address of an existing Dask scheduler (``tcp://host:8786``) instead; it is
        reached (within :data:`CONNECT_TIMEOUT`) before ``directory`` is touched, so a
        scheduler that does not answer leaves nothing behind.
    retries : how often Dask retries a realization whose worker failed.
    progress : called with a line of text as realizations finish.
    batch : run ``batch`` realizations at a time in this process, their relaxations as one
        batch on the engine's device (:meth:`athermal.engines.Engine.batcher`; the spec's
        minimizer's engine must run batches; no ``workers`` or ``scheduler`` then).
    """
    t0 = time.perf_counter()
    say = progress or (lambda text: None)
    if int(realizations) != realizations or realizations < 1:
        raise InputError(f"realizations: must be an integer >= 1, got {realizations!r}")
    if workers is not None and (int(workers) != workers or workers < 1):
        raise InputError(f"workers: must be an integer >= 1, got {workers!r}")
    if workers is not None and importlib.util.find_spec("distributed") is None:
        raise InputError(f"workers: {workers} worker processes need Dask; {INSTALL_HINT}")
    if batch is not None:
        jam = spec.jam
        check_batch(batch, jam.n, jam.dim, jam.minimizer.backend, workers, scheduler)
    out = Path(directory)
    if out.exists() and not out.is_dir():
        raise InputError(f"-o: {out} exists and is not a directory")
    manifest = out / "ensemble.json"
    identity = {"spec": asdict(spec), "seed": seed, "identity": spec.identity()}
    stored = _read_json(manifest) if manifest.exists() else None
    if stored is not None and (stored.get("identity"), stored.get("seed")) != (
        identity["identity"],
        seed,
    ):
        raise InputError(f"{out} holds an ensemble with another spec or seed; use a new directory")
    client = None if scheduler is None else _connect(scheduler)
    try:
        out.mkdir(parents=True, exist_ok=True)
        lock = claim(manifest)  # one run per directory at a time
    except BaseException:
        if client is not None:
            client.close()
        raise
    try:
        if stored is None:
            write_json(manifest, identity)
        seeds = child_seeds(seed, realizations)
        results: dict[int, Realization] = {}
        for k in range(realizations):
            path = out / f"realization-{k:04d}.json"
            if path.exists():
                result = _read_realization(path)
                if result is None or result.seed != seeds[k]:
                    warnings.warn(
                        f"{path}: unreadable or not this ensemble's; computed again", stacklevel=2
                    )
                    path.unlink()
                else:
                    results[k] = result
        todo = [k for k in range(realizations) if k not in results]
        engine = "none (all finished)"
        if todo:
            prefix = f"athermal-{int(spec.identity())}-{seed}"
            if batch is not None:
                engine = _compute_batched(spec, out, todo, seeds, batch, results, say)
            else:
                engine = _compute(
                    spec, out, todo, seeds, workers, client, retries, results, say, prefix
                )
    finally:
        lock.close()
        if client is not None:
            client.close()
    ordered = [results[k] for k in range(realizations)]
    summary = summarize(spec, ordered)
    write_json(out / "summary.json", summary)
    files = {"summary": str(out / "summary.json")}
    if ordered:
        files.update(_summary_files(spec, out, ordered, summary))
    return EnsembleResult(
        realizations=ordered,
        computed=todo,
        summary=summary,
        engine=engine,
        seconds=time.perf_counter() - t0,
        files=files,
    )


def _summary_files(
    spec: EnsembleSpec, out: Path, realizations: list[Realization], summary: dict[str, Any]
) -> dict[str, str]:
    """``realizations.csv`` (the scalar numbers of each realization) and ``summary.png``."""
    from . import plot
    from .tables import write_table

    rows = [
        {
            **{k: v for k, v in r.to_json().items() if isinstance(v, int | float)},
            **(
                {}
                if r.forces is None
                else {
                    "force_tail_decay": (
                        float("nan") if r.forces.tail_decay is None else r.forces.tail_decay
                    ),
                    "contact_anisotropy": r.forces.contact_anisotropy,
                    "force_anisotropy": r.forces.force_anisotropy,
                }
            ),
        }
        for r in realizations
    ]
    table = out / "realizations.csv"
    write_table(table, rows)
    jam = spec.jam
    title = f"N = {jam.n}, {jam.dim}D, alpha = {jam.alpha:g}, {len(realizations)} realizations"
    counted = [r.iteration_counts for r in realizations if r.iteration_counts is not None]
    if counted:
        figure = plot.iterations_figure(
            summary["delta_phi"],
            {
                name: [[c.iterations[name][k] for c in counted] for k in range(len(c0))]
                for name, c0 in counted[0].iterations.items()
            },
            title=title,
            error="sd",
        )
    else:
        panels = {
            r"$\phi_c$": [r.phi_c for r in realizations],
            r"$z - z_{iso}$": [r.z - r.z_iso for r in realizations],
            rf"$p / \epsilon^{{\alpha - 1}}$ ($\epsilon$ = {jam.epsilon:g})": [
                r.pressure / jam.epsilon ** (jam.alpha - 1.0) for r in realizations
            ],
        }
        compressed = [r.compression for r in realizations if r.compression is not None]
        for key in ("p", "G"):
            values = [c.exponents[key] for c in compressed if c.exponents[key] is not None]
            if values:
                panels[f"exponent of {key}"] = values
        figure = plot.summary_figure(panels, title=title)
    picture = plot.save(figure, out / "summary.png")
    files = {"table": str(table), "figure": str(picture)}
    runs = [r.events for r in realizations if r.events is not None]
    if runs:
        drops = {f"{len(runs)} packings": pooled_drops(runs, spec.events.transient)}
        figure = plot.avalanche_figure(drops, title=title)
        files["avalanches_figure"] = str(plot.save(figure, out / "avalanches.png"))
    if "yielding" in summary:
        sweep = {rf"$\Delta\phi$ = {spec.events.delta_phi:g}": summary["yielding"]["amplitudes"]}
        figure = plot.yielding_figure(sweep, title=title)
        files["yielding_figure"] = str(plot.save(figure, out / "yielding.png"))
    networks = [r.forces for r in realizations if r.forces is not None]
    if networks:
        pooled = {f"pooled over {len(networks)} jammed packings": pooled_forces(networks)}
        files["forces_figure"] = str(
            plot.save(plot.force_distribution_figure(pooled, title=title), out / "forces.png")
        )
    return files


def _read_realization(path: Path) -> Realization | None:
    """The realization in ``path``, or None when it is not one (a damaged file)."""
    data = _read_json(path)
    try:
        return None if data is None else Realization.from_json(data)
    except (KeyError, TypeError, ValueError):
        return None


def _read_json(path: Path) -> dict[str, Any] | None:
    """The JSON object in ``path``, or None when it is not one (a damaged file)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _connect(scheduler: str) -> Any:
    """A Dask client of the scheduler at ``scheduler``; :class:`InputError` in one line when
    dask is not installed or the scheduler does not answer within :data:`CONNECT_TIMEOUT`."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise InputError(f"--scheduler: {INSTALL_HINT}") from None
    try:
        return Client(scheduler, timeout=CONNECT_TIMEOUT)
    except (OSError, ValueError, TypeError) as exc:  # timeout / refused; a malformed address
        raise InputError(f"--scheduler: cannot reach {scheduler}: {one_line(exc)}") from None


def check_batch(
    batch: int,
    n: int,
    dim: int,
    backend: str,
    workers: int | None = None,
    scheduler: str | None = None,
) -> None:
    """Refuse a batch of ``batch`` packings of ``n`` particles in ``dim`` dimensions that
    cannot run: on an engine without batches (``backend``), with worker processes, or larger
    than the device's memory (naming what it would need)."""
    if int(batch) != batch or batch < 1:
        raise InputError(f"batch: must be an integer >= 1, got {batch!r}")
    try:
        engine = engines.check(backend, batch=True)
    except InputError as exc:
        raise InputError(f"batch: {exc}") from None
    if workers is not None or scheduler is not None:
        raise InputError("batch: a batch runs in this process; drop workers / scheduler")
    member, have = engine.batch_bytes(n, dim)
    need = batch * member
    if need > have:
        raise InputError(
            f"batch: {batch} packings of N = {n} need about {need / 2**30:.1f} GiB of device "
            f"memory, {have / 2**30:.1f} GiB free; take a smaller batch"
        )


def _compute_batched(
    spec: EnsembleSpec,
    out: Path,
    todo: list[int],
    seeds: list[int],
    batch: int,
    results: dict[int, Realization],
    say: Callable[[str], None],
) -> str:
    """Run the realizations ``todo``, ``batch`` at a time in threads of this process, their
    relaxations batched on the engine's device; where they ran."""
    from concurrent.futures import ThreadPoolExecutor, as_completed

    engine = engines.engine(spec.jam.minimizer.backend)
    batcher = engine.batcher(batch)

    def one(k: int) -> Realization:
        with batcher.member():
            return run_realization(spec, k, seeds[k], str(out))

    with ThreadPoolExecutor(max_workers=batch) as pool:
        for future in as_completed([pool.submit(one, k) for k in todo]):
            result = future.result()
            results[result.index] = result
            say(f"realization {result.index} done (phi_c {result.phi_c:.7f})")
    return (
        f"{engine.describe()}, batches of {batch}: {batcher.calls} batched calls, "
        f"{batcher.members} member loops"
    )


def _compute(
    spec: EnsembleSpec,
    out: Path,
    todo: list[int],
    seeds: list[int],
    workers: int | None,
    client: Any,
    retries: int,
    results: dict[int, Realization],
    say: Callable[[str], None],
    prefix: str,
) -> str:
    """Run the realizations ``todo`` on ``client`` (a connected scheduler's; it stays open), on
    a local cluster started here when None, or one after another without dask; the engine's
    name."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        warnings.warn(f"{INSTALL_HINT}: running the realizations one after another", stacklevel=3)
        for k in todo:
            results[k] = run_realization(spec, k, seeds[k], str(out))
            say(f"realization {k} done (phi_c {results[k].phi_c:.7f})")
        return "sequential"
    cluster = None
    if client is not None:
        engine = f"dask scheduler {client.scheduler.address}"
    else:
        available = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1
        count = workers or available
        import dask

        # the workers' statistical profiler samples every thread's stack each 10 ms, which
        # slows a realization (docs/decisions.md, "Measured behind the code")
        with dask.config.set({"distributed.worker.profile.enabled": False}):
            cluster = LocalCluster(
                n_workers=count,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,  # not a warning per task cancelled by Ctrl-C
            )
        client = Client(cluster)
        engine = f"dask LocalCluster, {count} worker processes"
    try:
        futures = [
            client.submit(
                run_realization,
                spec,
                k,
                seeds[k],
                str(out),
                key=f"realization-{k}",
                retries=retries,
            )
            for k in todo
        ]
        for future in as_completed(futures):
            result = future.result()
            results[result.index] = result
            say(f"realization {result.index} done (phi_c {result.phi_c:.7f})")
    finally:
        if cluster is not None:
            client.close()
            cluster.close()
    return engine
