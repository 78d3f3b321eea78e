"""What every results file of ``benchmarks/`` records, and how it is written: once, here.

The scripts import it as ``from benchmarks.machine import ...``; they run as modules of the
``benchmarks`` package from the repository root (``python -m benchmarks.NAME``).

- :func:`pin` pins the run to one core (the machines are shared: one core, less noise);
- :func:`describe` is the run's machine: date (UTC), commit, CPU model, cores, pinned cores and
  the versions of python, numpy, scipy and numba; :func:`line` the same as one line of text;
- :func:`save` writes ``<name>.json`` (the data plus ``describe()`` under ``"machine"``) and
  ``<name>.md`` (the markdown plus ``Run: <line>.``), each atomically
  (:func:`athermal.atomic.write_text`).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

from athermal.atomic import write_text

ROOT = Path(__file__).resolve().parent.parent


def cpu_model() -> str:
    """The "model name" of /proc/cpuinfo, else what :mod:`platform` knows."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for text in fh:
                if text.lower().startswith("model name"):
                    return text.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def _git(*args: str) -> subprocess.CompletedProcess[str] | None:
    try:
        return subprocess.run(
            ["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None


def commit() -> str:
    """The short commit hash, ``+dirty`` when the tree has changes; ``unknown`` without git
    (``uncommitted`` in a repository with no commit yet)."""
    inside = _git("rev-parse", "--is-inside-work-tree")
    if inside is None or inside.returncode != 0:
        return "unknown"
    head = _git("rev-parse", "--short", "HEAD")
    rev = (head.stdout.strip() if head is not None and head.returncode == 0 else "") or (
        "uncommitted"
    )
    status = _git("status", "--porcelain")
    if status is not None and status.returncode == 0 and status.stdout.strip():
        rev += "+dirty"
    return rev


def _allowed() -> list[int]:
    getter = getattr(os, "sched_getaffinity", None)
    return sorted(getter(0)) if getter is not None else []


def pin(core: int | None = None) -> list[int]:
    """Pin this process to ``core`` (default: the lowest allowed core) and return the cores it
    may run on now. A no-op where ``os.sched_setaffinity`` is missing; where pinning fails (a
    core not allowed) a note goes to stderr and the affinity is left as it was."""
    setter = getattr(os, "sched_setaffinity", None)
    allowed = _allowed()
    if setter is None:
        return allowed
    target = min(allowed) if core is None else core
    try:
        setter(0, {target})
    except (OSError, ValueError) as exc:
        print(f"note: could not pin to core {target} ({exc}); not pinned", file=sys.stderr)
    return _allowed()


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "absent"


def describe() -> dict[str, str]:
    """The run's machine: ``date_utc``, ``commit``, ``cpu``, ``cores``, ``pinned`` and
    ``software`` (python, numpy, scipy and numba versions)."""
    allowed = _allowed()
    return {
        "date_utc": datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S"),
        "commit": commit(),
        "cpu": cpu_model(),
        "cores": str(os.cpu_count()),
        "pinned": str(allowed) if allowed else "n/a",
        "software": f"python {platform.python_version()}, "
        + ", ".join(f"{p} {_version(p)}" for p in ("numpy", "scipy", "numba")),
    }


def line(meta: dict[str, str]) -> str:
    """``meta`` (:func:`describe`) as one line of text."""
    return (
        f"{meta['date_utc']} UTC; commit {meta['commit']}; {meta['cpu']}, {meta['cores']} cores, "
        f"pinned to {meta['pinned']}; {meta['software']}"
    )


def save(
    directory: Path,
    name: str,
    data: dict[str, Any],
    markdown: str,
    meta: dict[str, str] | str | None = None,
) -> None:
    """Write ``directory/<name>.json`` (``data`` plus ``meta`` under ``"machine"``) and
    ``directory/<name>.md`` (``markdown`` plus ``Run: <line>.``), each atomically; ``meta`` is
    the run's machine, default this one (:func:`describe`; a string: an older result's line)."""
    meta = describe() if meta is None else meta
    data["machine"] = meta
    text = markdown if markdown.endswith("\n") else markdown + "\n"
    text += f"\nRun: {line(meta) if isinstance(meta, dict) else meta}.\n"
    directory.mkdir(parents=True, exist_ok=True)
    write_text(directory / f"{name}.json", json.dumps(data, indent=1) + "\n")
    write_text(directory / f"{name}.md", text)
