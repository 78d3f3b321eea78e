"""athermal: quasi-static simulation of athermal soft-particle packings by energy minimization."""

from .cell import Cell, isotropic, pure_shear, simple_shear
from .contact import ContactModel, Contacts, find_contacts, hessian, strain_derivative
from .errors import FileFormatError, InputError
from .neighbors import NeighborList, build_neighbor_list
from .observables import Observables, measure
from .packing import Packing, bidisperse_radii, random_packing

__all__ = [
    "Cell",
    "ContactModel",
    "Contacts",
    "FileFormatError",
    "InputError",
    "NeighborList",
    "Observables",
    "Packing",
    "bidisperse_radii",
    "build_neighbor_list",
    "find_contacts",
    "hessian",
    "isotropic",
    "measure",
    "pure_shear",
    "random_packing",
    "simple_shear",
    "strain_derivative",
]
