"""The gyro's bias and scale, learnt from spans of windows where mice and gyro agree.

The gyro reads g = (1 + s) a + b T + n per window: a the turn, b its bias (rad/s), s its
scale error (an MPU-6050's sensitivity is within 3 % of its datasheet's).  Both are
learnt online: the bias wherever the mice tell the turn (exactly when standing still),
the scale in turns.

Per window the mice's turn is far noisier than over a span: a report stamped a little late
moves counts from one window to the next, so each window's turn is off by as much as the
next one's is off the other way.  Over a span of windows only the counts moved across the
span's two edges remain.  So (b, s) is not learnt window by window (as if those errors were
independent, which would learn slowly and over-confidently), but once a span (``SPAN_S``)
from the span's summed innovation

    E = sum_k (g_k - (1 + s_hat) a_k - b_hat T) = -H dx + sum_k (n_gyro,k - (1 + s_hat) n_mice,k)

with H = [n T, sum_k a_k], dx the estimate's error, and variance S = H P H^T + R, R the
mice's white errors summed, the timing variances of the span's first and last windows (its
two edges) and the gyro's white noise, each mouse term times (1 + s_hat)^2.  The edges'
own, not twice the span's mean: a span of still windows but for a sudden start at its end
has a mean a span's length smaller than that edge's variance, and one such span taught the
scale 0.03 off (and the bias, reset by the spans that then failed, took the rest).

E^2 / S is chi-square (1 dof) when both tell the truth: a span that fails it teaches
nothing, unless the mice it holds are trusted (three or more that agree, or a standstill):
then the gyro's bias moved, and
b is learnt again from that span (its variance reset; the scale's kept, and not taught by
the span: a clip in a fast turn would read as a new scale).  Until the mice's timing is
learnt (stampspread.py), R's timing is a cautious guess (stamps 0-4 ms late), which a span
passes or fails to learn from; but a trusted span that passes under the guess and fails at
the timing learnt so far (``sure``) may be a jump as well: it teaches nothing, and is a
jump if the span before it did the same, its E of the same sign (a late stamp's error in a
span is its edges', which the next span starts with the other way; a jump's stays).  Under
the guess alone, a 3.7 deg/s jump 1 s into the motion passed three spans of a slow turn
and was learnt as a scale 6.6 % off (5 degrees in 15 s); taken as a jump from one such
span, a square's first start with stamps 0-4 ms late relearnt its bias 0.08 deg/s off
(0.43 to 0.90 degree at the end of a 30 s drive).  A jump's span may hold windows from
before it (it fails where the jump began, anywhere in it), so the bias's variance stays at
least the jump the span shows after it is learnt from, and the next span learns the rest
of it: otherwise the scale took it in a steady turn (an 8.8 deg/s jump 1.1 s into the
motion: 5 degrees off).

The mice's stamps may lag the gyro's on average (a host stamping 0-4 ms late: 2 ms), and
a lag d moves E by d times the change of the turn rate across the span's edges (taken as
the gyro's rate in its last window less that in its first): a few per cent of a span's
turn where a turn starts or ends, nothing in steady motion.  Neither b nor s explains it;
R holds it at LAG_SIGMA (the first turn's spans taught the scale the lag), and a trusted
span that fails is a bias jump only if it fails with a lag of LAG_MAX too: a jump shows in
steady motion as well, a lag's error only with a change of rate (spans at a turn's end
read as jumps had the bias relearnt at 1-2 deg/s against a true 0.5).

A window the judge leaves out of the pose (GyroFusion.judged) is left out of its span too,
and the span's sum telescopes no more across it (``hole``).

Between renewals the error dx is constant, and a heading made with the gyro drifts by
H_k dx / (1 + s_hat) a window: ``cross``, the covariance of the heading's error with dx,
carries that (GyroFusion.window adds -2 kappa / (1 + s_hat) H_k cross to each window's
heading variance).
"""

from __future__ import annotations

import math

from mousedom.fusion import chi2

SPAN_S = 0.25  # seconds of windows per renewal
# The scale error's standard deviation before anything is learnt: an MPU-6050's
# sensitivity tolerance (PS-MPU-6000A-00 rev. 3.4, table 6.1: +-3 %)
SCALE_SIGMA = 0.03
# How well the mice know a turn's size: their CPIs are calibrated to about this, so the
# gyro's scale is not learnt closer to theirs than this over a span's turn
MICE_TURN_SCALE = 0.003
# How far the mice's stamps may lag the gyro's on average (s), which nothing learns: a
# host stamps its reports "a few ms" late (DESIGN.md; 0-4 ms: 2 ms on average), a gyro's
# low-pass filter delays its samples a few ms the other way.  LAG_SIGMA is R's, LAG_MAX
# the most: a trusted span that fails by no more than LAG_MAX gives where the turn rate
# changed is not read as a bias jump (module docstring)
LAG_SIGMA = 0.002
LAG_MAX = 0.006

Vec2 = list[float]
Mat2 = list[list[float]]


def _hph(h: Vec2, p: Mat2) -> float:
    return h[0] * (p[0][0] * h[0] + p[0][1] * h[1]) + h[1] * (p[1][0] * h[0] + p[1][1] * h[1])


def _ph(p: Mat2, h: Vec2) -> Vec2:
    return [p[0][0] * h[0] + p[0][1] * h[1], p[1][0] * h[0] + p[1][1] * h[1]]


class BiasLearner:
    """The gyro's (bias, scale) estimate, their covariance P, ``cross`` and the span being
    summed (see the module docstring)."""

    def __init__(
        self,
        sigma: float,
        walk: float,
        density: float,
        period: float,
        false_alarm: float = 1e-4,
        scale_sigma: float = SCALE_SIGMA,
    ) -> None:
        self.bias = 0.0  # rad/s
        self.scale = 0.0  # the scale error s: the gyro reads (1 + s) times the turn
        self._prior = [[sigma * sigma, 0.0], [0.0, scale_sigma * scale_sigma]]
        self.p = [row[:] for row in self._prior]
        self.cross = [0.0, 0.0]  # cov(heading error, (bias, scale) error)
        self.owed = 0.0  # heading (rad) the renewals since the last take_owed give back
        # sum of kappa / (1 + s_hat) a_k over every window since the heading was set: the
        # scale is the same for all of them, so a better estimate of it is owed by all
        self.turned = 0.0
        self._walk = walk * walk * period  # the bias's variance's growth per window
        self._white = density * density * period  # one window's white turn noise
        self._period = period
        self._span = max(1, round(SPAN_S / period))
        self._threshold = chi2.quantile(1.0 - false_alarm, 1)
        # the sign of the last span's E where it failed only at the mice's timing as
        # learnt so far (``renew``), 0 if it did not
        self._doubt = 0.0
        self._reset_span()

    def _reset_span(self) -> None:
        self._n = 0
        self._e = 0.0
        self._turn = 0.0  # the mice's turn, summed: H's second element
        self._white_sum = 0.0  # the mice's white variance, summed
        # the timing variances of the span's first and last windows: counts a report
        # stamped late moves between windows inside the span stay in its sum; only those
        # moved across its two edges remain (see the module docstring)
        self._timing_first = 0.0
        self._timing_last = 0.0
        # the same at the rig's timing as learnt so far, not guessed (GyroFusion._timing)
        self._sure_first = 0.0
        self._sure_last = 0.0
        # the gyro's rate (rad/s) in the span's first and last windows: a lag d of the
        # mice's stamps moves the span's sum by d times their difference
        self._rate_first = 0.0
        self._rate_last = 0.0
        self._holes = 0.0  # the innovations of the span's windows left out, squared
        self._ncov = 0.0  # the heading's noise with E's (see the module)
        self._used = [0.0, 0.0]  # sum of kappa / (1 + s_hat) H_k: how the heading used them
        self._trusted = True  # every window's mice trusted (three that agree, or still)

    @property
    def var(self) -> float:
        """The bias's variance."""
        return self.p[0][0]

    @property
    def sigma(self) -> float:
        return math.sqrt(self.p[0][0])

    @property
    def walk(self) -> float:
        """The bias's variance's growth per window."""
        return self._walk

    def h(self, a: float) -> Vec2:
        """One window's H: how the turn's reading moves with (bias, scale)."""
        return [self._period, a]

    def hph(self, a: float) -> float:
        """The variance one window's reading of a turn ``a`` gets from (bias, scale)."""
        return _hph(self.h(a), self.p)

    def predict(self) -> None:
        """A window passes: the bias may have wandered."""
        self.p[0][0] += self._walk

    def _bias_reset(self) -> None:
        """The bias's variance back to its prior (the scale's kept: see ``relearn``)."""
        self.p = [[max(self.p[0][0], self._prior[0][0]), 0.0], [0.0, self.p[1][1]]]

    def relearn(self) -> None:
        """The bias moved far: its variance reset, the span dropped.  The scale's is kept:
        a MEMS gyro's bias jumps (a knock, heat) but its scale does not, and what looks
        like a new scale to mice that win a disagreement is a gyro clipped at its range in
        a fast turn; learnt as a scale, a clip turned every window's heading since the
        start by the scale's change (tens of degrees over a drive)."""
        self._bias_reset()
        self._reset_span()

    def take_owed(self) -> float:
        """The heading owed by the renewals so far (then none)."""
        owed, self.owed = self.owed, 0.0
        return owed

    def corrected(self, turn: float) -> float:
        """The gyro's ``turn`` with the bias and scale taken out."""
        return (turn - self.bias * self._period) / (1.0 + self.scale)

    def carry(self, kappa: float, a: float) -> float:
        """The window's heading took ``kappa`` of the gyro's turn (``a`` the turn), with
        (bias, scale)'s error: returns the heading variance it owes the cross term, and
        carries that error in ``cross``."""
        g = kappa / (1.0 + self.scale)
        h = self.h(a)
        drift = -2.0 * g * (h[0] * self.cross[0] + h[1] * self.cross[1])
        ph = _ph(self.p, h)
        self.cross = [self.cross[0] - g * ph[0], self.cross[1] - g * ph[1]]
        return drift

    def observe(
        self, e: float, a: float, white: float, timing: float, kappa: float, trusted: bool,
        rate: float = 0.0, sure: float | None = None,
    ) -> None:  # fmt: skip
        """One window of the span: its innovation ``e`` (g - (1 + s) a - b T), the mice's
        turn ``a``, their white and timing variances, the gyro's share ``kappa`` in the
        heading, whether its mice are trusted, and the gyro's ``rate`` (its turn over T,
        rad/s: a lag's error in the span is in how it changed), and ``sure``, the timing
        variance at the rig's timing as learnt so far (None: ``timing``)."""
        sure = timing if sure is None else sure
        k1 = 1.0 + self.scale
        self._n += 1
        self._e += e
        self._turn += a
        self._white_sum += k1 * k1 * white
        if self._n == 1:
            self._timing_first = k1 * k1 * timing
            self._sure_first = k1 * k1 * sure
            self._rate_first = rate
        self._timing_last = k1 * k1 * timing
        self._sure_last = k1 * k1 * sure
        self._rate_last = rate
        self._ncov += kappa * self._white / k1 - (1.0 - kappa) * k1 * (white + timing)
        self._used[0] += kappa / k1 * self._period
        self._used[1] += kappa / k1 * a
        self.turned += kappa / k1 * a
        self._trusted = self._trusted and trusted
        # tested every window (a bias that jumped is seen within a few), learnt from once a
        # span
        if self._n >= self._span or not self._agrees():
            self.renew()

    def hole(self, e: float) -> None:
        """A moving window inside the span that the judge left out of the pose (and so of
        the span), its innovation ``e``.  The span's sum telescopes no more across it:
        what a late stamp moved into or out of the window stays in its neighbours, and a
        window is judged mostly where that was much (e beyond the judge's threshold), so
        the span errs by about e: R holds e^2 more.  Without, holes in a pair's first turn
        with stamps 0-4 ms late (1.6 mrad each) taught the gyro's scale 1 % off in one
        span, its sigma cut to 0.004.  (Summed into the span instead, as a window with
        e^2 more variance, one mouse's heading fared worse: 1.6 degrees median over 12
        drives against 0.6.)"""
        if math.isfinite(e):  # (before the span's first window: its first edge is e's)
            self._holes += e * e

    def _span_h(self) -> Vec2:
        return [self._n * self._period, self._turn]

    def _rest(self, lag: float, sure: bool = False) -> float:
        """R, the mice's stamps lagging the gyro's by ``lag`` (its sigma, seconds); ``sure``:
        their timing as learnt so far, not guessed."""
        mice_scale = (MICE_TURN_SCALE * self._turn) ** 2
        edges = (self._sure_first + self._sure_last if sure else
                 self._timing_first + self._timing_last) + self._holes  # fmt: skip
        lagged = (lag * (self._rate_last - self._rate_first)) ** 2
        return self._white_sum + edges + self._n * self._white + mice_scale + lagged

    def _agrees(self, lag: float = LAG_SIGMA, sure: bool = False) -> bool:
        """Whether the span so far passes the test (see the module docstring), its mice's
        stamps lagging the gyro's by ``lag``, their timing as learnt so far (``sure``) or
        guessed."""
        s = _hph(self._span_h(), self.p) + self._rest(lag, sure)
        return self._e * self._e <= self._threshold * s

    def renew(self) -> bool | None:
        """End the span: learn from it if it agrees (or its mice are trusted); whether it
        agreed (None: no window in it).  The heading the span's windows made with the
        estimate before is owed what the new one gives them (``owed``: the tracker turns
        the pose by it, as the mice's learnt scales give theirs back)."""
        if not self._n:
            return None
        # a jump: trusted mice, and failing even with a lag of LAG_MAX; where it fails so
        # only at their timing as learnt so far, not at the guess, it is a jump if the
        # span before did the same way, and teaches nothing (module docstring)
        jumped = self._trusted and not self._agrees(LAG_MAX)
        doubt = 0.0
        if self._trusted and not jumped and not self._agrees(LAG_MAX, sure=True):
            doubt = math.copysign(1.0, self._e)
            jumped = doubt == self._doubt
        self._doubt = 0.0 if jumped else doubt
        agreed = self._agrees() and not jumped and not doubt
        if not agreed and not jumped:
            self._reset_span()  # (failing, but no jump: module docstring)
            return False
        h = self._span_h()
        shown = 0.0
        if jumped:  # the bias moved: learnt again from this span, alone (see relearn)
            # as uncertain as the jump the span shows, at least: from the prior's sigma
            # (1 deg/s) alone, a span of mice whose timing is not learnt yet (its R that of
            # stamps 0-4 ms late) learnt a third of an 8.8 deg/s jump, and the scale took
            # part of the rest in a steady turn (5 degrees off in 15 s)
            self._bias_reset()
            shown = self._e / (self._n * self._period)
            self.p[0][0] = max(self.p[0][0], shown * shown)
            h = [h[0], 0.0]  # (the scale, independent of it now, learns nothing here)
        s = _hph(h, self.p) + self._rest(LAG_SIGMA)
        ph = _ph(self.p, h)
        k = [ph[0] / s, ph[1] / s]
        # E = -H dx + N: the estimate moves against the error it reads
        step = [k[0] * self._e, k[1] * self._e]
        self.bias += step[0]
        self.scale += step[1]
        # the corrected turn (g - b T) / (1 + s) of each window moves by -(T db + a ds) /
        # (1 + s), and the heading took kappa of it: the bias's change is owed by this
        # span's windows (it wanders), the scale's by every window since the heading was set
        self.owed -= self._used[0] * step[0] + self.turned * step[1]
        hx = h[0] * self.cross[0] + h[1] * self.cross[1]
        self.cross = [self.cross[0] - k[0] * hx + k[0] * self._ncov,
                      self.cross[1] - k[1] * hx + k[1] * self._ncov]  # fmt: skip
        self.p = [[self.p[i][j] - k[i] * ph[j] for j in range(2)] for i in range(2)]
        if jumped:  # and after it: the jump began anywhere in the span (module docstring)
            self.p[0][0] = max(self.p[0][0], shown * shown)
        self._reset_span()
        return agreed
