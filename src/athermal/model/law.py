"""The contact law: the energy of one overlap and its derivatives, in each arithmetic the
package computes in.

A law gives the energy ``E(delta)`` of a contact of stiffness ``k`` and overlap ``delta > 0``
(0 otherwise), its force ``f = dE/d delta`` (repulsive, along the contact normal) and its
stiffness ``dE^2/d delta^2``; from these every other module builds what it needs (gradient,
Hessian blocks ``E'' n n^T - (f/l) (I - n n^T)``, stress, moduli, the minimizers' curvature
bound, round-off floors). Its forms:

* **float64 in numpy** (:class:`ContactLaw`'s ``energy``, ``force``, ``stiffness``): the analyses;
* **float64 compiled by numba** (:class:`NumbaForm`): the pair loops of the energy, gradient and
  Hessian (:mod:`athermal.model.contact`) call these scalar functions; a law's own form gets the
  loops compiled once more for it (:func:`athermal.model.loops.kernels`);
* **JAX** (``jax_pair``, ``jax_total``): the JAX engine's pair sums;
* **double-double** (:meth:`ContactLaw.half_steps` and :func:`power_pair_dd`): the certificate's
  sums beyond float64 (:mod:`athermal.certify.extended`).

:class:`PowerContact` ``E = k delta^alpha / alpha`` (``alpha`` = 2 Hooke, 2.5 Hertz) is the
package's law and has every form. ``docs/howto/law.md`` shows how to add another.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from .. import _double as dd
from .._jit import _jit
from .._portable import power, power_of
from ..errors import InputError

FloatArray = NDArray[np.float64]


class NumbaForm(NamedTuple):
    """A law's float64 form for the compiled pair loops: three numba functions of scalars.

    ``pair(delta, k, alpha) -> (e, f)``: the force ``f`` at overlap ``delta >= 0`` (0 at 0) and
    a term ``e`` whose sum over the contacts, passed to ``total(sum, alpha)``, is the energy;
    ``curvature(delta, l, k, alpha) -> (a, c)`` for an overlapping pair at distance ``l``: its
    Hessian block is ``(a / l^2) b b^T - c I`` (``b`` the separation), i.e.
    ``a = E'' + f / l`` and ``c = f / l``. ``alpha`` is the law's :attr:`ContactLaw.alpha`."""

    pair: Any
    total: Any
    curvature: Any


class ContactLaw(ABC):
    """The energy of one contact as a function of its overlap, and its derivatives.

    A subclass gives :attr:`alpha` and the numpy forms; :attr:`numba` for relaxations on the
    numba engine (without it only the analyses run); ``jax_pair`` for the JAX engine;
    ``half_steps`` for certification. It must be hashable and compare by value (a frozen
    dataclass is): compiled forms are kept by law."""

    name: str = "law"
    numba: NumbaForm | None = None

    @property
    @abstractmethod
    def alpha(self) -> float:
        """The exponent of the energy at small overlap, ``E ~ delta^alpha``: the scaling near
        jamming (pressure ``~ Delta phi^(alpha - 1)``) and the round-off model use it."""

    @abstractmethod
    def energy(self, delta: FloatArray, k: FloatArray | float) -> FloatArray:
        """``E`` of each contact with overlap ``delta > 0`` ``(M,)`` and stiffness ``k``."""

    @abstractmethod
    def force(self, delta: FloatArray, k: FloatArray | float) -> FloatArray:
        """``f = dE/d delta`` ``(M,)``, > 0 (repulsive)."""

    @abstractmethod
    def stiffness(self, delta: FloatArray, k: FloatArray | float) -> FloatArray:
        """``d^2 E / d delta^2`` ``(M,)`` (force / length); the minimizers' curvature bound
        takes it as the norm of a contact's Hessian block (``>= f / l``, as for small
        overlaps)."""

    def energy_unit(self, k: float, length: float) -> float:
        """A typical energy: that of an overlap ``length`` in units of ``delta f(delta)``
        (``k length^alpha`` for a power law)."""
        return length * float(self.force(np.array([length]), k)[0])

    def jax_pair(self, overlap: Any, stiffness: Any) -> tuple[Any, Any]:
        """JAX: per-pair energy terms and forces ``(P,)`` (whose ``jax_total`` of the summed
        terms is the energy) at ``overlap >= 0`` (0 for pairs apart)."""
        raise InputError(f"law {self.name}: it has no JAX form; relax it with --backend numba")

    def jax_total(self, total: Any) -> Any:
        """JAX: the energy from the sum of :meth:`jax_pair`'s energy terms."""
        return total

    def half_steps(self) -> int:
        """The double-double form: ``2 (alpha - 1)`` for a power law whose force is a product
        of the overlap and its square root (:func:`power_pair_dd`); raises
        :class:`InputError` when the law has none."""
        raise InputError(
            f"law {self.name}: extended precision (certification) has no form of this law"
        )


class LawContacts:
    """What a set of contacts gives through its ``law`` from its ``overlap`` and ``stiffness``
    (each ``(M,)``) and unit ``normal`` ``(M, d)``: forces, stiffnesses, energies (the pairs'
    :class:`~athermal.model.contact.Contacts` and the walls'
    :class:`~athermal.model.walls.WallContacts`)."""

    law: ContactLaw
    overlap: FloatArray
    stiffness: FloatArray

    @property
    def normal(self) -> FloatArray:
        """Unit normals ``(M, d)``, along the force on the particle (``i``)."""
        raise NotImplementedError

    @property
    def force_magnitude(self) -> FloatArray:
        """The law's ``f(delta)`` ``(M,)``, > 0 (repulsive)."""
        return self.law.force(self.overlap, self.stiffness)

    @property
    def normal_stiffness(self) -> FloatArray:
        """The law's ``E''(delta)`` ``(M,)`` (force / length)."""
        return self.law.stiffness(self.overlap, self.stiffness)

    @property
    def force(self) -> FloatArray:
        """The force on each contact's particle ``(M, d)``: ``f n``."""
        return self.force_magnitude[:, None] * self.normal

    @property
    def energy(self) -> FloatArray:
        """The law's ``E(delta)`` of each contact ``(M,)``."""
        return self.law.energy(self.overlap, self.stiffness)


@_jit
def power_pair(delta, k, alpha):  # type: ignore[no-untyped-def]
    """:class:`PowerContact`'s ``pair``: ``(f delta, f)`` with ``f = k delta^(alpha-1)``, fast paths
    for alpha = 2, 2.5, 3."""
    if alpha == 2.0:
        f = k * delta
    elif alpha == 2.5:
        f = k * delta * np.sqrt(delta)
    elif alpha == 3.0:
        f = k * delta * delta
    else:
        f = k * power_of(delta, alpha - 1.0)
    return f * delta, f


@_jit
def power_total(twice, alpha):  # type: ignore[no-untyped-def]
    """:class:`PowerContact`'s ``total``: ``sum f delta / alpha``."""
    return twice / alpha


@_jit
def power_curvature(delta, dist, k, alpha):  # type: ignore[no-untyped-def]
    """:class:`PowerContact`'s ``curvature``: ``kappa (alpha - 1 + delta/l)`` and ``kappa delta/l``
    with ``kappa = k delta^(alpha-2)``."""
    if alpha == 2.0:
        kappa = k
    elif alpha == 2.5:
        kappa = k * np.sqrt(delta)
    else:
        kappa = k * power_of(delta, alpha - 2.0)
    ratio = delta / dist
    return kappa * (alpha - 1.0 + ratio), kappa * ratio


@numba.njit(cache=True, inline="always")
def power_pair_dd(dh, dl, k, half_steps, alpha):  # type: ignore[no-untyped-def]
    """:class:`PowerContact` in double-double: energy ``k delta^alpha / alpha`` and force
    ``k delta^(alpha - 1)`` at overlap ``dh + dl``, each ``(hi, lo)``, with
    ``delta^(alpha - 1) = delta^(half_steps / 2)``."""
    fh, fl = dd.power(dh, dl, half_steps)
    fh, fl = dd.mul(fh, fl, k, 0.0)
    uh, ul = dd.mul(fh, fl, dh, dl)
    uh, ul = dd.div(uh, ul, alpha, 0.0)
    return uh, ul, fh, fl


@dataclass(frozen=True)
class PowerContact(ContactLaw):
    """``E = k delta^alpha / alpha``, ``f = k delta^(alpha-1)``, ``E'' = (alpha - 1) k
    delta^(alpha-2)`` for ``alpha >= 2`` (seed eqs. for ``E_c`` and its derivatives)."""

    exponent: float = 2.0
    name = "power"
    numba = NumbaForm(power_pair, power_total, power_curvature)

    def __post_init__(self) -> None:
        alpha = float(self.exponent)
        if not np.isfinite(alpha) or alpha < 2.0:
            raise InputError(
                f"alpha: contact exponent must be a finite number >= 2, got {self.exponent!r}"
            )
        object.__setattr__(self, "exponent", alpha)

    @property
    def alpha(self) -> float:
        """The exponent."""
        return self.exponent

    def energy(self, delta: FloatArray, k: FloatArray | float) -> FloatArray:
        """``k delta^alpha / alpha``."""
        return k * power(delta, self.exponent) / self.exponent

    def force(self, delta: FloatArray, k: FloatArray | float) -> FloatArray:
        """``k delta^(alpha-1)``."""
        return k * power(delta, self.exponent - 1.0)

    def stiffness(self, delta: FloatArray, k: FloatArray | float) -> FloatArray:
        """``(alpha - 1) k delta^(alpha-2)``."""
        return k * (self.exponent - 1.0) * power(delta, self.exponent - 2.0)

    def energy_unit(self, k: float, length: float) -> float:
        """``k length^alpha``."""
        return k * float(power(length, self.exponent))

    def jax_pair(self, overlap: Any, stiffness: Any) -> tuple[Any, Any]:
        """``k delta^alpha`` and ``k delta^(alpha-1)`` (``alpha`` static: a traced one is a
        general power, ``docs/decisions.md``, "The contact exponent is static")."""
        return stiffness * overlap**self.exponent, stiffness * overlap ** (self.exponent - 1.0)

    def jax_total(self, total: Any) -> Any:
        """The summed ``k delta^alpha`` over alpha."""
        return total / self.exponent

    def half_steps(self) -> int:
        """``2 (alpha - 1)`` as an integer: the double-double force ``delta^(alpha - 1)`` is a
        product of ``delta`` and its square root. Raises :class:`InputError` for another
        alpha."""
        steps = 2.0 * (self.exponent - 1.0)
        if steps != round(steps) or steps < 2.0:
            raise InputError(
                "alpha: extended precision takes alpha = 2, 2.5, 3, ... (2 (alpha - 1) an "
                f"integer >= 2), got {self.exponent}"
            )
        return round(steps)
