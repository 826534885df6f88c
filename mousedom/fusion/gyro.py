"""A MEMS gyro's yaw rate in the window's solve, its bias and scale slowly varying states.

Each window the mice give the twist increment q = (u_x, u_y, a) with its covariance C
(models.py, after the fault screen).  The gyro's samples, integrated over the same window
(the tracker closes them with a count function, as a mouse's counts), give one more
reading of the turn:

    g = (1 + s) a + b T + n,    n ~ N(0, N^2 T)

with b the gyro's bias (rad/s), s its scale error, T the window's length and N the rate
noise density (rad/s/sqrt(Hz)): the integral of white rate noise over T has variance
N^2 T (the angle random walk).  The bias drifts as a random walk of density W
(rad/s/sqrt(s)): between two windows its variance grows by W^2 T.

With (b, s) known to the covariance P (gyrobias.py, which learns them once a span), the
window's update is the Kalman update of q by the one reading g (H_q = [0, 0, 1 + s]):

    innovation  e = g - (1 + s) a_mice - b T,    S = (1 + s)^2 C_aa + h P h^T + N^2 T
    q' = q + (1 + s) C[:, a] e / S               C' = C - (1 + s)^2 C[:, a] C[a, :] / S

with h = [T, a_mice]: the same as adding the gyro's row to the weighted least squares of
the mice (Kim & Lee's estimator with one more row, weighted by 1 / (N^2 T + h P h^T):
tests/test_gyro_fusion.py).  At a standstill the mice say exactly that nothing turned
(C_aa is nothing), so the window measures the bias alone; while moving, the redundancy of
mice and gyro does.  e^2 / S is chi-square with one degree of freedom when mice and gyro
both tell the truth: the test of their agreement (gyrojudge.py judges a failure).

What the heading is made of is the user's choice (``choices.GYRO_USES``): ``both`` (the
update above), ``mice`` (bias and scale are still learnt, the pose is the mice's) or
``gyro`` (the heading is the gyro's alone, a = (g - b T) / (1 + s), and the translation
the mice's given that heading: u = u_mice + C_ua / C_aa (a - a_mice)).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mousedom.config import GyroConfig
from mousedom.fusion.choices import GYRO as GYRO  # (re-exported: the gyro's name)
from mousedom.fusion.choices import GYRO_USES
from mousedom.fusion.gyrobias import BiasLearner
from mousedom.fusion.gyrojudge import RELEARN_S, GyroJudge, MiceView, Verdict
from mousedom.fusion.stampspread import StampSpread

# What the config does not say: the bias's random walk and how far off it may be at the
# start (simgyro.py says where these figures come from).
DEFAULT_BIAS_WALK = math.radians(0.001)  # rad/s/sqrt(s)
DEFAULT_BIAS_SIGMA = math.radians(1.0)  # rad/s

Matrix3 = list[list[float]]


@dataclass(frozen=True)
class GyroNoise:
    """A gyro's error figures, SI units."""

    density: float  # rate noise density N, rad/s/sqrt(Hz)
    bias_walk: float  # bias random walk W, rad/s/sqrt(s)
    bias_sigma: float  # the bias's standard deviation before anything is learnt, rad/s


# No mouse counting for this long is a standstill (seconds): a mouse moving at 1 mm/s
# counts every 25 ms at 1000 CPI
STILL_S = 0.25

# A turn slower than this, seen by the gyro while every mouse stands still, is its bias
# moving, not the robot (rad/s: 3 deg/s, ten times a robot's creep and far beyond a
# calibrated MEMS gyro's bias change over a drive)
STILL_TURN = math.radians(3.0)

# A gyro whose config gives no sample rate samples at least this often: the longest span a
# sample covers (a sample after a longer gap covers this much, as a mouse's report does).
SLOWEST_HZ = 50.0


def gyro_noise(config: GyroConfig) -> GyroNoise:
    """The figures of a config's ``gyro:`` section: its noise density, and the bias terms
    no config states (DEFAULT_BIAS_WALK, DEFAULT_BIAS_SIGMA)."""
    return GyroNoise(config.noise, DEFAULT_BIAS_WALK, DEFAULT_BIAS_SIGMA)


def gyro_period(config: GyroConfig) -> float:
    """The longest span one sample covers: its period, or SLOWEST_HZ's when unknown."""
    return 1.0 / (config.sample_hz or SLOWEST_HZ)


def gyro_turns(
    t: np.ndarray, rate: np.ndarray, last_t: float, period: float, bridge: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples (stamps, rad/s) as the angle each turned: its rate times the span it
    covers, the time since the sample before (``last_t`` for the first) where that is at
    most ``bridge``, else ``period`` (a sample after a silence: the count function's rule
    for a report's span, ``CountFunction.bridge``).  Not clipped at one period: stamps
    jitter, and a device runs at its own rate, not always the config's (a span of 1.1
    periods clipped to one lost a tenth of every turn: 5 degrees in a half turn and a
    quarter; a 250 Hz gyro configured at 300 Hz, 14 degrees).  A first sample ever
    (``last_t`` -inf) only starts the spans: its own is unknown, so it turns nothing.
    Returns the stamps, the angles and the spans."""
    gaps = np.diff(t, prepend=last_t)
    spans = np.where(gaps <= bridge, np.maximum(gaps, 0.0), period)
    spans = np.where(np.isfinite(gaps), spans, 0.0)
    return t, rate * spans, spans


class GyroWindow(NamedTuple):
    """What the gyro said of one window, and what became of it."""

    turn: float  # g: the samples' integral over the window, radians
    bias: float  # the bias after the window, rad/s
    bias_sigma: float  # its standard deviation, rad/s
    stat: float  # e^2 / S: chi-square (1 dof) when mice and gyro agree
    scale: float  # the scale error learnt so far: the gyro reads (1 + scale) times the turn
    used: bool  # whether it entered the pose (False: no samples, or use = mice)

    def row(self) -> list[float]:
        """PoseRow.gyro: turn, bias, bias sigma, agreement, scale."""
        return [self.turn, self.bias, self.bias_sigma, self.stat, self.scale]


class Judged(NamedTuple):
    """A window's motion after the gyro (``GyroFusion.judged``)."""

    q: list[float]
    c: Matrix3
    report: GyroWindow
    blamed: tuple[int, ...]  # mice left out for disagreeing with the gyro
    consistent: bool  # False: mice and gyro disagreed and nobody could be blamed


class GyroFusion:
    """One window at a time: the update of the module docstring, and the bias it learns.

    The tracker's two solving paths share one (the bias is carried from window to window,
    as the pose is); ``judged`` and ``window`` take one window's Python floats, the array
    path calling them window by window (the bias is sequential)."""

    def __init__(
        self,
        noise: GyroNoise,
        period: float,
        use: str = "both",
        judge: GyroJudge | None = None,
    ) -> None:
        if use not in GYRO_USES:
            raise ValueError(f"gyro use {use!r}: choose one of {', '.join(GYRO_USES)}")
        self.noise = noise
        self.period = period
        self.use = use
        self.judge = judge  # faults seen through the gyro (gyrojudge.py); None: not judged
        self._disagree = 0  # windows in a row the gyro disagreed with agreeing mice
        self._quiet = 0  # windows in a row no mouse in the solve counted anything
        false_alarm = judge.false_alarm if judge is not None else 1e-4
        self.state = BiasLearner(
            noise.bias_sigma, noise.bias_walk, noise.density, period, false_alarm
        )
        self._white_var = noise.density**2 * period  # the integral's white noise
        self.spread = StampSpread(period)  # the mice's timing, learnt against the gyro

    def heading_set(self) -> None:
        """The heading was set from outside (reset, fix): its error no longer owes
        anything to the bias's."""
        self.state.cross = [0.0, 0.0]
        self.state.turned = 0.0

    def window(
        self,
        q: Sequence[float],
        c: Matrix3,
        turn: float | None,
        ok: bool,
        still: bool = False,
        extra: float = 0.0,
        trusted: bool = False,
        sure: float | None = None,
    ) -> tuple[list[float], Matrix3, GyroWindow]:
        """The window's (q, C) with the gyro's ``turn`` (None: no samples) folded in as
        ``use`` says; ``ok`` False (the mice lacked rank) leaves q alone and learns
        nothing (no motion is invented).  ``still``: the robot stood still (GyroFusion
        .judged): nothing turned, exactly (C_aa = 0 whatever the mice's noise model says
        of a window without counts), the window measures the bias alone and the heading
        stays, whatever ``use`` (a zero-velocity update).  ``extra``: variance of the
        mice's turn from their timing (GyroJudge.timing_var), which q's covariance does
        not hold; ``trusted``: the mice would win a disagreement (gyrobias.py); ``sure``:
        ``extra`` at the rig's timing as learnt so far, not guessed (``_timing``; None: as
        ``extra``).

        The window's innovation goes to the bias learner, which learns once a span
        (gyrobias.py).  The bias's error is the same from one window to the next: a
        heading made with it drifts by T times it every window, which independent
        windows' variances would not add up to; with kappa the gyro's share of the
        window's turn (C_aa / S for both, 1 for gyro, 0 for mice), the heading's variance
        grows by C'_aa - 2 kappa T cross (cross: the covariance of the heading's error
        with the bias's, BiasLearner.cross)."""
        st = self.state
        st.predict()
        if turn is None or not ok:
            return list(q), c, self._report(math.nan, math.nan, False)
        mice_c = c
        timing = 0.0 if still else extra
        if timing:
            c = [row[:] for row in c]
            c[2][2] += timing
        k1 = 1.0 + st.scale
        a_mice = 0.0 if still else q[2]
        caa = 0.0 if still else c[2][2]
        e = turn - k1 * a_mice - st.bias * self.period
        s = k1 * k1 * caa + st.hph(a_mice) + self._white_var
        kappa = 0.0 if still else {"both": k1 * k1 * caa / s, "gyro": 1.0, "mice": 0.0}[self.use]
        drift = st.carry(kappa, a_mice)  # the heading's error with (bias, scale)'s
        a_gyro, var_gyro = st.corrected(turn), (self._white_var + st.hph(a_mice)) / (k1 * k1)
        sure_t = timing if sure is None or still else min(timing, sure)
        st.observe(
            e, a_mice, caa - timing, timing, kappa, trusted or still, turn / self.period, sure_t
        )
        report = self._report(turn, e * e / s, kappa > 0.0)
        if kappa == 0.0:  # the mice's (use = mice, or a standstill)
            return list(q), mice_c, report
        if self.use == "both":
            ca = [row[2] * k1 for row in c]
            q2 = [v + g * e / s for v, g in zip(q, ca, strict=True)]
            c2 = [[c[i][j] - ca[i] * ca[j] / s for j in range(3)] for i in range(3)]
            c2[2][2] = max(0.0, c2[2][2] + drift)
            return q2, c2, report
        # use = gyro: the heading is the gyro's, corrected with its bias and scale; the
        # translation the mice's given that heading
        r = var_gyro
        lx, ly = (c[0][2] / caa, c[1][2] / caa) if caa > 0.0 else (0.0, 0.0)
        q2 = [q[0] + lx * (a_gyro - q[2]), q[1] + ly * (a_gyro - q[2]), a_gyro]
        cxx = c[0][0] - lx * lx * caa + lx * lx * r
        cxy = c[0][1] - lx * ly * caa + lx * ly * r
        cyy = c[1][1] - ly * ly * caa + ly * ly * r
        c2 = [[cxx, cxy, lx * r], [cxy, cyy, ly * r], [lx * r, ly * r, max(0.0, r + drift)]]
        return q2, c2, report

    def _report(self, turn: float, stat: float, used: bool) -> GyroWindow:
        st = self.state
        return GyroWindow(turn, st.bias, st.sigma, stat, st.scale, used)

    def _verdict(
        self, q: Sequence[float], c: Matrix3, a: float, var_a: float, mice: MiceView,
        n_used: int, still: bool, slow: bool,
    ) -> Verdict:  # fmt: skip
        """A failed agreement's verdict (``judged``), the gyro's corrected turn ``a``,
        ``n_used`` of the mice in the solve."""
        judge = self.judge
        assert judge is not None  # (judged asks first)
        if n_used >= 3 and (still or mice.consistent):
            # three mice that agree, or stand still (they do not all lose the floor at
            # once): the gyro is wrong (saturated, a bias that moved)
            return Verdict(list(q), c, (), False, True, False)
        if slow:
            # a slow turn seen only by the gyro: the robot starting to turn (the gyro sees
            # it before the mice count) or its bias moving: the heading takes the gyro's
            return judge.gyro_heading(c, a, var_a)
        if still:
            return judge.silent_mice_blamed(c, a, var_a, mice)
        return judge.leave_one_out(q, c, a, var_a, mice)

    def _timing(
        self, q: Sequence[float], c: Matrix3, turn: float, mice: MiceView, judge: GyroJudge,
        silent: bool,
    ) -> tuple[float, float]:  # fmt: skip
        """A moving window's timing variance of the mice's turn beyond q's covariance (the
        judge's ``extra``), and the window taught to the stamps' spread: the config's rho
        on the whole motion, and the rig's timing in excess of it on what a late stamp
        moves (GyroJudge.stamp_var), by the learnt factor (stampspread.py; a host's "few
        ms" until it is learnt).  Also what it is at the factor learnt so far, not that
        guess (``sure``: the bias learner's test of a jump, gyrobias.py)."""
        unit, stamp = judge.timing_var(mice), judge.stamp_var(mice)
        extra = unit + stamp * (self.spread.in_use - 1.0)
        sure = unit + stamp * (self.spread.factor - 1.0)
        if not silent and mice.consistent:
            st, k1 = self.state, 1.0 + self.state.scale
            e = turn - k1 * q[2] - st.bias * self.period
            rest = k1 * k1 * c[2][2] + st.hph(q[2]) + self._white_var
            self.spread.observe(e, k1 * k1 * stamp, rest, tuple(mice.used))
        else:
            self.spread.gap()
        if silent:
            floor = judge.sigma_turn_var(mice) - c[2][2]
            if math.isfinite(floor):
                extra, sure = max(extra, floor), max(sure, floor)
        return extra, sure

    def judged(
        self, q: Sequence[float], c: Matrix3, turn: float | None, ok: bool, mice: MiceView
    ) -> Judged:
        """``window`` with the agreement test first: a window where mice and gyro disagree
        beyond the fault screen's false-alarm rate is judged (gyrojudge.py), not fused,
        and teaches the bias nothing.  Without a judge, or with use = mice, as ``window``
        (still: no used mouse counted)."""
        judge = self.judge
        if judge is None:
            return Judged(*self.window(q, c, turn, ok), (), True)
        # Still: no mouse in the solve counted for STILL_S.  A window without counts alone
        # is not: a mouse creeping at a few mm/s counts once in several windows.  Such a
        # window's zero turn is as uncertain as a count of each mouse (sigma), whatever
        # the noise model says of windows without counts.
        silent = not judge.moved(mice)
        self._quiet = self._quiet + 1 if silent else 0
        still = self._quiet * self.period >= STILL_S
        if turn is not None and not ok and self.use != "mice":
            # The mice in the solve lack rank (one left of two on an axle): with the gyro's
            # turn as one more row they may not
            self.spread.gap()
            st = self.state
            st.predict()
            k1 = 1.0 + st.scale
            a = st.corrected(turn)
            var_a = (self._white_var + st.hph(a)) / (k1 * k1)
            used = [i for i, u in enumerate(mice.used) if u]
            solved = judge.solve_with_gyro(used, mice.d, a, var_a)
            if solved is not None:
                q2, c2 = solved
                c2[2][2] = max(0.0, c2[2][2] + st.carry(1.0, a))
                return Judged(q2, c2, self._report(turn, math.nan, True), (), True)
            return Judged(list(q), c, self._report(turn, math.nan, False), (), True)
        if turn is None or not ok:
            self.spread.gap()
            return Judged(*self.window(q, c, turn, ok, still), (), True)
        if still:
            self.spread.gap()
        extra, sure = (0.0, 0.0) if still else self._timing(q, c, turn, mice, judge, silent)
        n_used = sum(1 for u in mice.used if u)
        trusted = n_used >= 3 and mice.consistent
        if self.use == "mice":
            return Judged(*self.window(q, c, turn, ok, still, extra, trusted, sure), (), True)
        st, t = self.state, self.period
        k1 = 1.0 + st.scale
        a_mice = 0.0 if still else q[2]
        caa = 0.0 if still else c[2][2] + extra
        e = turn - k1 * a_mice - st.bias * t
        hph = st.hph(a_mice) + st.walk * t * t  # (the window's own wander, as window adds)
        s = k1 * k1 * caa + hph + self._white_var
        stat = e * e / s
        if stat <= judge.threshold:
            self._disagree = 0
            judge.last_blamed = None
            return Judged(*self.window(q, c, turn, ok, still, extra, trusted, sure), (), True)
        slow = still and abs(e) <= STILL_TURN * t
        # Still mice against a gyro that turns faster than a bias moves: the robot turned
        # unseen (every mouse off the floor) or the gyro's bias jumped.  Two mice (at two
        # points: every turn moves one of them) would both have lost the floor at once:
        # the gyro is wrong, and its bias is learnt again from the standstill (blamed on
        # the mice instead, a 5 deg/s jump on a pair turned the heading 53 degrees in 12 s
        # of standstill, its sigma 0.4); the window is inconsistent, as two mice cannot
        # say which.  Three or more win outright (below, consistent).  One mouse cannot
        # tell: a robot starting to turn while its mouse is off the floor looks the same
        # (taken as a jump, such lifts ended 54 and 153 degrees off where the gyro kept 1).
        jumped = still and not slow and n_used == 2
        self._disagree = (self._disagree + 1 if trusted or still and n_used >= 3 or slow
                          or jumped else 0)  # fmt: skip
        if self._disagree * t >= RELEARN_S:
            # Disagreeing this long, window after window, with mice the gyro cannot beat
            # (three that agree or stand still; or a turn too slow to be the robot's): its
            # bias moved far, or was learnt wrong: learnt again from here
            st.relearn()
            self._disagree = 0
            return Judged(*self.window(q, c, turn, ok, still, extra, trusted, sure), (), True)
        st.predict()  # nothing learnt from a window judged
        if not still and not trusted:
            # the span it leaves errs by about as much (BiasLearner.hole); not where three
            # mice that agree blamed the gyro: its error was in this window alone
            st.hole(e)
        a = st.corrected(turn)
        var_a = (self._white_var + st.hph(a)) / (k1 * k1)
        if jumped:
            # (above): the mice's standstill kept, the window inconsistent (nobody blamed:
            # which of the two is not certain)
            verdict = Verdict(list(q), c, (), False, False, False)
        else:
            verdict = self._verdict(q, c, a, var_a, mice, n_used, still, slow)
        judge.last_blamed = verdict.blamed[0] if len(verdict.blamed) == 1 else None
        c2 = verdict.c
        if verdict.gyro_used:  # the heading's error takes (bias, scale)'s (see window)
            c2 = [row[:] for row in c2]
            c2[2][2] = max(0.0, c2[2][2] + st.carry(1.0, a))
        report = self._report(turn, stat, verdict.gyro_used)
        return Judged(verdict.q, c2, report, verdict.blamed, verdict.consistent)
