"""Shared fixtures and helpers for the test suite."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from athermal.cell import Cell
from athermal.packing import Packing

DATA = Path(str(resources.files("athermal.data")))  # reference configurations, with provenance


@pytest.fixture(scope="session")
def jammed_packing_2d() -> tuple[Packing, dict[str, np.ndarray]]:
    """The paper's Table configuration (N = 4096, alpha = 2) and its reference values."""
    ref = dict(np.load(DATA / "table1_N4096_alpha2.npz"))
    return Packing(ref["positions"], ref["radii"], Cell.box(ref["box"])), ref
