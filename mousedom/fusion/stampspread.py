"""How far the mice's turn errs from their stamps, learnt against the gyro.

The gyro's test (fusion/gyro.py) and its bias's spans (gyrobias.py) take each window's
turn of the mice to err, beyond q's covariance, by ``GyroJudge.timing_var``: the config's
``robust.relative_noise`` (rho) of each mouse's motion.  That rho is what stamps up to a
millisecond late give; a host that stamps reports 0-4 ms late (DESIGN.md's "a few ms")
gives several times it, and a judge built on the config's then takes healthy windows for
faults and learns the bias and scale from the few that pass (a pair's heading 3 degrees
off after 30 s with the gyro, 0.2 without).  Nothing in the config can know the host; the
rig shows it.

What a stamp's lateness does is move counts across a window's edge: the turn edge k
misplaces (tau_k) is taken from window k and given to window k + 1.  So the innovation of
window k, e_k = g_k - (1 + s) a_k - b T, holds tau_k - tau_(k-1), and neighbouring
windows' innovations are correlated:

    E[e_k e_(k-1)] = -var(tau_(k-1)),

while everything else in them (the gyro's white noise, the mice's sigma, a split's
rounding) is independent from one window to the next and adds nothing to the product.  With
u_k the timing variance the config's rho gives window k (var(tau) about a half of each of
the two windows an edge bounds), the factor by which the rig's timing exceeds the config's
is

    lambda = -4 sum e_k e_(k-1) / sum (u_(k-1) + u_k),

summed over neighbouring windows in which the mice moved, were in the solve alike and were
not found faulty (a fault's errors run the same way for many windows and would pull lambda
down, never up), and in which u is at least the rest of the innovation's variance (the
gyro's white noise, the mice's sigma, the bias's uncertainty): the products of windows
whose turn the stamps cannot move (a robot driving straight, whose one mouse's turn comes
from its sideways counts alone) hold that noise and nothing of lambda, and summed against
their tiny u they made it anything up to MAX_FACTOR.  Forgetting with a half-life of
``HALF_LIFE_S``; ``factor`` is 1 (the config's rho) until ``MIN_PAIRS`` such windows were
seen, and never below 1: the config's rho is the least timing error the judge allows.  An
estimate, not a test: it moves the judge's threshold, never the pose.
"""

from __future__ import annotations

import math

HALF_LIFE_S = 60.0  # of the evidence
MIN_PAIRS = 100  # neighbouring moving windows (1 s at 100 Hz) before the factor is used (with
# 300, a pair's healthy windows the judge took for faults in the first 3 s taught the scale)
# The most the timing may exceed the config's rho by (in variance): rho 8 times the
# config's 0.05 is a window's motion 40 % wrong from its stamps alone, beyond any host; a
# learnt factor past it would let a faulty mouse through the gyro's test.
MAX_FACTOR = 64.0
# The factor taken until the rig's is learnt (``in_use``): a host's late stamps are not
# known yet.  At the config's 1, mice stamped 0-4 ms late had their healthy windows judged
# faults in their first second of motion (9-14 windows of a pair, each leaving the counts
# a late stamp moved into its neighbour in the heading: 0.6-0.9 degrees of a pair's 30 s
# drives), and the first turn's spans taught the gyro's scale (1 % off in one span).
# 16: stamps 0-4 ms late (DESIGN.md's "a few ms") against the 0-1 ms the config's rho is of.
EARLY_FACTOR = 16.0


class StampSpread:
    """The factor of the mice's timing variance against the config's (module doc)."""

    def __init__(self, period: float) -> None:
        self._keep = 0.5 ** (period / HALF_LIFE_S)
        self._prev: tuple[float, float, tuple[bool, ...]] | None = None
        self._num = 0.0  # -4 sum e_k e_(k-1), forgetting
        self._den = 0.0  # sum u_(k-1) + u_k, forgetting
        self._pairs = 0.0  # neighbouring windows seen, forgetting
        self.factor = 1.0

    def observe(self, e: float, u: float, rest: float, used: tuple[bool, ...]) -> None:
        """A moving window's innovation ``e``, its timing variance ``u`` at the config's
        rho and the rest of its variance ``rest``, ``used`` the mice in its solve."""
        if not u >= rest:  # (the module docstring; also u NaN)
            self._prev = None
            return
        prev, self._prev = self._prev, (e, u, used)
        if prev is None or prev[2] != used:
            return
        product = -4.0 * e * prev[0]
        if not math.isfinite(product):  # (a rate near the float's end: nothing to learn)
            return
        keep = self._keep
        self._num = keep * self._num + product
        self._den = keep * self._den + u + prev[1]
        self._pairs = keep * self._pairs + 1.0
        if self._pairs >= MIN_PAIRS:
            self.factor = min(MAX_FACTOR, max(1.0, float(self._num / self._den)))

    @property
    def known(self) -> bool:
        """Whether ``factor`` is learnt (MIN_PAIRS windows seen), not the prior 1."""
        return self._pairs >= MIN_PAIRS

    @property
    def in_use(self) -> float:
        """The factor the judge and the bias's spans take: ``factor`` once known,
        EARLY_FACTOR before."""
        return self.factor if self.known else max(self.factor, EARLY_FACTOR)

    def gap(self) -> None:
        """A window that gives no innovation to pair with (still, no turn, a fault)."""
        self._prev = None
