"""athermal: quasi-static simulation of athermal soft-particle packings by energy minimization."""

from ._moved import install
from .analysis.fitting import PowerLaw, fit_power_law
from .analysis.forces import ForceStatistics, force_statistics
from .analysis.modes import Modes, vibrational_modes
from .analysis.moduli import LinearResponse, Stability, linear_response, stability
from .analysis.observables import Observables, measure
from .enthalpy import EnthalpyResult, relax_at_pressure
from .errors import ConvergenceError, FileFormatError, InputError
from .io import Frame, append_gsd, count_frames, read_gsd, write_gsd
from .minimize import MinimizeResult
from .model.cell import Cell, isotropic, pure_shear, simple_shear
from .model.contact import ContactModel, Contacts, find_contacts, hessian, strain_derivative
from .model.law import ContactLaw, NumbaForm, PowerContact
from .model.neighbors import NeighborList, build_neighbor_list
from .model.objective import Objective
from .model.packing import Packing, bidisperse_radii, polydisperse_radii, random_packing
from .protocols import (
    JammingCheck,
    Minimizer,
    check_jammed,
    compression_steps,
    finite_strain_bulk,
    finite_strain_shear,
    jam,
    jam_to_pressure,
    jamming_steps,
    log_spaced,
    scaling_exponents,
    shear_steps,
)
from .relaxation import Relaxation, relax

__all__ = [
    "Cell",
    "ContactLaw",
    "ContactModel",
    "Contacts",
    "ConvergenceError",
    "EnthalpyResult",
    "FileFormatError",
    "ForceStatistics",
    "Frame",
    "InputError",
    "JammingCheck",
    "LinearResponse",
    "MinimizeResult",
    "Minimizer",
    "Modes",
    "NeighborList",
    "NumbaForm",
    "Objective",
    "Observables",
    "Packing",
    "PowerContact",
    "PowerLaw",
    "Relaxation",
    "Stability",
    "append_gsd",
    "bidisperse_radii",
    "build_neighbor_list",
    "check_jammed",
    "compression_steps",
    "count_frames",
    "find_contacts",
    "finite_strain_bulk",
    "finite_strain_shear",
    "fit_power_law",
    "force_statistics",
    "hessian",
    "isotropic",
    "jam",
    "jam_to_pressure",
    "jamming_steps",
    "linear_response",
    "log_spaced",
    "measure",
    "polydisperse_radii",
    "pure_shear",
    "random_packing",
    "read_gsd",
    "relax",
    "relax_at_pressure",
    "scaling_exponents",
    "shear_steps",
    "simple_shear",
    "stability",
    "strain_derivative",
    "vibrational_modes",
    "write_gsd",
]

install()  # the modules' old names, for one release (athermal._moved)
