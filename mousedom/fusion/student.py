"""Student's t for whole degrees of freedom, without scipy (as ``chi2``).

The scale learner judges its estimate by a jackknife over blocks of evidence
(``scalefit.jackknife``), whose standard error has as many degrees of freedom as there are
blocks less one: a handful at first.  Judged by the normal's 3 sigma, an estimate from four
blocks would be applied on a 1-in-20 chance; t's quantile for their 3 degrees is 9.2.

For whole k, A(t|k) = P(|T| < t) has a closed form (Abramowitz & Stegun 26.7.3-26.7.4),
theta = atan(t / sqrt k):
  odd k:  A = 2/pi (theta + sin theta (cos theta + 2/3 cos^3 theta + ...
                   + (2 4 ... (k-3)) / (1 3 ... (k-2)) cos^(k-2) theta))   (the sum: k > 1)
  even k: A = sin theta (1 + 1/2 cos^2 theta + ... + (1 3 ... (k-3)) / (2 4 ... (k-2))
                   cos^(k-2) theta)
and the quantile is found by bisection on it (A rises monotonically in t).
"""

from __future__ import annotations

import functools
import math


def two_sided(t: float, dof: int) -> float:
    """P(|T| < t) for T ~ Student's t with ``dof`` (a positive whole number) degrees."""
    if dof < 1 or int(dof) != dof:
        raise ValueError(f"degrees of freedom must be a positive whole number, got {dof!r}")
    if t <= 0:
        return 0.0
    theta = math.atan(t / math.sqrt(dof))
    c2, s = math.cos(theta) ** 2, math.sin(theta)
    if dof % 2:
        total, term = 0.0, math.cos(theta)
        for j in range(1, (dof - 1) // 2 + 1):  # cos^(2j-1) theta times (2j-2)!! / (2j-1)!!
            total += term
            term *= c2 * (2 * j) / (2 * j + 1)
        return 2.0 / math.pi * (theta + s * total) if dof > 1 else 2.0 * theta / math.pi
    total, term = 0.0, 1.0
    for j in range(dof // 2):  # cos^(2j) theta times (2j-1)!! / (2j)!!
        total += term
        term *= c2 * (2 * j + 1) / (2 * j + 2)
    return s * total


@functools.lru_cache(maxsize=256)
def quantile(p: float, dof: int) -> float:
    """The t with P(|T| < t) = p (0 < p < 1), to a relative 1e-12."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must be between 0 and 1, got {p!r}")
    lo, hi = 0.0, 1.0
    while two_sided(hi, dof) < p:
        hi *= 2.0
    while hi - lo > 1e-12 * hi:
        mid = 0.5 * (lo + hi)
        if two_sided(mid, dof) < p:
            lo = mid
        else:
            hi = mid
    return hi
