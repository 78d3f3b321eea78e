"""The contact sums of a packing in double-double arithmetic (:mod:`athermal._double`).

:func:`contact_sums` evaluates, for positions held as ``x_hi + x_lo`` with float64 radii and
cell (exact inputs), every listed pair's separation, distance and overlap, and over the
overlapping pairs the energy, the gradient ``(N, d)`` and the virial ``sum l (x) f`` in
double-double (the contact law's double-double form, :mod:`athermal.model.law`): residual
forces far below float64's round-off floor of positions of order one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from .._double import add, div, mul, sqrt, sub, two_prod, two_sum
from .._portable import transform
from ..model.contact import ContactModel, Contacts
from ..model.law import power_pair_dd
from ..model.neighbors import build_neighbor_list
from ..model.packing import Packing

PRECISION = "double-double (float64 pairs hi + lo, 106-bit significand, ~1e-32 relative)"
"""What the certificates state as the precision used."""


@numba.njit(cache=True)
def contact_sums(  # type: ignore[no-untyped-def]
    xh, xl, radii, first, second, images, h, stiffness, bonded, half_steps, alpha,
    overlap_h, overlap_l, grad_h, grad_l, virial_h, virial_l,
):  # fmt: skip
    """The pair sums of a packing in double-double; returns the energy ``(hi, lo)``.

    ``xh + xl`` ``(N, d)`` are the positions, ``radii`` ``(N,)`` and the cell ``h`` ``(d, d)``
    float64; pair ``p`` joins ``first[p]`` and ``second[p]`` through the lattice image
    ``images[p]`` ``(d,)`` (integers as float64: separation ``x_i - x_j + h n``), with stiffness
    ``stiffness[p]``; energy and force by the power law's double-double form
    (:func:`~athermal.model.law.power_pair_dd`, ``delta^(alpha - 1) = delta^(half_steps /
    2)``). Written: every pair's
    overlap ``r_i + r_j - |x_i - x_j + h n|`` (negative: a gap) into ``overlap_h/l`` ``(P,)``;
    over the pairs that overlap, and the ``bonded[p]`` ones whatever their overlap (springs of
    rest length ``r_i + r_j``, pulling when apart: an even ``half_steps``), ``dE/dx`` into
    ``grad_h/l`` ``(N, d)`` and ``sum l (x) f`` (``l`` the separation, ``f`` the force on
    ``i``) into ``virial_h/l`` ``(d, d)``, all three overwritten.
    """
    d = xh.shape[1]
    grad_h[:] = 0.0
    grad_l[:] = 0.0
    virial_h[:] = 0.0
    virial_l[:] = 0.0
    eh, el = 0.0, 0.0
    sep_h = np.empty(d)
    sep_l = np.empty(d)
    for p in range(first.size):
        i, j = first[p], second[p]
        r2h, r2l = 0.0, 0.0
        for a in range(d):
            sh, sl = sub(xh[i, a], xl[i, a], xh[j, a], xl[j, a])
            for b in range(d):
                if images[p, b] != 0.0:
                    th, tl = two_prod(h[a, b], images[p, b])
                    sh, sl = add(sh, sl, th, tl)
            sep_h[a], sep_l[a] = sh, sl
            qh, ql = mul(sh, sl, sh, sl)
            r2h, r2l = add(r2h, r2l, qh, ql)
        rh, rl = sqrt(r2h, r2l)
        ch, cl = two_sum(radii[i], radii[j])
        dh, dl = sub(ch, cl, rh, rl)
        overlap_h[p], overlap_l[p] = dh, dl
        if dh <= 0.0 and not bonded[p]:
            continue
        uh, ul, fh, fl = power_pair_dd(dh, dl, stiffness[p], half_steps, alpha)
        eh, el = add(eh, el, uh, ul)
        ch, cl = div(fh, fl, rh, rl)  # force per unit separation
        for a in range(d):
            gh, gl = mul(ch, cl, sep_h[a], sep_l[a])  # force on i along a
            grad_h[i, a], grad_l[i, a] = sub(grad_h[i, a], grad_l[i, a], gh, gl)
            grad_h[j, a], grad_l[j, a] = add(grad_h[j, a], grad_l[j, a], gh, gl)
            for b in range(d):
                vh, vl = mul(sep_h[b], sep_l[b], gh, gl)
                virial_h[b, a], virial_l[b, a] = add(virial_h[b, a], virial_l[b, a], vh, vl)
    return eh, el


@numba.njit(cache=True)
def displace(xh, xl, step):  # type: ignore[no-untyped-def]
    """``x += step`` in double-double, in place (``xh``, ``xl``, ``step`` ``(N, d)``)."""
    for i in range(xh.shape[0]):
        for a in range(xh.shape[1]):
            xh[i, a], xl[i, a] = add(xh[i, a], xl[i, a], step[i, a], 0.0)


@dataclass(frozen=True, eq=False)
class PairSums:
    """The pair sums at ``hi + lo``: overlaps ``(P,)`` (negative: gaps), gradient ``(N, d)``,
    virial ``(d, d)``, energy, each as ``(hi, lo)``."""

    overlap: tuple[NDArray[np.float64], NDArray[np.float64]]
    gradient: tuple[NDArray[np.float64], NDArray[np.float64]]
    virial: tuple[NDArray[np.float64], NDArray[np.float64]]
    energy: tuple[float, float]

    def largest_force(self) -> float:
        """``max_i |grad_i|`` (the norm of each particle's ``hi + lo``)."""
        g = self.gradient[0] + self.gradient[1]
        return float(np.sqrt((g * g).sum(axis=1)).max())


class NearPairs:
    """The pairs of a packing within ``reach`` mean diameters of contact (surface to surface),
    with their lattice images and stiffnesses, fixed once listed; :meth:`sums` evaluates them at
    double-double positions."""

    def __init__(self, packing: Packing, model: ContactModel, reach: float) -> None:
        skin = reach * 2.0 * float(packing.radii.mean())
        nlist = build_neighbor_list(packing.positions, packing.radii, packing.cell, skin=skin)
        self.first = nlist.first.astype(np.int64)
        self.second = nlist.second.astype(np.int64)
        self.images = np.ascontiguousarray(nlist.images[nlist.code])
        typeid = model.typeid(packing)
        self.stiffness = np.ascontiguousarray(model.kmat[typeid[self.first], typeid[self.second]])
        self.half_steps = model.law.half_steps()
        self.alpha = float(model.alpha)
        self.law = model.law
        self.packing = packing

    def separations(self, hi: NDArray[np.float64]) -> NDArray[np.float64]:
        """``x_i - x_j + h n`` ``(P, d)`` of every pair at ``hi``, float64."""
        return hi[self.first] - hi[self.second] + transform(self.images, self.packing.cell.h)

    def contacts(
        self, hi: NDArray[np.float64], overlap: NDArray[np.float64], keep: NDArray[np.bool_]
    ) -> Contacts:
        """The pairs ``keep`` as contacts at ``hi`` with the (double-double) ``overlap``."""
        sep = self.separations(hi)[keep]
        return Contacts(
            self.first[keep],
            self.second[keep],
            sep,
            np.linalg.norm(sep, axis=1),
            overlap[keep],
            self.stiffness[keep],
            self.law,
        )

    def sums(
        self,
        hi: NDArray[np.float64],
        lo: NDArray[np.float64],
        radii: NDArray[np.float64] | None = None,
        bonded: NDArray[np.bool_] | None = None,
    ) -> PairSums:
        """The pair sums at ``hi + lo`` ``(N, d)`` (:func:`contact_sums`), with the packing's
        radii or ``radii``, and no pair ``bonded`` unless given."""
        p, (n, d) = self.first.size, hi.shape
        overlap = (np.empty(p), np.empty(p))
        gradient = (np.empty((n, d)), np.empty((n, d)))
        virial = (np.empty((d, d)), np.empty((d, d)))
        energy = contact_sums(
            np.ascontiguousarray(hi),
            np.ascontiguousarray(lo),
            self.packing.radii if radii is None else np.ascontiguousarray(radii),
            self.first,
            self.second,
            self.images,
            np.ascontiguousarray(self.packing.cell.h),
            self.stiffness,
            np.zeros(p, dtype=np.bool_) if bonded is None else np.ascontiguousarray(bonded),
            self.half_steps,
            self.alpha,
            *overlap,
            *gradient,
            *virial,
        )
        return PairSums(overlap, gradient, virial, (float(energy[0]), float(energy[1])))
