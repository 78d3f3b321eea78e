"""An independent reference for the double-double kernels: the pair sums of a packing in
Python's decimal arithmetic at 60 digits (each float64 converted exactly, every operation
correctly rounded)."""

from decimal import Decimal, getcontext

getcontext().prec = 60


def exact(hi: float, lo: float = 0.0) -> Decimal:
    """``hi + lo`` as a decimal, exactly."""
    return Decimal(hi) + Decimal(lo)


def decimal_sums(xh, xl, radii, h, first, second, images, k, alpha):
    """The pair sums by decimal arithmetic: overlaps, gradient, virial and energy."""
    n, d = xh.shape
    x = [[exact(xh[i, a], xl[i, a]) for a in range(d)] for i in range(n)]
    grad = [[Decimal(0)] * d for _ in range(n)]
    virial = [[Decimal(0)] * d for _ in range(d)]
    energy, overlaps = Decimal(0), []
    for p, (i, j) in enumerate(zip(first, second, strict=True)):
        sep = [
            x[i][a] - x[j][a] + sum(Decimal(h[a, b]) * Decimal(images[p, b]) for b in range(d))
            for a in range(d)
        ]
        r = sum(s * s for s in sep).sqrt()
        delta = Decimal(radii[i]) + Decimal(radii[j]) - r
        overlaps.append(delta)
        if delta <= 0:
            continue
        force = Decimal(k[p]) * delta ** (Decimal(alpha) - 1)  # decimal's power: exp(y ln x)
        energy += force * delta / Decimal(alpha)
        for a in range(d):
            f = force * sep[a] / r
            grad[i][a] -= f
            grad[j][a] += f
            for b in range(d):
                virial[b][a] += sep[b] * f
    return overlaps, grad, virial, energy
