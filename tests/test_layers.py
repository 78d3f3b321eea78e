"""The minimizer library sits below the physics (issue 36): read with :mod:`ast`, nothing run.

``src/athermal/minimize`` imports only the package's foundations (errors, validation, the numba
decorators, the block-vector kernels, the sparse solvers) and itself; no ``type: ignore`` and no
``getattr`` probe remain there. Run ``python -m pytest tests/test_layers.py`` to see the picture
hold.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "src" / "athermal"
LIBRARY = sorted((PACKAGE / "minimize").glob("*.py"))
BELOW = {"errors", "_validate", "_jit", "_portable", "_blocks", "linalg"}
"""The modules of athermal that the minimizers may import (none of them imports upward)."""


def athermal_modules(path: Path) -> set[str]:
    """The athermal modules ``path`` imports, as names relative to the package (``objective``,
    ``minimize.result``)."""
    return imported(path.read_text(encoding="utf-8"), path.parent.relative_to(PACKAGE).parts)


def imported(text: str, here: tuple[str, ...]) -> set[str]:
    """The athermal modules the source ``text`` of a module in the package's folder ``here``
    imports (:func:`athermal_modules`)."""
    tree = ast.parse(text)
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 0:
                parts = (node.module or "").split(".")
                if parts[0] != "athermal":
                    continue
                base = parts[1:]
            else:
                base = list(here[: len(here) - (node.level - 1)]) + (
                    node.module.split(".") if node.module else []
                )
            if node.module is None or (node.level and not node.module):
                found |= {".".join([*base, a.name]) for a in node.names}
            else:
                found.add(".".join(base))
        elif isinstance(node, ast.Import):
            found |= {
                ".".join(a.name.split(".")[1:]) for a in node.names if a.name.startswith("athermal")
            }
    return found


def outside(module: str) -> bool:
    """Whether ``module`` (relative to the package) is outside the minimizer library."""
    return module.split(".")[0] != "minimize"


@pytest.mark.parametrize("path", LIBRARY, ids=lambda p: p.name)
def test_the_minimizers_import_nothing_above_them(path):
    above = {m for m in athermal_modules(path) if outside(m) and m.split(".")[0] not in BELOW}
    assert not above, f"minimize/{path.name} imports {sorted(above)}"


@pytest.mark.parametrize("module", sorted(BELOW))
def test_what_they_import_stands_below_them(module):
    path = PACKAGE / f"{module}.py"
    above = {m for m in athermal_modules(path) if m.split(".")[0] not in BELOW}
    assert not above, f"{module}.py imports {sorted(above)}"


@pytest.mark.parametrize("path", LIBRARY, ids=lambda p: p.name)
def test_no_type_ignore_and_no_getattr_probe(path):
    text = path.read_text(encoding="utf-8")
    assert "type: ignore" not in text, f"minimize/{path.name}"
    calls = [
        node
        for node in ast.walk(ast.parse(text))
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) in {"getattr", "hasattr"}
    ]
    assert not calls, f"minimize/{path.name}: getattr/hasattr at line {calls[0].lineno}"


def test_the_walker_sees_a_forbidden_import():
    """The check on a module of ``minimize/`` that breaks the rule, in every spelling."""
    found = imported(
        "from ..objective import Objective\n"
        "from .. import packing\n"
        "import athermal.model.contact\n"
        "from athermal.model.neighbors import NeighborList\n"
        "from .result import Status\n",
        ("minimize",),
    )
    assert {"objective", "packing", "model.contact", "model.neighbors"} <= found
    assert {m for m in found if not outside(m)} == {"minimize.result"}


def rooms() -> dict[str, set[str]]:
    """The package's rooms (a subpackage, or a module at the top) and the rooms each imports."""
    graph: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        if parts[0] in ("__init__", "__main__"):
            continue
        graph.setdefault(parts[0], set()).update(
            m.split(".")[0] for m in athermal_modules(path) if m.split(".")[0] != parts[0]
        )
    return {room: {d for d in deps if d in graph} for room, deps in graph.items()}


def floors(graph: dict[str, set[str]]) -> dict[str, int]:
    """Each room's floor: one above the highest room it imports (ground: 1); raises on a
    cycle."""
    found: dict[str, int] = {}

    def floor(room: str, path: tuple[str, ...]) -> int:
        if room in path:
            raise AssertionError(f"import cycle: {' -> '.join((*path, room))}")
        if room not in found:
            found[room] = 1 + max((floor(d, (*path, room)) for d in graph[room]), default=0)
        return found[room]

    for room in graph:
        floor(room, ())
    return found


def test_the_house_has_no_cycle_and_its_floors():
    """The picture of ``docs/decisions.md`` ("The house"): 22 rooms on 11 floors, the command
    line alone at the top, the ground floor importing nothing of athermal."""
    graph = rooms()
    level = floors(graph)
    assert len(graph) <= 22 and max(level.values()) <= 11
    assert [r for r in level if level[r] == max(level.values())] == ["cli"]
    assert all(not graph[r] for r in ("errors", "_jit", "_records"))


def test_the_floor_walker_sees_a_cycle():
    with pytest.raises(AssertionError, match="import cycle: a -> b -> a"):
        floors({"a": {"b"}, "b": {"a"}})


def test_a_moved_module_still_imports_by_its_old_name_with_a_warning():
    import importlib
    import sys

    import athermal.model.contact as new

    sys.modules.pop("athermal.contact", None)
    with pytest.warns(DeprecationWarning, match="athermal.contact moved to athermal.model.contact"):
        old = importlib.import_module("athermal.contact")
    assert old is new and old.ContactModel is new.ContactModel
    assert new.__spec__.name == "athermal.model.contact"  # its relative imports still resolve
    sys.modules.pop("athermal.contact", None)
