"""Files replaced atomically and durably, the one way every writer of athermal uses: write a
temporary file beside the target, flush it to disk, rename it onto the target and flush the
directory. An error (a full disk, a kill) leaves a file already at the target untouched. The
file gets the permissions a new file gets under the process's umask, or keeps those of the file
it replaces (whatever mode the library that wrote the temporary file chose)."""

from __future__ import annotations

import glob
import os
import socket
import stat
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import FileFormatError, one_line


def _umask() -> int:
    """The process's umask, read once at import (setting it to read it back is not safe once
    threads write files)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _umask()


def _fsync(path: Path) -> None:
    """Flush the file ``path`` to disk."""
    with open(path, "rb+") as handle:
        os.fsync(handle.fileno())


_HOST = socket.gethostname().replace(".", "-")
"""This machine's name as temporary files carry it (a folder may be shared by several)."""


def _sweep(target: Path) -> None:
    """Remove the temporary files of ``target`` left by writers of this machine that were
    killed before they could (a Dask worker ended by Ctrl-C, a SIGKILL): each name carries its
    writer's machine and process id."""
    for stale in target.parent.glob(f".{glob.escape(target.stem)}.{_HOST}.*.tmp{target.suffix}"):
        pid = stale.name.removeprefix(f".{target.stem}.{_HOST}.").split(".")[0]
        if pid.isdigit() and not _alive(int(pid)):
            stale.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` of this machine runs."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


@contextmanager
def replacing(
    path: str | os.PathLike[str],
    *,
    what: str = "cannot write",
    why: Callable[[BaseException], str] = one_line,
) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix) to write; once the block ends, it
    replaces ``path``. An ``OSError`` or ``RuntimeError`` in the block becomes a
    :class:`FileFormatError` ``"{path}: {what} ({why(exc)})"``; the temporary file is removed."""
    target = Path(path)
    _sweep(target)
    temporary = target.with_name(
        f".{target.stem}.{_HOST}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp{target.suffix}"
    )
    try:
        yield temporary
        _fsync(temporary)
        mode = stat.S_IMODE(target.stat().st_mode) if target.exists() else 0o666 & ~_UMASK
        os.chmod(temporary, mode)
        os.replace(temporary, target)
        if os.name == "posix":
            directory = os.open(target.parent if str(target.parent) else ".", os.O_RDONLY)
            try:
                os.fsync(directory)
            finally:
                os.close(directory)
    except BaseException as exc:
        temporary.unlink(missing_ok=True)
        if isinstance(exc, OSError | RuntimeError) and not isinstance(exc, FileFormatError):
            raise FileFormatError(f"{target}: {what} ({why(exc)})") from exc
        raise


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Replace ``path`` by ``text`` (UTF-8) atomically."""
    with replacing(path) as temporary:
        temporary.write_text(text, encoding="utf-8")
