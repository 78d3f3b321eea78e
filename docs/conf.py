"""Sphinx configuration of athermal's documentation site.

Build it from the repository root with ``python -m sphinx -W -b html docs build/docs`` (the tools
come with ``pip install -e ".[docs]"``). The pages are Markdown (MyST); the API page is written at
build time from ``athermal.__all__`` and the docstrings, so it cannot fall behind the code.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import pkgutil
from importlib import metadata

from sphinx.application import Sphinx
from sphinx.pycode import ModuleAnalyzer

import athermal

project = "athermal"
author = "the athermal developers"
copyright = f"2026, {author}"  # the footer's
release = metadata.version("athermal")
version = release
extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.mathjax"]
source_suffix = {".md": "markdown"}
exclude_patterns = ["_build"]
myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 3
napoleon_google_docstring = False
autodoc_member_order = "bysource"
html_theme = "furo"
html_title = f"athermal {release}"
html_static_path = ["_static"]
html_css_files = ["wrap.css"]  # long code lines wrap in their boxes instead of being cut

# Modules whose public names are not all re-exported by ``athermal``: their other names get a
# section of their own on the API page.
MODULES = (
    "athermal.model.cell",
    "athermal.protocols",
    "athermal.analysis.moduli",
    "athermal.model.walls",
    "athermal.enthalpy",
    "athermal.certify",
    "athermal.certify.cage",
    "athermal.certify.criticality",
    "athermal.certify.extended",
    "athermal.studies.plot",
    "athermal.studies.paper",
)


def _modules(path: list[str], prefix: str) -> list[str]:
    """The modules of the package at ``path``, at any depth; without JAX not the JAX engine's
    (the extra the docs extra does not install: importing it refuses)."""
    found = []
    for info in pkgutil.iter_modules(path, prefix):
        if "__main__" in info.name:
            continue
        if (
            info.name.startswith("athermal.engines.jax.")
            and importlib.util.find_spec("jax") is None
        ):
            continue
        found.append(info.name)
        if info.ispkg:
            found += _modules(importlib.import_module(info.name).__path__, info.name + ".")
    return found


def _home(name: str, obj: object) -> str:
    """The module that defines the constant ``name`` with its docstring (a constant carries no
    ``__module__``, and autodoc would show its type's docstring from any other)."""
    for module_name in _modules(athermal.__path__, "athermal."):
        module = importlib.import_module(module_name)
        if getattr(module, name, None) is obj:
            docs = ModuleAnalyzer.for_module(module_name).find_attr_docs()
            if ("", name) in docs:
                return module_name
    raise LookupError(f"the constant {name} has no docstring in the module that defines it")


def _directive(qualified: str, obj: object) -> str:
    if inspect.isclass(obj):
        return f".. autoclass:: {qualified}\n   :members:\n"
    if callable(obj):
        return f".. autofunction:: {qualified}\n"
    name = qualified.rpartition(".")[2]
    return f".. autodata:: {_home(name, obj)}.{name}\n   :no-value:\n"


def api_reference() -> str:
    """The API page's reference part as reStructuredText: ``athermal.__all__`` by module, then
    the further public names of :data:`MODULES`."""
    by_module: dict[str, list[str]] = {}
    for name in sorted(athermal.__all__):
        module = getattr(getattr(athermal, name), "__module__", None) or "athermal"
        by_module.setdefault(module, []).append(name)
    seen = {id(getattr(athermal, name)) for name in athermal.__all__}
    parts = []
    for module in sorted(by_module):
        title = f"From ``{module}``"
        parts.append(f"{title}\n{'-' * len(title)}\n")
        parts += [_directive(f"athermal.{n}", getattr(athermal, n)) for n in by_module[module]]
    for module_name in MODULES:
        module = importlib.import_module(module_name)
        documented = {n for (scope, n) in ModuleAnalyzer.for_module(module_name).find_attr_docs()}
        names = getattr(module, "__all__", None) or [
            n
            for n, v in vars(module).items()
            if not n.startswith("_")
            and (
                getattr(v, "__module__", "") == module_name or (n in documented and not callable(v))
            )
        ]
        names = [n for n in sorted(names) if id(getattr(module, n)) not in seen]
        title = f"``{module_name}``"
        parts.append(f"{title}\n{'-' * len(title)}\n\n.. automodule:: {module_name}\n")
        parts += [_directive(f"{module_name}.{n}", getattr(module, n)) for n in names]
    return "\n".join(parts)


def _fill_api_page(app: Sphinx, docname: str, source: list[str]) -> None:
    if docname == "api":
        source[0] = source[0].replace(
            "<!-- the reference -->", "```{eval-rst}\n" + api_reference() + "\n```"
        )


def setup(app: Sphinx) -> None:
    app.connect("source-read", _fill_api_page)
