"""Run the fenced code blocks of a Markdown page in order, in one folder, as a reader pastes
them: ``bash`` blocks into a shell, ``python`` blocks each into a fresh interpreter."""

from __future__ import annotations

import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

FENCE = re.compile(r"^```(bash|python)\n(.*?)^```", re.S | re.M)


@dataclass(frozen=True)
class Block:
    """One fenced block: its language, its code and the section (``##`` heading) it is in."""

    language: str
    code: str
    section: str


def blocks(page: Path) -> list[Block]:
    """The ``bash`` and ``python`` blocks of ``page``, in order."""
    text = page.read_text()
    found = []
    for match in FENCE.finditer(text):
        headings = re.findall(r"^## (.+)$", text[: match.start()], re.M)
        found.append(Block(match.group(1), match.group(2), headings[-1] if headings else ""))
    return found


def paste(block: Block, folder: Path, timeout: float = 900.0) -> str:
    """Run ``block`` in ``folder``; its stdout. Fails the test, with the block's stderr, when
    it exits with a non-zero code."""
    command = ["bash", "-euo", "pipefail", "-c", block.code]
    if block.language == "python":
        command = [sys.executable, "-c", block.code]
    done = subprocess.run(command, cwd=folder, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{block.section}: {block.code}\n{done.stderr}"
    return done.stdout
