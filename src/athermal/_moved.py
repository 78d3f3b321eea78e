"""The modules that moved into rooms (issue 52), still importable by their old names for one
release, with a :class:`DeprecationWarning` naming the new one."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from types import ModuleType

MOVED = {
    "cell": "model.cell",
    "packing": "model.packing",
    "neighbors": "model.neighbors",
    "walls": "model.walls",
    "contact": "model.contact",
    "objective": "model.objective",
    "precon": "engines.precon",
    "jaxengine": "engines.jax.device",
    "observables": "analysis.observables",
    "moduli": "analysis.moduli",
    "modes": "analysis.modes",
    "forces": "analysis.forces",
    "fitting": "analysis.fitting",
    "extended": "certify.extended",
    "cage": "certify.cage",
    "criticality": "certify.criticality",
    "experiments": "studies.experiments",
    "ensemble": "studies.ensemble",
    "paper": "studies.paper",
    "bench": "studies.bench",
    "plot": "studies.plot",
    "checkpoint": "studies.checkpoint",
    "tables": "studies.tables",
}
"""Old module (relative to ``athermal``) -> where it lives now."""


class MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports ``athermal.<old>`` as the module it moved to, warning once per import."""

    def __init__(self) -> None:
        self.specs: dict[str, importlib.machinery.ModuleSpec | None] = {}
        """The moved modules' own specs, by their new names."""

    def find_spec(
        self, fullname: str, path: object = None, target: object = None
    ) -> importlib.machinery.ModuleSpec | None:
        """A spec for an old name of :data:`MOVED`, else None (the other finders look)."""
        old = fullname.removeprefix("athermal.")
        if fullname.startswith("athermal.") and old in MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        """The moved module itself (one module object under both names)."""
        new = f"athermal.{MOVED[spec.name.removeprefix('athermal.')]}"
        warnings.warn(
            f"{spec.name} moved to {new}; the old name goes in the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        module = importlib.import_module(new)
        self.specs[new] = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        """Nothing runs (the module ran under its new name); the import machinery set its
        ``__spec__`` to the old name's, and it gets its own back."""
        module.__spec__ = self.specs[module.__name__]


def install() -> None:
    """Put :class:`MovedFinder` on the import path (once)."""
    if not any(isinstance(f, MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(MovedFinder())
