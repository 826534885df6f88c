"""Faults seen through the gyro: which of mice and gyro to believe when they disagree.

The gyro's agreement statistic (fusion/gyro.py: e^2 / S, chi-square with one degree of
freedom when both tell the truth) is tested at the fault screen's false-alarm rate.  A
window that fails it is judged, not fused:

- every mouse in the solve was silent, yet the gyro turned beyond its bias: the robot
  moved and the mice did not see it (lifted, or a dead one on a one-mouse rig).  They are
  blamed; the heading is the gyro's and the translation unknown (not counted, and the
  window is marked inconsistent).  Unless two mice stand still (at two points, every
  turn moves one: both would have lost the floor at once): then the gyro's bias jumped
  (fusion/gyro.py, ``judged``); three or more win as below.
- three or more mice that agree among themselves (their own screen passed): the gyro is
  wrong (saturated, a bias jump).  It is left out of the window and its bias is not
  learnt from it; after ``RELEARN_S`` of such windows in a row its bias's uncertainty is
  reset, so that it is learnt again from the mice (a bias that jumped).
- fewer mice: each one in turn is left out, and the rest are solved with the gyro's turn
  as one more row.  The explanation is taken if it is the only one that fits, or the only
  one that leaves out a silent mouse (a lifted mouse reads nothing: two mice on an axle,
  one lifted while driving straight, read as a pivot that the gyro does not see).
  Otherwise the window is inconsistent: the mice's motion is kept, nobody is blamed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from mousedom.fusion import chi2

RELEARN_S = 0.5  # gyro disagreeing with agreeing mice this long: its bias is learnt again
UNDER = 0.75  # a mouse reading less than this share of its motion under-reads (lifted)
# A window's translation that no mouse saw: taken as none, with the variance of a robot
# at this speed (m/s: a floor robot's pace) over the window
UNSEEN_SPEED = 1.0

Matrix3 = list[list[float]]


class MiceView(NamedTuple):
    """What the judge needs of a window's mice."""

    d: Sequence[Sequence[float]]  # each mouse's body-frame displacement (x, y), metres
    used: Sequence[bool]  # the mice in the solve
    consistent: bool  # whether their own screen found them consistent
    # Each mouse's learnt factor of its error in proportion to motion, as the screen tested
    # this window with (noisemodel's lam_r: >= 1, learnt from the mice's redundancy, where
    # stamps a few ms late make it several times the config's rho); None: not learnt
    learnt: Sequence[float] | None = None


class Verdict(NamedTuple):
    """A failed agreement judged: the window's motion, who is blamed, what it says."""

    q: list[float]
    c: Matrix3
    blamed: tuple[int, ...]  # mice left out for disagreeing with the gyro
    gyro_used: bool  # the gyro's turn is in q
    consistent: bool  # False: nobody could be blamed, or the translation is unknown
    learn: bool  # the window may teach the bias (never when judged)


class GyroJudge:
    """The rig's geometry and test threshold, for judging disagreements (module doc)."""

    def __init__(
        self,
        positions: np.ndarray,
        sigma: np.ndarray,
        cols: tuple[int, ...],
        false_alarm: float,
        still: Sequence[float],
        relative: float = 0.0,
        period: float = 0.01,
    ) -> None:
        self.positions = np.asarray(positions, dtype=float)
        self.sigma = np.asarray(sigma, dtype=float)
        self.cols = cols  # the twist's components the model solves for
        self.threshold = chi2.quantile(1.0 - false_alarm, 1)
        self.false_alarm = false_alarm
        self.period = period  # the window's length, seconds
        self.last_blamed: int | None = None  # the mouse blamed in the window before
        self.still = list(still)  # below these a reading is no count, metres
        # Each mouse's reading error in proportion to its motion (robust.relative_noise):
        # a report stamped a little late moves counts from one window to the next, which
        # q's covariance does not hold and the gyro, stamped by the kernel, does not share
        self.relative = relative

    def _relative2(self, mice: MiceView, idx: list[int]) -> np.ndarray:
        """The squared proportional error of the mice ``idx``: rho^2, times each one's
        learnt factor where the screen learns them (MiceView.learnt)."""
        rho2 = np.full(len(idx), self.relative**2)
        if mice.learnt is not None:
            rho2 *= np.asarray(mice.learnt)[idx]
        return rho2

    def moved(self, mice: MiceView) -> bool:
        """Whether any mouse in the solve counted anything."""
        return any(
            abs(d[0]) > s or abs(d[1]) > s
            for d, u, s in zip(mice.d, mice.used, self.still, strict=True)
            if u
        )

    def timing_var(self, mice: MiceView) -> float:
        """The variance the turn of the mice in the solve gets from their errors in
        proportion to their motion: the rotation of a weighted rigid fit, 1 / sum_i w_i
        |p_i - c|^2 with w_i = 1 / (rho_i |d_i|)^2 and c the weighted centre (Kim &
        Lee's estimator's turn for isotropic errors), less that of their sigma alone;
        rho_i the config's relative_noise, times the root of mouse i's learnt factor."""
        if not self.relative:
            return 0.0
        idx = [i for i, u in enumerate(mice.used) if u]
        if len(idx) == 1:  # Hong's one mouse ahead of the axle: a = d_y / p_x
            i = idx[0]
            px = self.positions[i][0]
            moved2 = mice.d[i][0] ** 2 + mice.d[i][1] ** 2
            return float(self._relative2(mice, idx)[0]) * moved2 / (px * px) if px else 0.0
        if len(idx) < 2:
            return 0.0
        p = self.positions[idx]
        d2 = np.array([mice.d[i][0] ** 2 + mice.d[i][1] ** 2 for i in idx])
        base = self.sigma[idx] ** 2
        both = base + self._relative2(mice, idx) * d2

        def turn_var(var: np.ndarray) -> float:
            w = 1.0 / var
            centre = (w[:, None] * p).sum(axis=0) / w.sum()
            spread = float((w * ((p - centre) ** 2).sum(axis=1)).sum())
            return 1.0 / spread if spread > 0.0 else 0.0

        return max(0.0, turn_var(both) - turn_var(base))

    def stamp_var(self, mice: MiceView) -> float:
        """The part of ``timing_var`` that a late stamp moves between windows, which
        stampspread.py learns the rig's factor of: a late stamp moves counts along a
        mouse's motion, and Hong's one mouse turns only its sideways ones (a = d_y / p_x).
        Its forward counts (driving straight, most of a drive) move no turn across a
        window's edge: learnt against the whole motion, those windows held the factor
        near 1, several times short of what stamps 0-4 ms late give a turning window (the
        judge took those for faults, each leaving in the heading what the stamp had moved
        into its neighbour).  The config's rho stays on the whole motion (it holds a
        CPI's or a mounting's error too, which the forward counts do move).  Two or more
        mice: ``timing_var``."""
        idx = [i for i, u in enumerate(mice.used) if u]
        if len(idx) != 1:
            return self.timing_var(mice)
        if not self.relative:
            return 0.0
        i = idx[0]
        px = self.positions[i][0]
        side2 = mice.d[i][1] ** 2
        return float(self._relative2(mice, idx)[0]) * side2 / (px * px) if px else 0.0

    def sigma_turn_var(self, mice: MiceView) -> float:
        """The turn's variance of the mice in the solve from their sigma alone (a count
        each): what a window without counts knows of the turn while the robot may creep."""
        idx = [i for i, u in enumerate(mice.used) if u]
        if len(idx) < 2:
            return math.inf
        p = self.positions[idx]
        w = 1.0 / self.sigma[idx] ** 2
        centre = (w[:, None] * p).sum(axis=0) / w.sum()
        spread = float((w * ((p - centre) ** 2).sum(axis=1)).sum())
        return 1.0 / spread if spread > 0.0 else math.inf

    def gyro_heading(self, c: Matrix3, a: float, var_a: float) -> Verdict:
        """The heading the gyro's turn ``a`` (variance ``var_a``), the translation none."""
        c2 = [row[:] for row in c]
        c2[0][2] = c2[1][2] = c2[2][0] = c2[2][1] = 0.0
        c2[2][2] = var_a
        return Verdict([0.0, 0.0, a], c2, (), True, True, False)

    def silent_mice_blamed(self, c: Matrix3, a: float, var_a: float, mice: MiceView) -> Verdict:
        """The gyro turned by ``a`` (variance ``var_a``), faster than a bias, while every
        used mouse was still: they are blamed, the translation is unknown."""
        blamed = tuple(i for i, u in enumerate(mice.used) if u)
        return self._unseen(self.gyro_heading(c, a, var_a), blamed)

    def _unseen(self, v: Verdict, blamed: tuple[int, ...]) -> Verdict:
        """``v`` with no mouse left to see the translation: the mice ``blamed``, the
        window inconsistent, the translation taken as none with the variance of a robot
        at UNSEEN_SPEED (an unknown motion is not a small one)."""
        c2 = [row[:] for row in v.c]
        unseen = (UNSEEN_SPEED * self.period) ** 2
        c2[0][0] += unseen
        c2[1][1] += unseen
        return v._replace(c=c2, blamed=blamed, consistent=False)

    def leave_one_out(
        self, q: Sequence[float], c: Matrix3, a: float, var_a: float, mice: MiceView
    ) -> Verdict:
        """Two or fewer mice that disagree with the gyro: the one explanation that fits,
        or the only one that leaves out a mouse reading less than half of what the rest
        and the gyro say it should (a lifted mouse reads little or nothing; no healthy
        one reads motion that did not happen); with one mouse left, that one blamed if
        it under-reads the gyro's turn so, the heading the gyro's.  Otherwise none."""
        used = [i for i, u in enumerate(mice.used) if u]
        if len(used) == 1:
            j = used[0]
            if self._under_reads(j, [0.0, 0.0, a], mice.d):
                return self._unseen(self.gyro_heading(c, a, var_a), (j,))
            return Verdict(list(q), c, (), False, False, False)
        fits = []
        for j in used:
            others = [i for i in used if i != j]
            solved = self.solve_with_gyro(others, mice.d, a, var_a)
            if solved is not None:
                fits.append((j, solved))
        if len(fits) == 1:
            j, (q2, c2) = fits[0]
            return Verdict(q2, c2, (j,), True, True, False)
        # the mouse that under-reads most, if clearly the most (half the next one's share);
        # where two under-read alike (one mouse reading half in a pivot looks like the
        # other reading double), the one blamed in the window before, if it is one of them:
        # a fault lasts
        shares = sorted((self._share(j, s[0], mice.d), j, s) for j, s in fits)
        under = [(share, j, s) for share, j, s in shares if share < UNDER]
        pick = None
        if under and (len(shares) == 1 or shares[1][0] > 2.0 * shares[0][0] + 0.1):
            pick = shares[0]
        elif self.last_blamed is not None:
            pick = next((u for u in under if u[1] == self.last_blamed), None)
        if pick is None:
            return Verdict(list(q), c, (), False, False, False)
        _, j, (q2, c2) = pick
        return Verdict(q2, c2, (j,), True, True, False)

    def _under_reads(self, j: int, q: Sequence[float], d: Sequence[Sequence[float]]) -> bool:
        """Whether mouse ``j`` read less than UNDER of what the motion ``q`` moves it by."""
        return self._share(j, q, d) < UNDER

    def _share(self, j: int, q: Sequence[float], d: Sequence[Sequence[float]]) -> float:
        """How much of what the motion ``q`` moves mouse ``j`` by it read (inf: the motion
        moves it by less than three of its sigma, too little to tell)."""
        px, py = self.positions[j]
        expected = math.hypot(q[0] - q[2] * py, q[1] + q[2] * px)
        if expected <= 3.0 * self.sigma[j]:
            return math.inf
        return math.hypot(d[j][0], d[j][1]) / expected

    def solve_with_gyro(
        self, mice: list[int], d: Sequence[Sequence[float]], a: float, var_a: float
    ) -> tuple[list[float], Matrix3] | None:
        if not mice:
            return None
        """Weighted least squares of ``mice`` (Kim & Lee's rows) with the gyro's turn as
        one more row; None if it lacks rank or its residual fails the test."""
        rows, obs, weights = [], [], []
        for i in mice:
            px, py = self.positions[i]
            w = 1.0 / self.sigma[i] ** 2
            rows += [[1.0, 0.0, -py], [0.0, 1.0, px]]
            obs += [d[i][0], d[i][1]]
            weights += [w, w]
        rows.append([0.0, 0.0, 1.0])
        obs.append(a)
        weights.append(1.0 / var_a)
        cols = list(self.cols)
        design = np.array(rows)[:, cols]
        w = np.array(weights)
        info = design.T @ (design * w[:, None])
        if np.linalg.matrix_rank(info) < len(cols):
            return None
        cov = np.linalg.inv(info)
        x = cov @ (design.T @ (w * np.array(obs)))
        residual = np.array(obs) - design @ x
        dof = len(obs) - len(cols)
        if dof > 0 and float(np.sum(w * residual**2)) > chi2.quantile(1.0 - self.false_alarm, dof):
            return None
        q = [0.0, 0.0, 0.0]
        c3 = np.zeros((3, 3))
        for k, col in enumerate(cols):
            q[col] = float(x[k])
        c3[np.ix_(cols, cols)] = cov
        return q, c3.tolist()
