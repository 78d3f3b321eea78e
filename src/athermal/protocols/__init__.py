"""Quasi-static protocols, each a generator of relaxed steps: jamming, compression, shear."""

from ..relaxation import Minimizer
from .compress import (
    EVENTS,
    CompressionStep,
    ScalingExponents,
    compression_steps,
    isostatic_z,
    log_spaced,
    scaling_exponents,
)
from .finite_strain import FiniteStrain, finite_strain_bulk, finite_strain_shear
from .jamming import (
    DPHI,
    EPSILON,
    JAM_PROTOCOL,
    JAM_PROTOCOLS,
    JAMMING_MINIMIZER,
    JAMMING_SCHEME,
    PHI_INIT,
    RESOLUTION,
    JammingCheck,
    JammingResult,
    JammingStep,
    JamProtocol,
    check_jammed,
    jam,
    jamming_steps,
)
from .pressure import PressureResult, PressureTrial, jam_to_pressure, pressure_search
from .shear import SHEAR_MODES, ShearMode, ShearStep, shear_steps

__all__ = [
    "DPHI",
    "EPSILON",
    "EVENTS",
    "JAMMING_MINIMIZER",
    "JAMMING_SCHEME",
    "JAM_PROTOCOL",
    "JAM_PROTOCOLS",
    "PHI_INIT",
    "RESOLUTION",
    "SHEAR_MODES",
    "CompressionStep",
    "FiniteStrain",
    "JamProtocol",
    "JammingCheck",
    "JammingResult",
    "JammingStep",
    "Minimizer",
    "PressureResult",
    "PressureTrial",
    "ScalingExponents",
    "ShearMode",
    "ShearStep",
    "check_jammed",
    "compression_steps",
    "finite_strain_bulk",
    "finite_strain_shear",
    "isostatic_z",
    "jam",
    "jam_to_pressure",
    "jamming_steps",
    "log_spaced",
    "pressure_search",
    "scaling_exponents",
    "shear_steps",
]
