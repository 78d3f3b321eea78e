"""Quasi-static protocols, each a generator of relaxed steps: jamming, compression, shear."""

from ._relax import Minimizer
from .compress import (
    CompressionStep,
    ScalingExponents,
    compression_steps,
    isostatic_z,
    log_spaced,
    scaling_exponents,
)
from .jamming import JammingResult, JammingStep, jam, jamming_steps
from .shear import SHEAR_MODES, ShearMode, ShearStep, shear_steps

__all__ = [
    "SHEAR_MODES",
    "CompressionStep",
    "JammingResult",
    "JammingStep",
    "Minimizer",
    "ScalingExponents",
    "ShearMode",
    "ShearStep",
    "compression_steps",
    "isostatic_z",
    "jam",
    "jamming_steps",
    "log_spaced",
    "scaling_exponents",
    "shear_steps",
]
