"""Chi-square tail probabilities and quantiles for whole degrees of freedom, without scipy.

The consistency test of the fusion (``robust``) needs the (1 - alpha) quantile of the
chi-square distribution for 1..2N degrees of freedom.  For whole k the survival function has
a closed form (Abramowitz & Stegun 26.4.4-26.4.5): with h = x/2,
  even k: Q = exp(-h) sum_{j<k/2} h^j / j!
  odd k:  Q = erfc(sqrt h) + exp(-h) sum_{j<(k-1)/2} h^(j+1/2) / Gamma(j + 3/2)
and the quantile is found by bisection on it (Q falls monotonically in x).  Past x = 1200
(pooled sums of hundreds of degrees) the terms are summed in logs, where the direct sums
would overflow.
"""

from __future__ import annotations

import functools
import math
import statistics


def survival(x: float, dof: int) -> float:
    """P(X > x) for X ~ chi-square with ``dof`` (a positive whole number) degrees."""
    if dof < 1 or int(dof) != dof:
        raise ValueError(f"degrees of freedom must be a positive whole number, got {dof!r}")
    if x <= 0:
        return 1.0
    h = 0.5 * x
    if h > _DIRECT_H:
        return _survival_logs(h, dof)
    if dof % 2 == 0:
        term, total = 1.0, 1.0
        for j in range(1, dof // 2):
            term *= h / j
            total += term
        return math.exp(-h) * total
    total = math.erfc(math.sqrt(h))
    term = math.sqrt(h) / math.gamma(1.5)  # j = 0
    acc = 0.0
    for j in range((dof - 1) // 2):
        if j:
            term *= h / (j + 0.5)
        acc += term
    return total + math.exp(-h) * acc


# Beyond this h the sums' terms (up to about e^h) and exp(-h) leave float64's range
# (e^709 overflows, e^-709 is subnormal): the sum is then taken term by term in logs.
_DIRECT_H = 600.0


def _survival_logs(h: float, dof: int) -> float:
    """``survival``'s sums with each term exp(log term - h), added exactly (fsum)."""
    log_h = math.log(h)
    if dof % 2 == 0:
        return math.fsum(math.exp(j * log_h - math.lgamma(j + 1) - h) for j in range(dof // 2))
    terms = (math.exp((j + 0.5) * log_h - math.lgamma(j + 1.5) - h) for j in range((dof - 1) // 2))
    return math.erfc(math.sqrt(h)) + math.fsum(terms)


@functools.lru_cache(maxsize=512)
def quantile(p: float, dof: int) -> float:
    """The x with P(X <= x) = p: the test threshold for a false-alarm rate 1 - p."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must be inside (0, 1), got {p!r}")
    tail = 1.0 - p
    lo, hi = 0.0, max(1.0, 2.0 * dof)
    while survival(hi, dof) > tail:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if survival(mid, dof) > tail:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    return hi


# Past this many degrees a quantile of a tie's sums (robust.Screen._tie_break) is the
# Wilson-Hilferty approximation (the median within 7e-6 of the exact at 100 degrees,
# closer beyond): the exact quantile's survival sums grow with the degrees, and past 1200
# they are summed in logs at tens of milliseconds a call, where a tie held for seconds asks
# for one of every window's new sum.
_EXACT_DOF = 100


@functools.lru_cache(maxsize=512)
def sum_quantile(p: float, dof: int) -> float:
    """``quantile`` for a sum of many windows' statistics: exact up to _EXACT_DOF degrees,
    then k (1 - 2 / 9k + z_p sqrt(2 / 9k))^3 (z_p: the standard normal's p quantile)."""
    if dof <= _EXACT_DOF:
        return quantile(p, dof)
    v = 2.0 / (9.0 * dof)
    return dof * (1.0 - v + statistics.NormalDist().inv_cdf(p) * math.sqrt(v)) ** 3


def median(dof: int) -> float:
    """The median of chi-square with ``dof`` (a positive whole number) degrees
    (``sum_quantile``'s: past _EXACT_DOF, k (1 - 2 / 9k)^3)."""
    return sum_quantile(0.5, dof)
