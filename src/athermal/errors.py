"""Exceptions raised by athermal at its public doors."""


class InputError(ValueError):
    """Bad input: the message names the offending argument and what is wrong with it."""


class FileFormatError(InputError):
    """A file that cannot be read as an athermal/HOOMD GSD configuration."""


class ConvergenceError(RuntimeError):
    """A protocol step whose energy minimization did not converge (the message says how)."""


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (its type's name when it has none)."""
    return " ".join(str(exc).split()) or type(exc).__name__


JAX_MISSING = (
    "backend jax: JAX is not installed; pip install jax (CPU; docs/howto/gpu.md for the CUDA "
    "build), or pip install -e '.[jax]' in athermal's checkout"
)
"""The one line for the JAX engine without JAX (:mod:`athermal.engines.jax.device`, ``--backend
jax``)."""
