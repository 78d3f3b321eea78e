"""Run the fenced code blocks of a Markdown page in order, in one folder, as a reader pastes
them: ``bash`` blocks into a shell, ``python`` blocks each into a fresh interpreter; and hold
what they print to the page's ``text`` block after each (the output it quotes)."""

from __future__ import annotations

import re
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path

FENCE = re.compile(r"^```(bash|python|text)\n(.*?)^```", re.S | re.M)
ELIDED = "..."
"""A line of a quoted output that stands for any number of lines."""


@dataclass(frozen=True)
class Block:
    """One fenced block: its language, its code, the section (``##`` heading) it is in, and the
    output the page quotes for it (the ``text`` block after it, before the next code block, in
    the same section; None when there is none)."""

    language: str
    code: str
    section: str
    printed: str | None = None


def blocks(page: Path) -> list[Block]:
    """The ``bash`` and ``python`` blocks of ``page``, in order, each with its quoted output."""
    text = page.read_text()
    found: list[Block] = []
    for match in FENCE.finditer(text):
        headings = re.findall(r"^## (.+)$", text[: match.start()], re.M)
        section = headings[-1] if headings else ""
        if match.group(1) != "text":
            found.append(Block(match.group(1), match.group(2), section))
        elif found and found[-1].section == section and found[-1].printed is None:
            found[-1] = replace(found[-1], printed=match.group(2))
    return found


def check_printed(block: Block, out: str) -> None:
    """Every line of the output ``block`` quotes is a line of ``out``, exactly (trailing blanks
    aside) and in order; :data:`ELIDED` skips any lines. Fails naming the first line missing."""
    lines = [line.rstrip() for line in out.splitlines()]
    at = 0
    for quoted in (block.printed or "").splitlines():
        quoted = quoted.rstrip()
        if quoted.strip() == ELIDED:
            continue
        while at < len(lines) and lines[at] != quoted:
            at += 1
        assert at < len(lines), f"{block.section}: quoted {quoted!r}, not printed in order:\n{out}"
        at += 1


def paste(block: Block, folder: Path, timeout: float = 900.0) -> str:
    """Run ``block`` in ``folder``; its stdout. Fails the test, with the block's stderr, when
    it exits with a non-zero code."""
    command = ["bash", "-euo", "pipefail", "-c", block.code]
    if block.language == "python":
        command = [sys.executable, "-c", block.code]
    done = subprocess.run(command, cwd=folder, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{block.section}: {block.code}\n{done.stderr}"
    return done.stdout
