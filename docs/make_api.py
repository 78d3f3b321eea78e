"""Write ``docs/api.md``: every public name of ``athermal`` (``athermal.__all__``), grouped by
module, with its signature and docstring, and the same for the protocol, moduli and plot
modules. Run from the repository root: ``python docs/make_api.py``; ``--check`` exits 1 when
the page is out of date (the test suite runs it)."""

from __future__ import annotations

import importlib
import inspect
import sys
from pathlib import Path

import athermal

PAGE = Path(__file__).resolve().parent / "api.md"
EXTRA_MODULES = ("athermal.protocols", "athermal.moduli", "athermal.plot", "athermal.paper")


def _entry(name: str, obj: object) -> list[str]:
    kind = "class" if inspect.isclass(obj) else "function" if callable(obj) else "constant"
    try:
        signature = str(inspect.signature(obj)) if callable(obj) else ""  # type: ignore[arg-type]
    except (TypeError, ValueError):
        signature = ""
    doc = inspect.getdoc(obj) or ""
    lines = [f"### `{name}{signature}`", "", f"*{kind}*", ""]
    if doc:
        lines += ["```text", doc, "```", ""]
    if inspect.isclass(obj):
        for member, value in vars(obj).items():
            if member.startswith("_") or not (callable(value) or isinstance(value, property)):
                continue
            target = value.fget if isinstance(value, property) else value
            member_doc = inspect.getdoc(target) or ""
            first = member_doc.splitlines()[0] if member_doc else ""
            lines.append(f"- `{name}.{member}`: {first}")
        lines.append("")
    return lines


def render() -> str:
    """The page's markdown."""
    lines = [
        "# athermal API",
        "",
        "Generated from the docstrings by `python docs/make_api.py`; do not edit by hand.",
        "Shapes are written `(N, d)`; units are those of the packing (unit cell, `k = 1` by",
        "default): lengths, energies in `k` x length^alpha, stresses in `k` x length^(alpha-d).",
        "",
        "## `athermal` (the public names, `athermal.__all__`)",
        "",
    ]
    by_module: dict[str, list[str]] = {}
    for name in sorted(athermal.__all__):
        obj = getattr(athermal, name)
        module = getattr(obj, "__module__", "athermal") or "athermal"
        by_module.setdefault(module, []).append(name)
    for module in sorted(by_module):
        lines += [f"### from `{module}`", ""]
        for name in by_module[module]:
            lines += _entry(name, getattr(athermal, name))
    for module_name in EXTRA_MODULES:
        module = importlib.import_module(module_name)
        lines += [f"## `{module_name}`", "", inspect.getdoc(module) or "", ""]
        names = getattr(module, "__all__", None) or [
            n
            for n, v in vars(module).items()
            if not n.startswith("_") and getattr(v, "__module__", "") == module_name
        ]
        for name in sorted(names):
            lines += _entry(name, getattr(module, name))
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str]) -> int:
    text = render()
    if "--check" in argv:
        if not PAGE.exists() or PAGE.read_text() != text:
            print(f"{PAGE} is out of date: run python docs/make_api.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
