"""benchmarks/ is a package of scripts on athermal's public API (issue 36, item 7).

Read with :mod:`ast`, nothing run: no script edits ``sys.path`` or imports a sibling by its bare
name; an internal athermal name (a leading underscore in the name or in a module on its path)
is imported only if ``benchmarks/README.md`` lists it ("What the scripts import"), likewise a
private attribute and patching with ``unittest.mock``; no script is named like athermal or one
of its subpackages; every script is smoke-run by ``.ci/benchmarks``.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = ROOT / "benchmarks"
SCRIPTS = sorted(BENCHMARKS.glob("*.py"))
README = BENCHMARKS / "README.md"
CI_SMOKE = ROOT / ".ci" / "benchmarks"

# benchmarks/README.md, "What the scripts import": the one internal module and its names ...
ALLOWED_INTERNAL: dict[str, set[str]] = {}
# ... the private attributes the profiler touches, and the scripts that patch with mock
ALLOWED_PRIVATE_ATTRIBUTES = {"breakdown.py": {"_rebuild"}}
ALLOWED_MOCK = {"breakdown.py"}


def private(name: str) -> bool:
    """A leading underscore, not a dunder."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def subpackages() -> set[str]:
    """``athermal`` and the names of its subpackages."""
    package = ROOT / "src" / "athermal"
    return {"athermal"} | {p.parent.name for p in package.glob("*/__init__.py")}


def athermal_imports(tree: ast.Module) -> list[tuple[str, str | None, int]]:
    """``(module, name or None, line)`` of every athermal import: ``import``, ``from ...
    import`` and ``import_module("...")``."""
    out: list[tuple[str, str | None, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, None, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out += [(node.module, a.name, node.lineno) for a in node.names]
        elif (
            isinstance(node, ast.Call)
            and getattr(node.func, "id", getattr(node.func, "attr", None)) == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            out.append((node.args[0].value, None, node.lineno))
    return [(m, n, line) for m, n, line in out if m.split(".")[0] == "athermal"]


def internal_imports(tree: ast.Module) -> set[tuple[str, str | None]]:
    """``(module, name)`` of the athermal imports with a private part."""
    found = set()
    for module, name, _ in athermal_imports(tree):
        if any(private(part) for part in module.split(".")) or (name and private(name)):
            found.add((module, name))
    return found


def private_attributes(tree: ast.Module) -> set[str]:
    """Private attributes read or patched on anything but ``self``: ``x._name`` and the name
    given as a string to ``getattr``/``setattr``/``hasattr``/``patch.object``."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and private(node.attr):
            if not (isinstance(node.value, ast.Name) and node.value.id == "self"):
                found.add(node.attr)
        elif isinstance(node, ast.Call) and len(node.args) >= 2:
            func = getattr(node.func, "id", getattr(node.func, "attr", None))
            name = node.args[1]
            if (
                func in {"getattr", "setattr", "hasattr", "object"}
                and isinstance(name, ast.Constant)
                and isinstance(name.value, str)
                and private(name.value)
            ):
                found.add(name.value)
    return found


def uses_mock(tree: ast.Module) -> bool:
    """Whether the script imports ``unittest.mock`` (or a name from it)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(
            a.name.startswith("unittest.mock") for a in node.names
        ):
            return True
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("unittest"):
            if node.module == "unittest.mock" or any(a.name == "mock" for a in node.names):
                return True
    return False


def path_edits(tree: ast.Module) -> list[int]:
    """Lines that touch ``sys.path``, ``site.addsitedir`` or ``PYTHONPATH``."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and (
            (node.attr == "path" and getattr(node.value, "id", None) == "sys")
            or node.attr == "addsitedir"
        ):
            lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.module in {"sys", "site"}:
            if any(a.name in {"path", "addsitedir"} for a in node.names):
                lines.append(node.lineno)
        elif isinstance(node, ast.Constant) and node.value == "PYTHONPATH":
            lines.append(node.lineno)
    return lines


def parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def test_benchmarks_is_a_package_of_scripts():
    assert (BENCHMARKS / "__init__.py").is_file()
    assert {p.name for p in SCRIPTS} >= {"machine.py", "kernels.py", "table1.py"}


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_no_sys_path_edit(script):
    assert path_edits(parse(script)) == [], f"{script.name}: sys.path edited (run it with -m)"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_siblings_imported_through_the_package(script):
    siblings = {p.stem for p in SCRIPTS}
    bare = []
    for node in ast.walk(parse(script)):
        if isinstance(node, ast.Import):
            bare += [a.name for a in node.names if a.name.split(".")[0] in siblings]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            bare += [node.module] if node.module.split(".")[0] in siblings else []
    assert bare == [], f"{script.name}: import benchmarks.{bare[0]}, not {bare[0]}"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_internal_names_are_the_listed_ones(script):
    tree = parse(script)
    allowed = {(m, n) for m, names in ALLOWED_INTERNAL.items() for n in names}
    assert internal_imports(tree) <= allowed, (
        f"{script.name}: internal athermal imports not listed in benchmarks/README.md: "
        f"{sorted(internal_imports(tree) - allowed, key=str)}"
    )
    extra = private_attributes(tree) - ALLOWED_PRIVATE_ATTRIBUTES.get(script.name, set())
    assert not extra, f"{script.name}: private attributes not listed: {sorted(extra)}"
    assert not uses_mock(tree) or script.name in ALLOWED_MOCK, f"{script.name}: patches with mock"


def test_the_list_is_used_and_documented():
    """Every listed name is used by some script (the list shrinks with the need) and named in
    benchmarks/README.md."""
    trees = {p.name: parse(p) for p in SCRIPTS}
    used = set().union(*(internal_imports(t) for t in trees.values()))
    readme = README.read_text(encoding="utf-8")
    for module, names in ALLOWED_INTERNAL.items():
        assert f"`{module}`" in readme
        for name in names:
            assert (module, name) in used, f"{module}.{name} is listed but no script uses it"
            assert f"`{name}" in readme, name
    for script, attributes in ALLOWED_PRIVATE_ATTRIBUTES.items():
        assert attributes <= private_attributes(trees[script]), script
        assert all(f"`{a}`" in readme for a in attributes), attributes
    assert {name for name, tree in trees.items() if uses_mock(tree)} == ALLOWED_MOCK
    assert all(name in readme for name in ALLOWED_MOCK)


def test_no_script_is_named_like_athermal_or_a_subpackage():
    clash = {p.stem for p in SCRIPTS} & subpackages()
    assert not clash, f"benchmarks/{sorted(clash)[0]}.py is named like athermal's subpackage"


def test_usage_lines_run_modules():
    for path in [*SCRIPTS, README, ROOT / "README.md", ROOT / ".ci" / "run", CI_SMOKE]:
        text = path.read_text(encoding="utf-8")
        assert "python benchmarks/" not in text, f"{path.name}: use python -m benchmarks.NAME"
    assert 'python -m "benchmarks.$@"' in CI_SMOKE.read_text(encoding="utf-8")
    assert "bash .ci/benchmarks" in (ROOT / ".ci" / "run").read_text(encoding="utf-8")


def test_the_checks_catch_what_they_forbid():
    """The walkers on a script that breaks every rule."""
    bad = ast.parse(
        "import sys\n"
        "from importlib import import_module\n"
        "from unittest import mock\n"
        "sys.path.insert(0, '.')\n"
        "from athermal.minimize._memory import Memory\n"
        "from athermal.protocols.finite_strain import _linear_start\n"
        "lbfgs = import_module('athermal.minimize._compiled')\n"
        "obj._typeid\n"
        "mock.patch.object(obj, '_shifts', None)\n"
    )
    assert path_edits(bad) == [4]
    assert internal_imports(bad) == {
        ("athermal.minimize._memory", "Memory"),
        ("athermal.protocols.finite_strain", "_linear_start"),
        ("athermal.minimize._compiled", None),
    }
    assert private_attributes(bad) == {"_typeid", "_shifts"}
    assert uses_mock(bad)
    assert {"protocols", "minimize", "athermal"} <= subpackages()


def test_every_script_is_smoke_run_in_ci():
    """``.ci/benchmarks`` runs each script of ``benchmarks/`` (its smallest run): a script that
    no longer runs fails CI."""
    listed = set(re.findall(r"^\s*run (\w+)", CI_SMOKE.read_text(encoding="utf-8"), re.M))
    scripts = {p.stem for p in SCRIPTS if p.stem not in ("machine", "__init__")}
    assert scripts <= listed, f"not smoke-run: {sorted(scripts - listed)}"
    assert listed <= scripts, f"listed but gone: {sorted(listed - scripts)}"
