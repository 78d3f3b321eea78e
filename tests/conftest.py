"""Shared fixtures and helpers for the test suite."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from athermal.analysis.moduli import nonaffine_displacement, nonrattler_contacts
from athermal.model.cell import Cell
from athermal.model.neighbors import build_neighbor_list
from athermal.model.packing import Packing

DATA = Path(str(resources.files("athermal.data")))  # reference configurations, with provenance


@pytest.fixture(scope="session")
def jammed_packing_2d() -> tuple[Packing, dict[str, np.ndarray]]:
    """The paper's Table configuration (N = 4096, alpha = 2) and its reference values."""
    ref = dict(np.load(DATA / "table1_N4096_alpha2.npz"))
    return Packing(ref["positions"], ref["radii"], Cell.box(ref["box"])), ref


def network(packing, model):
    """The contacts of ``packing``'s non-rattlers: pairs ``(i, j)`` and wall contacts
    ``(i, axis, side)``."""
    live, _ = nonrattler_contacts(packing, model)
    w = live.walls
    pairs = set(zip(live.i.tolist(), live.j.tolist(), strict=True))
    return pairs | set(zip(w.particle.tolist(), w.axis.tolist(), w.side.tolist(), strict=True))


def network_strain(packing, model, d1, rattlers=False):
    """The least ``|g|`` at which, along ``x -> (I + g d1) x`` in linear response (the affine
    map and :func:`nonaffine_displacement`), a contact of ``packing``'s non-rattlers, with
    each other or a wall, parts or a gap between them closes: their network holds below it.
    With ``rattlers``, the gaps of the rattlers (carried affinely) count too: below it no
    contact at all forms or parts."""
    x, radii, cell = packing.positions, packing.radii, packing.cell
    _, rattler = nonrattler_contacts(packing, model)
    u = nonaffine_displacement(packing, model, d1)
    nl = build_neighbor_list(x, radii, cell, float(radii.mean()))
    live = np.ones(nl.first.size, dtype=bool)
    if not rattlers:
        live = ~(rattler[nl.first] | rattler[nl.second])
    first, second, sep = nl.first[live], nl.second[live], nl.separations(x, cell)[live]
    dist = np.linalg.norm(sep, axis=1)
    overlaps = [radii[first] + radii[second] - dist]
    rates = [-np.einsum("kd,kd->k", sep / dist[:, None], sep @ d1.T + u[first] - u[second])]
    moved = x @ d1.T + u
    for a in cell.walls:  # the overlap r - (side x_a + L_a / 2) with each wall
        for side in (1.0, -1.0):
            overlaps.append((radii - side * x[:, a] - 0.5 * cell.h[a, a])[~rattler])
            rates.append((-side * moved[:, a] - 0.5 * d1[a, a] * cell.h[a, a])[~rattler])
    overlap, rate = np.concatenate(overlaps), np.concatenate(rates)
    moving = rate != 0.0
    return float(np.min(np.abs(overlap[moving] / rate[moving])))
