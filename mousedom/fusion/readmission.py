"""An excluded mouse's way back (robust.py's step 4): its windows judged, in groups, toward
its re-admission.

A mouse the screen excluded is re-admitted after ``readmit_s`` of windows in which it
agreed with the others (within its error and their prediction's) while they moved enough
to have shown the fault (``moved_enough``), and where the run's fit of a proportional fault
agrees (``run_agrees``); one its own sensor's evidence excluded, after a fifth of that once
the evidence is gone and it agrees.  Windows shorter than EVIDENCE_S are judged in groups
(``grouped``).  What it agreed in is told to the ``ledger`` (given back at its return),
and so is its re-admission.  ``robust.Screen`` holds one and calls it for each window of
an excluded mouse; the health it changes is the mouse's ``MouseHealth``.
"""

from __future__ import annotations

import math

import numpy as np

from mousedom.fusion.health import (
    INCONSISTENT,
    LOW_QUALITY,
    NONE,
    SATURATED,
    SILENT,
    TRACKING,
    MouseHealth,
)
from mousedom.fusion.ledger import Ledger
from mousedom.fusion.shortfall import SHORT

# An excluded mouse's windows are judged toward its re-admission in groups at least this
# long (``Readmission.grouped``): a window's motion shrinks with its length while the error that
# late stamps put in it does not (it is motion over the lateness, a few ms), so windows of
# 2.5-5 ms, each alone, seldom moved a mouse beyond that error: a healthy mouse excluded
# once (a false alarm) was never let back (a drive ended 37 mm off against 2 with fault
# handling off).  Summed over a group, the motion grows with the group and the lateness
# stays that of its edges.  A window of 10 ms or longer starts as a group of its own.
EVIDENCE_S = 0.01
# ... and a group goes on, up to this long, until the others moved the mouse enough to show
# a fault (_SHOWS times the test's threshold on the error not in proportion to the motion):
# where late stamps' learnt error is wide, windows of 10 ms seldom moved a mouse so far
# (5 in 1,300 on a far mouse behind a close pair), and a healthy mouse excluded once was
# never let back (63 of 155 lifts of one second stayed excluded to the drive's end; now
# none, tests/test_readmission_evidence.py).  A group's motion grows with its windows, its
# error not in proportion to the motion (summed as if independent) as their square root.
EVIDENCE_MAX_S = 0.25
_SHOWS = 4.0


def within(r: np.ndarray, cov: np.ndarray, thr2: float) -> bool:
    """Whether the residual r (2,) of covariance ``cov`` (2, 2) passes the test of two
    degrees of freedom whose threshold is ``thr2``."""
    if not np.all(np.isfinite(cov)):
        return True  # nothing predicts it: nothing to disagree with
    return float(r @ np.linalg.solve(cov, r)) <= thr2


def fresh_wait(h: MouseHealth) -> None:
    """A mouse's re-admission starts afresh (a new account, or gone): nothing behind, no
    fit from an earlier wait (``Readmission.waiting``)."""
    h.behind, h.fit_r, h.fit_info = 0, 0.0, 0.0
    h.behind_r, h.behind_cov = np.zeros(2), np.zeros((2, 2))
    h.group_n = 0


class Readmission:
    """Judges an excluded mouse's windows toward its re-admission (module docstring):
    how many windows it needs (``readmit``, ``readmit_evidence``), how they are grouped,
    and the test each group and run passes.  Holds no mouse's state: that is each
    ``MouseHealth``'s, and what it is owed the ledger's."""

    def __init__(
        self, window: float, readmit_s: float, thresholds: list[float], late_limit: int
    ) -> None:
        """``window``: the window's length (s); ``thresholds``: the screen's chi-square
        thresholds by degrees of freedom; ``late_limit``: the windows a late mouse may lag
        (``Lateness.limit``), as long as an excluded one may be behind."""
        self.readmit = max(1, math.ceil(readmit_s / window - 1e-9))
        self.readmit_evidence = max(1, self.readmit // 5)
        # the windows of a group (grouped): at least, and at most
        self._group = max(1, math.ceil(EVIDENCE_S / window - 1e-9))
        self._group_max = max(self._group, math.ceil(EVIDENCE_MAX_S / window - 1e-9))
        self._thr1, self._thr2 = thresholds[1], thresholds[2]
        self._late_limit = late_limit

    def waiting(
        self, ledger: Ledger, i: int, h: MouseHealth, di: np.ndarray, pi: np.ndarray,
        s2: float, not_proportional: float, pred_cov: np.ndarray, k: int, beyond: bool,
        reads_nothing: bool,
    ) -> None:  # fmt: skip
        """Mouse i, excluded before this window, waiting to be re-admitted: ``k`` windows
        judged at once (``grouped``), its reading ``di`` and prediction ``pi`` over them,
        its variance ``s2``, the part of it not in proportion to the motion and the
        prediction's covariance ``pred_cov``; ``beyond``: held out beyond the scale
        learner's bounds (judged, never let back: ``Screen.hold_beyond``);
        ``reads_nothing``: ``di`` is no reading (a silence).  What it agreed in and its
        re-admission go to ``ledger``."""
        thr2 = self._thr2
        # Excluded earlier: count the windows that would have shown its fault (the others
        # moved it well beyond its error) and where it agreed.  Each window is held to
        # the mouse's error and its prediction's (``pred_cov``): far from mice that fix
        # the turn poorly (a close pair and a far mouse), the prediction's error across
        # the line to them is many times the mouse's own, and a healthy mouse held to its
        # own alone never agrees again.  So that a fault that looser test lets by (an
        # under-read at low speed) is still told, the run is also judged as a whole
        # (``run_agrees``).  A window it disagrees in leaves it behind, as a late mouse
        # is, for up to ``lateness.limit`` windows: it agrees again once its residuals
        # summed since are within their summed error (the counts came), and its run goes
        # on; a mouse still behind after that starts a new run.
        r = di - pi
        cov = s2 * np.eye(2) + pred_cov
        alone = within(r, cov, thr2)
        caught_up = False
        if h.behind:
            if within(r + h.behind_r, cov + h.behind_cov, thr2):
                r, cov, caught_up = r + h.behind_r, cov + h.behind_cov, True  # paid back
            elif alone:
                # agrees now, but what it owed never came: not a lag; a run starts here
                self.end_run(ledger, i, h)
                h.good = 0
            h.behind = 0 if caught_up or alone else h.behind
        if not (alone or caught_up):
            if h.behind < self._late_limit:
                h.behind_r = r + (h.behind_r if h.behind else 0.0)
                h.behind_cov = cov + (h.behind_cov if h.behind else 0.0)
                h.behind += k
                return
            h.behind = 0
            self.end_run(ledger, i, h)
            h.good = 0
            h.reason = SILENT if reads_nothing else INCONSISTENT
            return
        # moved enough to show a fault: the others moved it beyond its own error, and
        # either it read as much (SHORT of it along it at least: the window a
        # lifted mouse lands in reads part of it, within a far mouse's wide tolerance,
        # and given back turned a heading by half a degree) or that motion is beyond the
        # window's tolerance of a reading of nothing too, the prediction's error with it.
        # (A far mouse, held to the others' poor prediction of it, passed in silence
        # while they slowed from a spin, still lifted: its run started there and gave
        # back their motion, a heading 1 degree off at its return.)
        p2 = float(pi @ pi)
        read2 = float(di @ di)
        moved = self.moved_enough(pi, not_proportional)
        shows = moved and (
            float(di @ pi) >= SHORT * p2
            or float(pi @ np.linalg.solve(not_proportional * np.eye(2) + pred_cov, pi)) > 4.0 * thr2
        )
        if h.good > 0 or (shows and k <= self._group):
            # a run starts where the mouse shows itself sound: before, a lifted mouse's
            # silence can pass where the motion's changes widen every tolerance.  A group
            # grown to show (``grouped``) counts toward the re-admission but is not given
            # back: it may begin before the mouse landed, and its tolerance, summed over
            # its windows, let the silence pass (11 mm given back, a drive 20 mm off)
            ledger.agree(i, r, 0.5 * float(np.trace(cov)))
        if h.good == 0:
            h.fit_r = h.fit_info = 0.0
        if moved and read2 > 0.0 and not caught_up:
            # along its own reading, whose direction the prediction's error does not
            # steer (along the prediction, that error would read as an under-read).  The
            # mouse's own noise n does steer it: (d - p) . d holds |n|^2, whose mean, the
            # trace of its covariance (2 s2), is taken off.  And the windows are chosen by
            # the others' motion, not by the reading, which chose long readings where the
            # motion was near the bar.  Each bias alone made a healthy mouse's g 0.05-0.2
            # (reading "over"), a run's fit grew tight enough to see it and failed, and
            # the mouse was never let back.
            u = di / math.sqrt(read2)
            var = float(u @ cov @ u)
            h.fit_r += (float(r @ di) - 2.0 * s2) / var
            h.fit_info += read2 / var
        if h.reason in (SATURATED, LOW_QUALITY):
            # Its own sensor said why, and says so no more: a fifth of the wait (a longer
            # one only loses a good mouse, here the one whose speed limit a fast rig
            # keeps crossing).
            h.good += k
            if h.good >= self.readmit_evidence:
                ledger.readmit(i, h.good)
                h.state, h.reason, h.good = TRACKING, NONE, 0
        elif shows:
            h.good += k
            if h.good >= self.readmit and not beyond:
                verdict = self.run_agrees(h)
                if verdict is False:  # the run disagrees as a whole: a new one starts
                    self.end_run(ledger, i, h)
                    h.good = 0
                elif verdict:
                    ledger.readmit(i, h.good)
                    h.state, h.reason, h.good = TRACKING, NONE, 0

    def moved_enough(self, p: np.ndarray, not_proportional: float) -> bool:
        """Whether the others moved an excluded mouse (prediction ``p``) far enough beyond
        its error not in proportion to the motion for a fault to show: what a group waits
        for (``grouped``), what a window must have to count toward re-admission and
        what the run's fit takes (``waiting``)."""
        return float(p @ p) > _SHOWS * self._thr2 * not_proportional

    def grouped(
        self, h: MouseHealth, di: np.ndarray, pi: np.ndarray, s2: float,
        not_proportional: float, pred_cov: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, float, float, np.ndarray, int] | None:  # fmt: skip
        """One more window of an excluded mouse's group: None while the group goes on
        (shorter than EVIDENCE_S, or the others have not yet moved the mouse enough to
        show a fault, ``moved_enough``, within EVIDENCE_MAX_S), else its reading,
        prediction, variance, variance not in proportion to the motion and prediction's
        covariance, each summed over its windows (the variances summed as if
        independent: a late count in one window is missing from the one before, so the
        sum's is smaller; the test is the stricter for it), and its windows."""
        if self._group_max == 1:
            return di, pi, s2, not_proportional, pred_cov, 1
        g = h.group
        if h.group_n == 0:
            g[:] = 0.0
        g[0:2] += di
        g[2:4] += pi
        g[4] += s2
        g[5] += not_proportional
        g[6:10] += pred_cov.ravel()
        h.group_n += 1
        if h.group_n < self._group:
            return None
        if h.group_n < self._group_max and not self.moved_enough(g[2:4], float(g[5])):
            return None
        k, h.group_n = h.group_n, 0
        return (g[0:2].copy(), g[2:4].copy(), float(g[4]), float(g[5]),
                g[6:10].reshape(2, 2).copy(), k)  # fmt: skip

    def end_run(self, ledger: Ledger, i: int, h: MouseHealth) -> None:
        """An excluded mouse's run of agreeing windows ends: banked to be given back at its
        re-admission (``ledger``) only where its fit agrees, having seen enough to tell a
        proportional fault (windows that each agreed while their reading did not: an
        under-read at low speed, its lags merged by the windows that caught up)."""
        ledger.end_run(i, h.good if self.run_agrees(h) else 0)

    def run_agrees(self, h: MouseHealth) -> bool | None:
        """Whether an excluded mouse's run of agreeing windows agrees as a whole: its
        residual along its reading, as a fraction g of the reading, fitted over the run by
        each window's error along it, within the test of the fit's own error (one degree
        of freedom).  A fault in proportion to the motion (a factor f) gives
        g = (f - 1) / f whatever each window's error (-1 for an under-read by half), and
        the prediction's errors only noise.  None while the fit is too loose to have told
        an under-read by half (its error above half of 1 over the test's width): the run
        goes on."""
        thr1 = self._thr1
        if h.fit_info < 4.0 * thr1:
            return None
        return h.fit_r * h.fit_r <= thr1 * h.fit_info
