"""athermal: quasi-static simulation of athermal soft-particle packings by energy minimization."""

from .cell import Cell, isotropic, pure_shear, simple_shear
from .contact import ContactModel, Contacts, find_contacts, hessian, strain_derivative
from .errors import FileFormatError, InputError
from .io import Frame, append_gsd, count_frames, read_gsd, write_gsd
from .neighbors import NeighborList, build_neighbor_list
from .observables import Observables, measure
from .packing import Packing, bidisperse_radii, random_packing

__all__ = [
    "Cell",
    "ContactModel",
    "Contacts",
    "FileFormatError",
    "Frame",
    "InputError",
    "NeighborList",
    "Observables",
    "Packing",
    "append_gsd",
    "bidisperse_radii",
    "build_neighbor_list",
    "count_frames",
    "find_contacts",
    "hessian",
    "isotropic",
    "measure",
    "pure_shear",
    "random_packing",
    "read_gsd",
    "simple_shear",
    "strain_derivative",
    "write_gsd",
]
