"""The jamming workflow after the bisection: the jammed packing carried to the one that is kept
(at a target pressure, or certified in float64 or by a bisection in double-double) with what its
file logs. ``athermal jam`` is this and its output."""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from numpy.typing import NDArray

from ..analysis.observables import Observables, file_observables, measure
from ..certify import CertifiedPacking, certify
from ..certify.bisection import bisect_jamming_point
from ..errors import ConvergenceError, InputError
from ..io import write_gsd
from ..model.contact import ContactModel
from ..model.packing import Packing
from ..protocols import RESOLUTION, JammingResult
from ..protocols.pressure import (
    PRESSURE_RTOL,
    PressureResult,
    pressure_search,
    warn_if_near_jamming,
)
from ..relaxation import Minimizer
from .checkpoint import load_march, march_key, save_march


@dataclass(frozen=True, eq=False)
class Jammed:
    """A jamming run's outcome: its ``result``, the ``packing`` kept and its ``observables``,
    the bracket ``phi_low < phi_c``, the ``pressure`` search that led to it (None: the jammed
    packing), its certificate (``certified``; ``refused``: why certification failed, the
    packing then kept uncertified) and the double-double bisection's record (``bisected``)."""

    result: JammingResult
    packing: Packing
    observables: Observables
    phi_c: float
    phi_low: float
    pressure: PressureResult | None = None
    certified: CertifiedPacking | None = None
    refused: str | None = None
    bisected: dict[str, Any] = field(default_factory=dict)

    @property
    def written(self) -> str:
        """What the packing kept is, in words."""
        if self.pressure is None:
            return "the jammed packing at phi_c"
        return f"the packing at pressure {self.pressure.target:g} (phi = {self.pressure.phi:.9f})"

    def at_pressure(self) -> dict[str, Any]:
        """The pressure search's numbers (empty without one)."""
        found = self.pressure
        if found is None:
            return {}
        return {
            "target_pressure": found.target,
            "phi": found.phi,
            "delta_phi": found.delta_phi,
            "pressure_trials": len(found.trials),
            "pressure_drops": found.pressure_drops,
            "pressure_iterations": found.iterations,
        }

    def jamming_check(self) -> dict[str, Any]:
        """The referee's checks of the jammed packing (whatever packing is kept)."""
        jammed, check = self.result.observables, self.result.check
        return {
            "phi": jammed.phi,
            "energy": jammed.energy,
            "pressure": jammed.pressure,
            "z": jammed.z,
            "contacts": jammed.contacts,
            "n_rattlers": jammed.n_rattlers,
            "excess_contacts": check.excess_contacts,
            "allowed_excess": round(check.allowed_excess, 2),
            "unjams_when_decompressed": check.unjams,
            "decompression": check.decompression,
            "stable": check.stable,
            "passed": check.passed,
        }

    def log(self) -> dict[str, float | NDArray[Any]]:
        """What the file of the packing kept logs: its certificate, observables, bracket, the
        target pressure and the jamming check's numbers."""
        check = self.jamming_check()
        return {
            **({} if self.certified is None else self.certified.certificate.log()),
            **file_observables(self.observables),
            "phi_c": self.phi_c,
            "phi_low": self.phi_low,
            "phi_high": self.phi_c,
            **{
                k: v for k, v in self.at_pressure().items() if k in ("target_pressure", "delta_phi")
            },
            **{
                f"jamming_check_{k}": float(v)
                for k, v in check.items()
                if k in ("energy", "pressure", "z", "contacts", "excess_contacts")
            },
        }

    def write(self, path: str, model: ContactModel, seed: int | None) -> None:
        """Write the packing kept, with its double-double positions when certified, and
        :meth:`log`, to the GSD file ``path``."""
        write_gsd(
            path,
            self.packing,
            model=model,
            seed=seed,
            position_lo=None if self.certified is None else self.certified.position_lo,
            observables=self.log(),
        )


def finish_jamming(
    result: JammingResult,
    model: ContactModel,
    *,
    epsilon: float,
    pressure: float | None = None,
    pressure_rtol: float = PRESSURE_RTOL,
    minimizer: Minimizer | None = None,
    certifying: bool = False,
    march: str | os.PathLike[str] | None = None,
    resume: bool = False,
) -> Jammed:
    """Carry ``result`` to the packing kept: at ``pressure`` (relative accuracy
    ``pressure_rtol``, trials relaxed by ``minimizer``) when given; certified when
    ``certifying``, by a bisection in double-double down to ``epsilon`` when ``epsilon`` is
    below float64's verdict (:data:`~athermal.protocols.RESOLUTION`), else by :func:`certify`
    of the jammed packing. A certification that fails is recorded in ``refused``. The
    bisection's march checkpoints to the file ``march`` (:func:`~athermal.studies.checkpoint.
    save_march`), continues from it when ``resume`` (where it is this march's), and removes it
    once done."""
    obs, packing, found = result.observables, result.packing, None
    if pressure is not None:
        found = pressure_search(
            result.packing,
            model,
            pressure,
            phi_low=result.phi_low,
            phi_c=result.phi_c,
            rtol=pressure_rtol,
            minimizer=minimizer,
        )
        warn_if_near_jamming(found, epsilon)
        obs, packing = found.observables, found.packing
    outcome = Jammed(result, packing, obs, result.phi_c, result.phi_low, found)
    if not certifying:
        return outcome
    try:
        if epsilon < RESOLUTION:  # below float64's verdict: bisect in double-double
            key = march_key(result.packing, model, epsilon)
            point = bisect_jamming_point(
                result.packing,
                model,
                epsilon,
                resume=load_march(march, key) if march is not None and resume else None,
                on_checkpoint=None if march is None else lambda s: save_march(march, s, key),
            )
            if march is not None:
                Path(march).unlink(missing_ok=True)
            bisected = {
                "float64_phi_low": result.phi_low,
                "float64_phi_high": result.phi_c,
                **point.march(),
            }
            return replace(
                outcome,
                packing=point.jammed.packing,
                observables=certified_observables(point.jammed, model),
                phi_c=point.phi_high,
                phi_low=point.phi_low,
                certified=point.jammed,
                bisected=bisected,
            )
        certified = certify(result.packing, model)
        return replace(outcome, packing=certified.packing, certified=certified)
    except (InputError, ConvergenceError) as exc:  # the jammed packing is kept as it is
        return replace(outcome, refused=str(exc))


def certified_observables(certified: CertifiedPacking, model: ContactModel) -> Observables:
    """The observables of a packing bisected in double-double: energy, pressure, contacts,
    rattlers and z from its certificate (float64 misses its smallest overlaps, ~1e-17), the
    tensors from float64."""
    cert = certified.certificate
    live = certified.packing.n - cert.n_rattlers
    return replace(
        measure(certified.packing, model),
        energy=cert.energy,
        pressure=cert.pressure,
        contacts=cert.contacts,
        contacts_nonrattler=cert.contacts,
        n_rattlers=cert.n_rattlers,
        z=2.0 * cert.contacts / live,
    )
