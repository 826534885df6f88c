"""Fault-tolerant fusion: test each window's mice against the rigid-body model, exclude the
mouse (or mice) whose readings the others contradict, and keep a health state per mouse.

A lifted mouse goes silent, a glossy patch makes one under-read, a seam makes one jump, a
fast turn saturates one: each is a reading that no rigid motion of the rig explains
together with the others.  Per window (docs/models.md, "Faults"):

1. The live mice's readings d are solved as today (weighted least squares, W = sigma^-2),
   and their residuals are normalised by each mouse's expected error over the window, s_i
   (``noisemodel``: a floor, a part in proportion to motion and one for report splitting,
   each scaled by what the mouse's own residuals have shown).  The s_i are taken from the
   solution with every candidate mouse and kept while mice are left out in turn, so that a
   faulty mouse cannot widen its own tolerance by moving the solution.
1b. A mouse that reads short of its motion (``shortfall.reads_short``: under a quarter of
   the solve with it, or, the one most out of proportion to the solve without it, under
   three quarters of that) sums its shortfall; once the sum is beyond twice its floor at
   the test's threshold it is held out (as late) though the window passes, or where it
   fails in a tie that the window passes without it: wide tolerances learnt from late
   stamps would let a lift pass window after window, and an under-read whose first
   windows passed was learnt by the noise model as noise (``_quiet_blame``).
2. T = min_q sum_i |d_i - A_i q|^2 / s_i^2 is chi-square with 2L - k degrees of freedom on
   a healthy rig of L mice and k unknowns, whatever the layout.  Above its (1 - alpha)
   quantile (``false_alarm`` alpha, 1e-4 by default) the window is inconsistent.
3. Then each mouse (then each pair) is left out in turn, where the rest still determine the
   model with at least one redundant reading; if exactly one choice makes the rest
   consistent, those mice are excluded.  Where several do (the geometry cannot tell, e.g.
   mice on one line), one that fits far better than another that fits worse than its own
   median, or keeps the rig's motion continuous (against the motion of 50 ms before and
   against a ramp), or whose excluded mouse reads as a lifted one is the one
   (``_tie_break``); otherwise nobody is blamed: the window keeps all mice, its covariance
   is multiplied by T / dof, and the mice become ``suspect``.
3b. Where the kept mice fail, none of them can be blamed and some are held out from
   earlier windows, the choice is revisited: if an explanation among all the live mice
   excludes no more of them, it is taken, and the mice it brings back are suspect until they
   agree for ``readmit_s``.
4. An excluded mouse is re-admitted after ``readmit_s`` of windows in which it agreed with
   the others (within its error and their prediction's) while they moved enough to have
   shown the fault, and where the run's fit of a proportional fault agrees; one its own
   sensor's evidence excluded, after a fifth of that once the evidence is gone and it
   agrees (``readmission``).
5. What a held-out mouse read is settled with the pose by corrections to the window's
   twist (``Decision.correction``), so that every count counts once and a fault from its
   start only: the windows just before its exclusion in which its fault began are taken
   back (``_take_back``); at re-admission a late mouse's counts are given back whole, a
   faulty one's from the windows it agreed in (``ledger``).

Sensor evidence gates a mouse before any of this: SQUAL below ``min_squal`` or the
sensor's overflow flag ("low quality"), a reading or a prediction beyond ``max_speed``
("saturated").  Decisions use only the window and the ones before it: nothing reaches back
to change a window already published, so the daemon and replay give the same poses.

The common case (every mouse tracking, the window consistent) is decided by ``fast_one`` on
Python floats (the daemon) or ``screenbatch.screen`` for whole arrays (replay); only
windows where something happens take ``decide``, the one exact path both share.  The test
of a set of mice is ``rigidtest.RigidTest`` (the screen is one); the states, ``health``.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from mousedom.config import RobustConfig
from mousedom.fusion import chi2, steady
from mousedom.fusion.health import (
    EXCLUDED,
    INCONSISTENT,
    LATE,
    LOW_QUALITY,
    MISSING,
    NONE,
    REASONS,
    SATURATED,
    SILENT,
    STATES,
    SUSPECT,
    TRACKING,
    Health,
    MouseHealth,
    Reason,
)
from mousedom.fusion.lateness import Lateness
from mousedom.fusion.ledger import Ledger
from mousedom.fusion.noisemodel import NoiseModel, norm2
from mousedom.fusion.readmission import Readmission, fresh_wait
from mousedom.fusion.rigidtest import RigidTest, Statistic
from mousedom.fusion.shortfall import SHORT, others_word, reads_short
from mousedom.fusion.silences import SILENT_SHARE, Silences

# The health's names are the screen's vocabulary (robust.EXCLUDED, robust.REASONS, ...).
__all__ = ["EXCLUDED", "INCONSISTENT", "LATE", "LOW_QUALITY", "MISSING", "NONE", "REASONS",
           "SATURATED", "SILENT", "STATES", "SUSPECT", "TRACKING", "Decision", "Health",
           "Reason", "Screen"]  # fmt: skip

# How much smoother than the next one the winning explanation's motion must be (tie_break).
_CONTINUITY_MARGIN = 3.0
_FIT_MARGIN = chi2.quantile(0.999, 1)
# The continuity of motion does not decide a tie for an explanation whose fit, summed over
# the tie, is beyond this quantile of its own and worse than another's (_tie_break).
FIT_VETO = 0.95
# How far back the continuity of motion is judged from (_tie_break).
HISTORY_S = 0.05
# A mouse whose hat block has an eigenvalue beyond this is not looked back on for a
# paid-back lag (Screen._caught_up): (I - block)^-1 would multiply the earlier windows'
# residuals, noise included, by more than 4 along it.
_CATCH_UP_LEVERAGE = 0.75
# How many windows before a mouse's exclusion a mouse short of its motion is taken back
# over at least (Screen._take_back): a fault starts within a window and grows past the test
# in a few.
TAKE_BACK_WINDOWS = 3
# How far back a fault's onset is looked for (Screen._take_back): a fault that grows slowly
# (a mouse that saturates as a turn speeds up, a surface that turns glossy) passes the test
# window after window for most of a second before it is caught.
TAKE_BACK_S = 1.0
# Where the onset's sum has fallen this far (in sigmas) below its peak, the walk back stops:
# noise alone takes about one a window from it and does not climb back so far.
_ONSET_GIVE_UP = 6.0


def _moved_by(p: np.ndarray, ref: np.ndarray, s2: np.ndarray) -> float:
    """How far the mice's motions ``p`` (N, 2) are from ``ref``, in their errors ``s2``:
    sum_i |p_i - ref_i|^2 / s2_i (the continuity of motion's change, ``_tie_break``)."""
    return float(np.sum(np.sum((p - ref) ** 2, axis=1) / s2))


def _fits_badly(total: float, dof: int) -> bool:
    """Whether an explanation's statistic summed over a tie's run (``_fit_sums``, ``dof``
    degrees in all) is worse than its own median: only then does a difference of sums
    tell the explanations apart (``Screen._tie_break``).  Each kept set tests other
    directions, and the noise model's error in proportion to the motion is the same
    across it as along it, while CPI and timing errors lie along it: a pair whose one
    redundant reading lies across the motion fits a drive nearly exactly whether or not
    one of it under-reads, and a healthy pair along the motion shows its errors.  A
    far-one rig's mouse behind the far one reading half, its pair summed 0.69 over 34
    windows against the healthy pair's 11.9 (its median: 33.3), and the fit blamed the
    far mouse: 4.0 m off, where fault handling off ended 0.26 m off."""
    return total > chi2.median(dof)


def _but(used: np.ndarray, i: int) -> np.ndarray:
    """``used`` without mouse i."""
    out = used.copy()
    out[i] = False
    return out


class Explanation(NamedTuple):
    """A set of mice whose exclusion lets the window pass, with the test it passed."""

    excluded: list[int]
    stat: Statistic


@dataclass(frozen=True)
class Decision:
    """What ``decide`` made of one window."""

    used: np.ndarray  # (N,) bool: the mice the window is solved with
    inflate: float  # the q covariance's factor (1 unless inconsistent and unattributed)
    consistent: bool
    # (3,) to add to the window's twist increment: what mice re-admitted in it would have
    # given over their exclusion (ledger), less what mice held out of it took while
    # their fault began (_take_back)
    correction: np.ndarray | None = None


class Screen(RigidTest):
    """The per-window decision and the mice's health (module docstring) on the rig's
    ``RigidTest``.  No I/O, no clock."""

    def __init__(
        self,
        model: str,
        positions: np.ndarray,
        sigma: np.ndarray,
        report_periods: np.ndarray,
        window: float,
        settings: RobustConfig,
        max_speed: np.ndarray | None = None,
    ) -> None:
        super().__init__(model, positions, sigma, settings.false_alarm)
        self.noise = NoiseModel(
            self.sigma, settings.relative_noise, report_periods, window, settings.false_alarm
        )
        speed = np.full(self.n, np.inf) if max_speed is None else np.asarray(max_speed, float)
        self.max_step2 = (speed * window) ** 2  # inf: no limit
        self.health = [MouseHealth() for _ in range(self.n)]
        self._steady: tuple[bool, ...] | None = None
        self._steady_known = False  # _steady is that of the health as it is
        self._held_beyond: frozenset[int] = frozenset()  # hold_beyond's mice
        # Python copies for fast_one, which must not touch numpy (RigidTest._xy).
        self._max2 = self.max_step2.tolist()
        self._prev = [[0.0, 0.0] for _ in range(self.n)]  # the previous window's predictions
        self._leverage_lists: dict[tuple[bool, ...], list[float]] = {}
        # The readings of the windows of the last TAKE_BACK_S (each (N, 2), or flattened
        # floats), where a fault's onset is looked for when its mouse is held out
        # (_take_back), and the mice each was solved with.  The tie break's continuity
        # and a paid-back lag look at the last ``history_len`` of them (HISTORY_S), past
        # windows a creeping fault may already have bent (_tie_break, _caught_up).
        self.history_len = max(2, round(HISTORY_S / window))
        self.onset_len = max(self.history_len, round(TAKE_BACK_S / window))
        # (twice history_len at least: the ramp of _tie_break looks that far back)
        self.history: deque[Any] = deque(maxlen=max(self.onset_len, 2 * self.history_len))
        self.used_history: deque[tuple[bool, ...]] = deque(maxlen=self.onset_len)
        self._windows = 0  # windows solved so far (_used_for): which ties are consecutive
        # The take-backs not yet handed on (``hand_taken``): (mouse, first window, end
        # window), numbered as ``_windows`` counts them.  The scale learner must not give
        # those windows' readings back again (ScaleLearner._give_back_faults).
        self._taken: list[tuple[int, int, int]] = []
        # The tie breaks of the latest windows, per set of mice tested: the last window,
        # every explanation's statistic summed over the tie's run (_fit_sums), and how
        # many windows that run holds.
        self._ties: dict[tuple[bool, ...], tuple[int, dict[tuple[int, ...], float], int]] = {}
        # What each held-out mouse owes the pose, settled at its re-admission (ledger).
        self.lateness = Lateness(self.n, window, settings.late_s)
        # An excluded mouse's way back (readmission), and what a held-out mouse owes the
        # pose, settled at its re-admission (ledger).
        self.readmission = Readmission(
            window, settings.readmit_s, self._thresholds, self.lateness.limit
        )
        self.ledger = Ledger(self.n, self._thresholds[2], self.readmission.readmit_evidence)
        # Each mouse's shortfall (predicted less read motion) summed over the windows it
        # read short in since it last read in full (``_quiet_blame``); any not zero.
        self._quiet = [[0.0, 0.0] for _ in range(self.n)]
        self._quiet_n = [0] * self.n  # the windows in each of those sums
        # and what each sum may hold without a fault: the variance of its white noise (the
        # mouse's own, the config's sigma, and its prediction's: the sandwich on it), and
        # the prediction's error in proportion to the others' motion (their CPIs, which
        # do not average out: summed as amplitudes), over its windows
        self._quiet_var = [0.0] * self.n
        self._quiet_sys = [0.0] * self.n
        self._short_now = [False] * self.n  # short in the window being decided
        self._quiet_any = False
        self._quiet_held: int | None = None  # the mouse this window held out for it
        self.silences = Silences(self.n)  # each used mouse's silence (``_runs``)

    # ----------------------------------------------------------------- basics

    def steady(self) -> tuple[bool, ...] | None:
        """The live pattern under which the common case applies (every tracking mouse
        live, every missing one not), or None while some mouse is suspect or excluded.
        Kept until the health changes (``_update``): fast_one asks every window."""
        if self._steady_known:
            return self._steady
        self._steady, self._steady_known = self._steady_of_health(), True
        return self._steady

    def _steady_of_health(self) -> tuple[bool, ...] | None:
        out = []
        for h in self.health:
            if h.state == TRACKING:
                out.append(True)
            elif h.state == MISSING:
                out.append(False)
            else:
                return None
        return tuple(out)

    @property
    def prev_p(self) -> np.ndarray:
        """(N, 2) the previous window's predictions."""
        return np.array(self._prev, dtype=float).reshape(self.n, 2)

    def accepted(self, p: np.ndarray, d: np.ndarray, used: Sequence[bool],
                 decided: bool = False) -> None:  # fmt: skip
        """Windows done: their predictions p (rows, N, 2) and readings d, oldest first
        (the continuity of motion and lateness look back over them), every row solved
        with the mice ``used``; ``decided``: by ``decide``, which kept the silences'
        accounts itself (``_runs``)."""
        if self.silences.any and not decided:
            self.silences.rows(p, d, used, self.noise.sig2_list, self._thresholds[2])
        self._prev = np.asarray(p[-1], dtype=float).tolist()
        self.history.extend(d[-self.onset_len :])
        self.lateness.remember_rows(p)
        self._used_for(used, len(p))

    def _used_for(self, used: Sequence[bool], rows: int) -> None:
        """``rows`` more windows solved with the mice ``used`` (how far back a mouse's
        readings were its own part of the solve, and with whom: _caught_up, _take_back)."""
        row = used if type(used) is tuple else tuple(bool(u) for u in used)  # (fast_one's)
        self.used_history.extend([row] * min(rows, self.onset_len))
        self._windows += rows

    def hand_taken(self) -> list[tuple[int, int, int]]:
        """The take-backs since the last call, once: (mouse, from, to), the windows taken
        back being those ``from`` down to ``to`` + 1 windows before the latest one solved
        and the latest itself as 1 (``to`` = 1: up to the one before the window that took
        them back).  Counted back, not numbered: the learners count their own windows."""
        taken = self._taken
        if not taken:
            return taken  # (empty: every window of the daemon's common case)
        self._taken, now = [], self._windows
        return [(i, now - lo, now - hi) for i, lo, hi in taken]

    def used_run(self, i: int) -> int:
        """The latest windows in a row mouse i was used in (up to ``history_len``)."""
        run = 0
        for used in reversed(self.used_history):
            if run == self.history_len or not used[i]:
                break
            run += 1
        return run

    def _count_window(self, defer_block_end: bool) -> None:
        """One more window solved; at a block's end the noise model learns from it, or
        with ``defer_block_end`` it is left due for ``settle`` (Tracker.settle: the daemon
        learns once the window's POSE is out)."""
        self.noise.seen += 1
        if not defer_block_end:
            self.settle()

    @property
    def block_due(self) -> bool:
        """A window ended the noise model's block and it has not learnt from it yet."""
        return self.noise.seen >= self.noise.block

    def settle(self) -> None:
        """The noise model's block end that a window left due, if one did."""
        if self.block_due:
            self.noise.end_block()

    # ----------------------------------------------------------------- common case

    def fast_one(
        self, d: list[float], q: list[float], live: tuple[bool, ...], evidence: bool,
        defer_block_end: bool = False, spans: list[float] | None = None,
    ) -> bool:  # fmt: skip
        """The common case on floats: True (and the window is accepted as solved) when the
        state is steady for ``live``, no sensor evidence (SQUAL, overflow) is in the window,
        no mouse is beyond its speed and the test passes.  ``d``: every mouse's body-frame
        displacement, flattened (x1, y1, x2, ...); ``spans``: as ``decide``'s (the
        granularity term of a mouse whose span the edges cut grows, ``steady_window``)."""
        if evidence or live != (self._steady if self._steady_known else self.steady()):
            return False
        if spans is not None and (self.silences.any or self._any_silent(d, live)):
            # a silence's account is the decision's to open and keep through a cut span
            # (``_runs``: each window at its own variance, the span's term with it)
            return False
        dof = 2 * sum(live) - self.k
        leverage = None
        if dof > 0:
            leverage = self._leverage_lists.get(live)
            if leverage is None:
                leverage = self._leverage_lists[live] = self.leverage(np.array(live)).tolist()
        nm = self.noise
        gran2 = nm.f_gran2 if spans is None else nm.f_gran2_for(spans)
        rig = steady.Rig(self._xy, self._max2, self._prev, nm.f_floor, nm.f_rho2, gran2,
                         nm.sig2_list, nm.lam_r_list)  # fmt: skip
        threshold = self._thresholds[dof] if dof > 0 else math.inf
        gains = self.others_gain_list(live)
        accepted = steady.steady_window(d, q, live, rig, threshold, dof, leverage, gains, spans)
        if accepted is None:
            return False  # decide (a shortfall among it: ``_quiet_blame``)
        p, by_floor, by_prop, heard = accepted
        if self._quiet_any:
            self._heard(heard, not any(heard))
        if self.silences.any:
            self.silences.rows([p], [d], live, nm.sig2_list, self._thresholds[2])
        self._prev = p
        nm.take(by_floor, by_prop)
        self.history.append(d)
        self.lateness.remember(self._prev)
        self._used_for(live, 1)
        self._count_window(defer_block_end)
        return True

    # ----------------------------------------------------------------- the exact path

    def heard_rows(self, p: np.ndarray, live: np.ndarray) -> None:
        """Windows the common case accepted (``screenbatch``; none holds a mouse short of
        its motion: those are decided), their predictions p (rows, N, 2) and live mice
        (rows, N): each live mouse moved beyond its sigma in one of them read in full, and
        its shortfall's sum starts again (``fast_one``'s ``heard``, row by row)."""
        if self._quiet_any:
            moved = (norm2(np.asarray(p, dtype=float)) > self.noise.sig2) & live
            self._heard(np.any(moved, axis=0), not np.all(np.any(moved, axis=1)))

    def _heard(self, read: Sequence[bool], still: bool = False) -> None:
        """The mice that read what the others moved them in the windows just accepted
        (their motion beyond sigma, and not short): their shortfall's sum starts again;
        every mouse's does where the rig stood still in one of them (``still``: none
        moved beyond its sigma).  A shortfall is a fault's while the robot moves: a sum
        carried over a standstill joined windows seconds apart, and a mouse whose sum a
        creeping mouse had grown (each still mouse read short of the motion the creep bent
        into every prediction) was held out at the first window of the next motion."""
        for i, r in enumerate(read):
            if r or still:
                self._quiet_reset(i)
        self._quiet_any = any(x or y for x, y in self._quiet)

    def exclude_faulty(self, mice: Sequence[int]) -> None:
        """Mice the scales found reading out of proportion to their motion over a block
        (``ScaleLearner._faults``: half of it, say, where each window's test let that by):
        excluded from the next window on, as if a window had blamed them, and back as any
        excluded mouse (``Readmission.waiting``: its run is judged as a whole against an under-read,
        and given back only where it agrees).  Not where the mice left could not check
        each other (one degree of freedom at least)."""
        out = [i for i in mice if self.health[i].state in (TRACKING, SUSPECT)]
        rest = sum(h.state in (TRACKING, SUSPECT) for h in self.health) - len(out)
        if self.dof(rest) < 1:
            return  # the rest could not check each other: the windows' test goes on
        for i in out:
            h = self.health[i]
            self.ledger.hold(i, np.zeros(2), 0.0)
            fresh_wait(h)
            h.state, h.reason, h.good = EXCLUDED, INCONSISTENT, 0
            self._quiet_reset(i)
        self._steady_known = False

    def hold_beyond(self, mice: Sequence[int]) -> None:
        """The mice whose scale the learner's evidence puts beyond its bounds
        (``ScaleLearner.beyond``): excluded as ``exclude_faulty`` does, and not re-admitted
        while they stay in it.  A mouse reading 15 % more than its CPI says passes each
        window's test and its run's (a fifth of a second), and one scale clipped to the
        bound leaves it 5 % off in every window it is used in."""
        # At every renewal, not only when the set changes: a held mouse may be back in use
        # by another way (unplugged and back: MISSING -> TRACKING; its sensor's gate;
        # needed for rank), or exclude_faulty refused it (the rest could not check each
        # other); exclude_faulty acts on the mice in use alone.
        self._held_beyond = frozenset(mice)
        if any(self.health[i].state in (TRACKING, SUSPECT) for i in self._held_beyond):
            self.exclude_faulty(sorted(self._held_beyond))

    def _quiet_reset(self, i: int) -> None:
        """Mouse i read in full (or is gone): its shortfall's sum starts again."""
        self._quiet[i], self._quiet_n[i] = [0.0, 0.0], 0
        self._quiet_var[i] = self._quiet_sys[i] = 0.0

    def _prediction_errors(self, d: np.ndarray, used: np.ndarray) -> tuple[list, list]:
        """Per mouse, what its prediction from the ``used`` mice may be off by: the
        variance of the white part (the config's sigma through the estimator's sandwich,
        a trace) and the amplitude of the part in proportion to the others' motion (the
        config's relative_noise, rho^2 |d|^2, through the same: a CPI's error, which does
        not cancel in a sum; the learnt factor on it is mostly late stamps', which do)."""
        white = np.trace(self.prediction_cov(used, self.noise.sig2), axis1=1, axis2=2)
        rho2 = self.noise.rho2 * np.sum(d * d, axis=1)
        prop = np.sqrt(np.trace(self.prediction_cov(used, rho2), axis1=1, axis2=2))
        return white.tolist(), prop.tolist()

    def _quiet_blame(self, d: np.ndarray, p: np.ndarray, live: np.ndarray,
                     used: np.ndarray) -> int | None:  # fmt: skip
        """The window's shortfalls (module step 1b): each live mouse the others moved
        beyond its sigma (and its prediction's noise) that reads short of that
        (``reads_short``) adds what it missed (p - d) to its shortfall's sum; one that
        read more starts again.  Returns the used mouse whose sum, over two windows or more, is
        beyond twice its expected error's floor (two windows' worth of counts moved by late
        stamps) plus the sum's white noise, at the test's threshold, where the rest can do
        without it (the one furthest beyond, if several), else None.

        A lifted mouse reads nothing, or noise; where late stamps and USB gaps have taught
        the noise model wide tolerances (floors thousands of times the config's sigma^2),
        a lift at a walking pace passes the window's test window after window and bends
        the heading by tens of degrees.  A shortfall is either lateness (the counts come,
        and the late mouse is settled: ``lateness``, ``ledger``) or a fault: held out as
        late here, a mouse that never catches up is excluded after ``late_s``."""
        floor = self.noise.f_floor
        sig2 = self.noise.sig2_list
        worst, blame = 1.0, None
        white: list[float] | None = None  # _prediction_errors', once a mouse reads short
        prop: list[float] = []
        self._short_now = [False] * self.n
        moved = live & (norm2(p) > self.noise.sig2)
        if not moved.any():
            # the rig stands (or no solve says it moved: p is zero): every sum ends
            self._heard([False] * self.n, still=True)
            return None
        key = tuple(used.tolist())
        short = reads_short(d.ravel().tolist(), p.tolist(), self.others_gain_list(key),
                            moved.tolist(), key)  # fmt: skip
        for i in range(self.n):
            px, py = float(p[i, 0]), float(p[i, 1])
            p2 = px * px + py * py
            if not live[i]:
                self._quiet_reset(i)
                continue
            if p2 <= sig2[i]:
                continue  # moved too little to tell
            dx, dy = float(d[i, 0]), float(d[i, 1])
            if not short[i]:
                self._quiet_reset(i)
                continue
            if white is None:
                white, prop = self._prediction_errors(d, used)
            if p2 <= sig2[i] + white[i] + prop[i] * prop[i]:
                continue  # the others' errors predict as much (a mouse at the pivot)
            qx, qy = self._quiet[i][0] + (px - dx), self._quiet[i][1] + (py - dy)
            self._quiet[i] = [qx, qy]
            self._quiet_n[i] += 1
            self._quiet_var[i] += 2.0 * sig2[i] + white[i]
            self._quiet_sys[i] += prop[i]
            self._short_now[i] = True
            # beyond twice the floor (lateness: counts moved between windows, which cancel
            # in the sum) and what the sum's errors allow, which do not cancel: a mouse at
            # a spin's pivot reads nothing while the others' noise and CPI errors predict
            # a little, and that sum walked past the floor in a few dozen windows (a
            # healthy mouse held out, a line of three ending 0.18 m off)
            sys2 = self._quiet_sys[i] * self._quiet_sys[i]
            beyond = (qx * qx + qy * qy) / (
                self._thresholds[2] * (2.0 * floor[i] + self._quiet_var[i] + sys2)
            )
            # two windows at least: one silent window is how a 125 Hz mouse starts to move
            # (its first report is still to come), or how a late report looks
            in_use = self.health[i].state in (TRACKING, SUSPECT) and self._quiet_n[i] >= 2
            if used[i] and in_use and beyond > worst and self._solve(d, _but(used, i)) is not None:
                worst, blame = beyond, i
        self._quiet_any = any(x or y for x, y in self._quiet)
        if blame is not None and self._one_mover(d, used):
            return None
        return blame

    def _one_mover(self, d: np.ndarray, used: np.ndarray) -> bool:
        """Whether, of four or more mice in use, one alone read anything beyond its sigma:
        then it is the odd one (a mouse creeping while the rest stand still drags every
        prediction, and the still ones read short of it), not the silent ones lifted.
        Lifts come one mouse at a time; a shortfall's sum waits for a window in which more
        mice move (tests/test_robust_creep.py).  Not with three: one mover and two silent
        mice are also a spin about one of them with the other lifted, which must be
        blamed (tests/test_shortfall_pivot.py); nor with a spin's centre among four, where
        two mice move."""
        sig2 = self.noise.sig2_list
        n_used = moved = 0
        for i in range(self.n):
            if used[i]:
                n_used += 1
                moved += float(d[i, 0]) ** 2 + float(d[i, 1]) ** 2 > sig2[i]
        return n_used >= 4 and moved == 1

    # ----------------------------------------------------------------- a silence's catch-up

    def _runs(self, d: np.ndarray, used: np.ndarray, s2: np.ndarray) -> None:
        """A decided window's part in each used mouse's silence: a mouse silent while the
        others moved it beyond its sigma opens one (or adds to it) with its residual under
        them, as does a mouse with one open that reads again (its catch-up); a mouse
        held out leaves it to the ledger."""
        sig2 = self.noise.sig2
        silences = self.silences
        silent = [self._silent(d, i) for i in range(self.n)]
        if not silences.any and all(silent[i] for i in range(self.n) if used[i]):
            return  # no used mouse read anything (a standstill): no silence to tell
        for i in range(self.n):
            if not used[i]:
                if silences.silent[i]:
                    # held out now: the silence it was used through joins its account, so
                    # that a catch-up arriving while it is out pays it back (``Ledger``)
                    self.ledger.before(i, silences.sum[i], float(silences.s2[i]))
                    silences.close(i)
                continue
            if not (silences.silent[i] or silent[i]):
                continue
            q = self._solve(d, _but(used, i))
            if q is None:
                silences.close(i)
                continue
            p_i = self.predict(q)[i]
            if not silences.silent[i] and float(p_i @ p_i) <= sig2[i]:
                continue  # moved too little to tell: nothing owed
            silences.step(i, d[i] - p_i, silent[i], float(s2[i]), self._thresholds[2])
        silences.settle()

    def _catching_up(self, d: np.ndarray, used: np.ndarray, s2: np.ndarray) -> list[int]:
        """The used mice whose reading in this window is the catch-up of a silence they
        were used through (``_runs``): their residuals under the others summed over the
        silence and through this window are within twice this window's error and the
        silence's, at the test's threshold, where the silence owed more (``Silences.owed``;
        the catch-up's second window is judged on what the first left).

        A USB host that does not poll a mouse for longer than ``late_report_s`` delivers
        its counts summed in one report, which covers one report period
        (``countfunction``): the silence was used as a mouse reading nothing (nothing
        told it from a mouse at rest), and the catch-up reads as a jump, the others short
        of it.  Blamed, the mouse's counts were lost (its zeros kept) and, of two mice,
        the healthy one was held out: ends metres off where fault handling off took
        them.  This window's error holds the catch-up's own proportional error (it
        grows with the reading), the CPIs' part of the sum."""
        thr2 = self._thresholds[2]
        silences = self.silences
        out = []
        for i in range(self.n):
            if not (used[i] and silences.catching(i)):
                continue  # (its silence owed nothing beyond its errors: nothing to catch up)
            if self._silent(d, i):
                continue
            q = self._solve(d, _but(used, i))
            if q is None:
                continue
            var = 2.0 * float(s2[i]) + float(silences.s2[i])
            owed = silences.sum[i] + d[i] - self.predict(q)[i]
            if float(owed @ owed) <= thr2 * var:
                out.append(i)
        return out

    def _silent(self, d: np.ndarray, i: int) -> bool:
        """No counts in the window (a thousandth of its sigma: the split of reports
        across windows leaves rounding dust where there were none)."""
        return self._reads_nothing(d[i], i)

    def _any_silent(self, d: list[float], live: tuple[bool, ...]) -> bool:
        """Whether a live mouse reads nothing in the window (``_silent``, on the flattened
        floats the common case has)."""
        sig2 = self.noise.sig2_list
        return any(live[i] and d[2 * i] ** 2 + d[2 * i + 1] ** 2 <= SILENT_SHARE * sig2[i]
                   for i in range(self.n))  # fmt: skip

    def _reads_nothing(self, di: np.ndarray, i: int) -> bool:
        """``_silent`` for mouse i's reading ``di``."""
        return float(di @ di) <= SILENT_SHARE * self.noise.sig2[i]

    def decide(
        self,
        d: np.ndarray,
        live: np.ndarray,
        squal_scale: ArrayLike | None = None,
        low_quality: ArrayLike | None = None,
        spans: ArrayLike | None = None,
        defer_block_end: bool = False,
    ) -> Decision:
        """The exact per-window decision (module docstring, steps 1-4); updates health.
        ``spans`` (N,): the long report spans the window's edges cut, per mouse (0: none;
        the noise model's granularity term grows with them); ``defer_block_end``: see
        ``_count_window``."""
        n = self.n
        d = np.asarray(d, dtype=float).reshape(n, 2)
        live = np.asarray(live, dtype=bool)
        scale = np.ones(n) if squal_scale is None else np.asarray(squal_scale, dtype=float)
        lowq = np.zeros(n, dtype=bool) if low_quality is None else np.asarray(low_quality)
        gran2 = self.noise.gran2_for(spans)
        excluded = np.array([h.state in (EXCLUDED, LATE) for h in self.health])
        used = live & ~excluded
        if self._solve(d, used) is None:
            used = live.copy()  # the healthy ones alone cannot: the excluded must serve
        q = self._solve(d, used)
        p = self.predict(q) if q is not None else np.zeros((n, 2))
        quiet = self._quiet_blame(d, p, live, used)
        self._quiet_held = None
        # Sensor evidence first.
        gate = np.zeros(n, dtype=int)
        gate[live & (np.maximum(np.sum(d * d, 1), np.sum(p * p, 1)) >= self.max_step2)] = SATURATED
        gate[live & lowq] = LOW_QUALITY
        gated = used & (gate > 0)
        suspect = np.zeros(n, dtype=bool)
        reason = gate.copy()
        if gated.any():
            if self._solve(d, used & ~gated) is not None:
                used = used & ~gated
            else:
                suspect |= gated  # cannot do without it: used, but flagged
            q = self._solve(d, used)
            p = self.predict(q) if q is not None else p
        gp = None if gran2 is None else self._span_p(d, used, p, spans)
        floor, prop = self.noise.parts(d, p, self.prev_p, gran2=gran2, gran_p=gp)
        s2 = floor * scale + prop
        tested_used, tested_p = used, p  # what floor and prop are for (a change rebinds)
        inflate, consistent = 1.0, True
        stat = self._statistic(d, used, s2)
        blamed, caught_up = self._blame(d, used, s2, stat)
        if caught_up:
            pass  # counts moved between windows, not a fault: the window stands as solved
        elif stat is not None and stat.dof > 0 and not self._passes(stat):
            swap = (None if blamed is not None
                    else self._reexamine(d, live, used, gate, scale, gran2, spans))  # fmt: skip
            if swap is not None:
                # the kept set is wrong, the mice held out are not all: fewer exclusions
                # explain the window with them back (they come back suspect, see _update)
                used = (used | (live & (gate == 0))).copy()
                for j in swap:
                    reason[j] = SILENT if self._silent(d, j) else INCONSISTENT
                used[list(swap)] = False
                q = self._solve(d, used)
                assert q is not None  # these mice passed their test: they have rank
                p = self.predict(q)
            elif blamed is not None:
                for j in blamed:
                    reason[j] = SILENT if self._silent(d, j) else INCONSISTENT
                used, p = self._without(d, used, blamed)
            elif quiet is not None and used[quiet] and self._passes_without(d, used, quiet, s2):
                # nothing in the window alone tells who (a tie), but one mouse has read
                # short of what the others moved it beyond its error, window after window,
                # and the window passes without it: held out as where the window passes
                reason[quiet] = SILENT if self._silent(d, quiet) else INCONSISTENT
                used, p = self._without(d, used, [quiet])
                self._quiet_held = quiet
            else:
                consistent = False
                inflate = stat.t / stat.dof
                suspect |= used
                reason[used & (reason == NONE)] = INCONSISTENT
        elif quiet is not None and used[quiet] and self._solve(d, _but(used, quiet)) is not None:
            # the window passes, but a mouse has read short of what the others moved it
            # beyond its error: held out (as late, until it catches up or late_s is over)
            reason[quiet] = SILENT if self._silent(d, quiet) else INCONSISTENT
            used, p = self._without(d, used, [quiet])
            self._quiet_held = quiet
        if used is not tested_used or p is not tested_p:  # a mouse blamed, swapped or gated
            gp = None if gran2 is None else self._span_p(d, used, p, spans)
            floor, prop = self.noise.parts(d, p, self.prev_p, gran2=gran2, gran_p=gp)
        floor = floor * scale
        was_used = [h.state in (TRACKING, SUSPECT) for h in self.health]
        self._update(d, p, live, used, suspect, reason, consistent, floor, prop)
        self._runs(d, used, floor + prop)
        correction = self._settle(used, live & ~used, was_used, reason, floor + prop)
        if consistent and not caught_up and self.dof(int(used.sum())) > 0:
            self._sample_noise(d, p, used, suspect, floor, prop)
        self.accepted(p[None], d[None], used.tolist(), decided=True)
        self._count_window(defer_block_end)
        return Decision(used=used, inflate=inflate, consistent=consistent, correction=correction)

    def _passes_without(self, d: np.ndarray, used: np.ndarray, i: int, s2: np.ndarray) -> bool:
        """Whether the window's test passes with mouse i left out of ``used``."""
        stat = self._statistic(d, _but(used, i), s2)
        return stat is not None and self._passes(stat)

    def _blame(self, d: np.ndarray, used: np.ndarray, s2: np.ndarray,
               stat: Statistic | None) -> tuple[list[int] | None, bool]:  # fmt: skip
        """The mice a window that fails its test blames (``_identify``; None: none can
        be), and whether what it holds is counts moved between windows, not a fault:
        a lag paid back (``_caught_up``), or a silence's catch-up (``_catching_up``; then
        also where the window passes, so that the noise model does not learn from it)."""
        caught_up = False
        catching = self._catching_up(d, used, s2) if self.silences.any else []
        blamed = None
        if stat is not None and stat.dof > 0 and not self._passes(stat):
            blamed = self._identify(d, used, s2)
            if catching and (blamed is None or set(blamed) <= set(catching)):
                blamed, caught_up = None, True
            elif blamed is not None and self._caught_up(d, used, blamed, s2):
                blamed, caught_up = None, True
        elif catching:
            caught_up = True
        if catching:
            # what the others read short of the solution the catch-up bent is not theirs
            # to owe (of two mice, the healthy one was held out for it)
            for i in range(self.n):
                self._quiet_reset(i)
            self._quiet_any = False
        return blamed, caught_up

    def _sample_noise(self, d: np.ndarray, p: np.ndarray, used: np.ndarray, suspect: np.ndarray,
                      floor: np.ndarray, prop: np.ndarray) -> None:  # fmt: skip
        """A consistent window's samples for the noise model: each mouse used, not suspect,
        that moved."""
        r2 = np.sum((d - p) ** 2, axis=1)
        moving = np.maximum(np.sum(d * d, 1), np.sum(p * p, 1)) > self.noise.sig2
        h = self.leverage(used)
        for i in np.flatnonzero(used & moving & ~suspect).tolist():
            self.noise.sample(i, float(r2[i]), float(floor[i]), float(prop[i]), float(h[i]))

    def _without(self, d: np.ndarray, used: np.ndarray,
                 mice: list[int]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """The window solved without ``mice`` (the rest has rank: they passed a test, or
        ``_quiet_blame`` checked): the mice used, and each mouse's prediction."""
        used = used.copy()
        used[mice] = False
        q = self._solve(d, used)
        assert q is not None
        return used, self.predict(q)

    def _caught_up(self, d: np.ndarray, used: np.ndarray, blamed: list[int],
                   s2: np.ndarray) -> bool:  # fmt: skip
        """Whether the mice blamed for this window read more than the others say only by
        counts late from the windows just before, in which they were used and read short
        within their tolerance (stamps late by a long tail; a report held up): a lag that
        was never flagged, paid back.  Then the readings summed from one of those windows
        through this one agree with the others (each earlier residual, shrunk by the mouse's
        own weight in the solve it was used in, taken back to full size), within twice its
        own error at the test's threshold (without the allowance for the others' prediction
        that ``Ledger.paid`` makes for a held-out mouse: not measured here, left as it was);
        the counts are the mouse's,
        counted once, and the window is solved with it.  A jump, a lift or an under-read
        owes far more than a few windows' tolerance and is blamed as before."""
        if len(blamed) != 1 or len(self.history) < 2:
            return False
        j = blamed[0]
        if self.health[j].state != TRACKING or self._silent(d, j):
            return False
        rest = used.copy()
        rest[j] = False
        q = self._solve(d, rest)
        if q is None:
            return False
        owed = d[j] - self.predict(q)[j]
        block = self.hat_block(used, j)
        if block is None or not np.all(np.abs(np.linalg.eigvals(block)) <= _CATCH_UP_LEVERAGE):
            # its own weight hid nearly all of its residual in the windows before: taken
            # back to full size, their noise would be multiplied past any test
            return False
        full = np.linalg.inv(np.eye(2) - block)  # a residual in use -> under the others
        tol2 = self._thresholds[2] * 2.0 * float(s2[j])
        past_d = list(self.history)[-self.history_len :]
        past_p = list(self.lateness.recent)
        for k in range(1, min(len(past_d), len(past_p), self.used_run(j)) + 1):
            dk = np.asarray(past_d[-k], dtype=float).reshape(self.n, 2)[j]
            pk = np.asarray(past_p[-k], dtype=float).reshape(self.n, 2)[j]
            owed = owed + full @ (dk - pk)
            if float(owed @ owed) <= tol2:
                return True
        return False

    def _settle(self, used: np.ndarray, out: np.ndarray, was_used: list[bool],
                reason: np.ndarray, s2: np.ndarray) -> np.ndarray | None:  # fmt: skip
        """The window's correction (module step 5): what the mice re-admitted in it are
        owed, less what the mice held out of it, used before, took while their fault
        began."""
        correction = self.ledger.settle(used, self._solve) if self.ledger.readmitted else None
        # each past window's mice as the take-backs leave them: two mice held out together
        # come out of a window one after the other, which sums to the pair's exact share
        kept: dict[int, np.ndarray] = {}
        for i in np.flatnonzero(out).tolist():
            if was_used[i] and reason[i] in (SILENT, INCONSISTENT):
                short = self._quiet_n[i] - 1 if i == self._quiet_held else 0
                back = self._take_back(i, float(s2[i]), kept, short)
                if back is not None:
                    correction = back if correction is None else correction + back
        return correction

    def _take_back(self, i: int, s2: float, kept: dict[int, np.ndarray],
                   short: int = 0) -> np.ndarray | None:  # fmt: skip
        """The twist to take back from the windows just before mouse i was held out, in
        which it was used while its fault began (``Decision.correction``), or None.

        A fault starts within a window and often passes the test in the first one or two
        (its share of the window, a mouse of high leverage), and one that grows slowly
        (a mouse saturating as a turn speeds up) passes it for most of a second: those
        windows keep its error for good, where a user who knew would have left the mouse
        out from the fault's start.  Going back from the last window (up to TAKE_BACK_S,
        each with the mice it was solved with: ``used_history``; ``kept``: less those taken
        out of it already), each window's residual of the mouse under the others, along
        its residual now, is measured in its expected error now (z); the onset is where
        the sum of z - 1 over the windows after it is largest (a CUSUM's change point: a
        window of the fault adds its excess over one sigma, one of noise takes about one
        away, so the sum peaks where the fault began).  Those windows are solved again
        without it and the difference is taken back.  What is taken back joins what the
        mouse owes: a late mouse that pays back is given it all again (``ledger``).

        A mouse held out for reading short of its motion (``_quiet_blame``) began its
        fault where its shortfall's sum began: the ``short`` windows before this one, each
        of which read less than SHORT of what the others moved it (the solve without it,
        ``reads_short``'s second rule without its guards), are taken back (as far
        as the readings are kept), however small each was against tolerances that late
        stamps widened."""
        now = self.ledger.owed[i]
        size = math.sqrt(float(now @ now))
        if size == 0.0:
            return None
        u = now / size
        rows = list(self.history)[::-1]
        sets = list(self.used_history)[::-1]
        steps: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        take = score = best = 0.0
        take_n = 0
        for k in range(min(len(rows), len(sets))):
            with_i = kept.get(k, np.array(sets[k], dtype=bool))
            if not with_i[i]:
                break  # not in that window's solve: nothing of it to take back
            rest_k = with_i.copy()
            rest_k[i] = False
            dk = np.asarray(rows[k], dtype=float).reshape(self.n, 2)
            rest, both = self._solve(dk, rest_k), self._solve(dk, with_i)
            block = self.hat_block(with_i, i)
            if rest is None or both is None or block is None:
                break
            pk = self.predict(rest)[i]
            r = dk[i] - pk
            steps.append((r, both - rest, rest_k))
            if k < short:
                if float(dk[i] @ pk) >= SHORT * float(pk @ pk):
                    break  # not short there: the sum began after it
                take_n = k + 1
                continue
            # the residual under the others has the covariance s2 (I - block)^-1
            spread = float(u @ np.linalg.solve(np.eye(2) - block, u))
            if not spread > 0.0:
                break
            score += float(r @ u) / math.sqrt(s2 * spread) - 1.0
            if score > best:
                best, take = score, float(k + 1)
            elif score < best - _ONSET_GIVE_UP:
                break  # far below its peak: noise from here on
        take_n = max(take_n, int(take))
        if take_n == 0:
            return None
        taken_r, taken_q = np.zeros(2), np.zeros(3)
        for k, (r, dq, rest_k) in enumerate(steps[:take_n]):
            taken_r += r
            taken_q += dq
            kept[k] = rest_k
        if not taken_r.any():
            return None
        self.ledger.take(i, taken_r)
        # (this window is not counted yet: the last one taken back is _windows - 1)
        self._taken.append((i, self._windows - take_n, self._windows))
        return -taken_q

    def _span_p(
        self, d: np.ndarray, used: np.ndarray, p: np.ndarray, spans: ArrayLike | None
    ) -> np.ndarray:
        """The predictions the granularity term of a mouse whose report span the window's
        edges cut takes its change of motion from: the other mice's (leave one out), where
        they have the rank.  From p itself, a jump spread over the span would move p, and
        with it its own tolerance, by a share of the jump: a glitch would excuse itself."""
        out = p
        cut = np.asarray(spans if spans is not None else np.zeros(self.n), dtype=float) > 0
        gains = None
        for i in np.flatnonzero(cut & used).tolist():
            if gains is None:
                gains = self.others_gain_list(tuple(used.tolist()))
            out = out.copy() if out is p else out
            if any(gains[i]):
                # block deletion: the others' solve's prediction, as the common case takes
                # it (steady.steady_window, screenbatch)
                dx, dy = float(d[i, 0]), float(d[i, 1])
                out[i] = others_word(dx, dy, float(p[i, 0]), float(p[i, 1]), gains[i])
                continue
            rest = used.copy()  # the others place it poorly or not at all: their solve
            rest[i] = False
            q = self._solve(d, rest)
            if q is not None:
                out[i] = self.predict(q)[i]
        return out

    def _reexamine(self, d, live, used, gate, scale, gran2=None, spans=None) -> list[int] | None:
        """Revisit earlier exclusions when the kept set fails and nobody in it can be
        blamed (module step 3b): among all live mice the sensor did not gate, the
        explanation of this window, if it excludes no more mice than are held out (the
        current choice fails; one that explains the window is better).  A
        healthy mouse blamed in a window the geometry could not tell (the diagonal pair
        of a square in a pivot) is then not locked out while the faulty one stays in.
        (Where the kept set can blame one of its own, that is taken: swapping mice back
        in on every jump of another lets a mouse that reads short in with it.)"""
        held_out = live & ~used & (gate == 0)
        if not held_out.any():
            return None
        every = used | held_out
        q = self._solve(d, every)
        if q is None:
            return None
        p = self.predict(q)
        gp = None if gran2 is None else self._span_p(d, every, p, spans)
        floor, prop = self.noise.parts(d, p, self.prev_p, gran2=gran2, gran_p=gp)
        s2 = floor * scale + prop
        swap = self._identify(d, every, s2)
        if swap is None or len(swap) > int(held_out.sum()):
            return None
        return list(swap)

    def _identify(self, d: np.ndarray, used: np.ndarray, s2: np.ndarray):
        """The mice whose exclusion alone restores consistency, or None (module step 3)."""
        idx = np.flatnonzero(used)
        for size in (1, 2):
            if self.dof(len(idx) - size) < 1:
                return None
            passing = []
            fits: dict[tuple[int, ...], float] = {}  # every explanation's statistic
            for combo in map(list, itertools.combinations(idx.tolist(), size)):
                sub = used.copy()
                sub[combo] = False
                stat = self._statistic(d, sub, s2)
                if stat is None:
                    continue
                fits[tuple(combo)] = stat.t
                if self._passes(stat):
                    passing.append(Explanation(combo, stat))
            if len(passing) == 1:
                return passing[0].excluded
            if len(passing) > 1:
                return self._tie_break(d, passing, s2, used, fits)
            if not fits:
                return None
        return None

    def _tie_break(
        self,
        d: np.ndarray,
        passing: list[Explanation],
        s2: np.ndarray,
        used: np.ndarray,
        fits: dict[tuple[int, ...], float],
    ) -> list[int] | None:
        """Several exclusions explain the window (the geometry cannot tell the fault's
        direction apart): evidence and physical priors decide, or nobody is blamed.  First
        the fit: an explanation that leaves far less residual than every other (by the
        0.999 quantile of chi-square with one degree, a likelihood ratio over 200) wins,
        where the next one fits worse than its own median (``_fits_badly``).
        Then continuity of motion: a robot does not change its motion by a multiple of its
        tolerance from one window to the next, a glitching sensor does, so an explanation
        whose motion is by far the closest to the motion its own mice read HISTORY_S
        earlier wins (not the previous window's solution: a fault that crept in below the
        test's tolerance has already bent that towards itself), where it is also by far
        the closest to that motion carried on from twice as far back (a ramp), and unless
        the fit speaks against it (FIT_VETO).  Then a mouse that reads as a lifted one
        while the rest say it moved (``_lifted``).  The fit (``fits``: every exclusion of
        the passing ones' size, its statistic) is judged summed over the tie's windows
        (``_fit_sums``)."""
        sums, run = self._fit_sums(used, fits)
        ranked = sorted(passing, key=lambda c: sums[tuple(c.excluded)])
        worse = sums[tuple(ranked[1].excluded)]
        if worse - sums[tuple(ranked[0].excluded)] > _FIT_MARGIN and _fits_badly(
            worse, ranked[1].stat.dof * run
        ):
            return ranked[0].excluded
        silent = []
        change = []
        then, then2 = self._then(), self._then(2)
        trend = []
        for combo, stat in passing:
            p = self.predict(stat.q)
            if all(self._lifted(d, p, s2, j) for j in combo):
                silent.append(combo)
            before = self.prev_p
            ahead = None
            if then is not None:
                # the same mice's motion a few windows back: a fault that crept in below
                # the test's tolerance has bent the previous window's solution towards
                # itself, not these mice's own readings of then
                kept = used.copy()
                kept[list(combo)] = False
                q_then = self._solve(then, self._read_then(then, kept))  # None without rank
                if q_then is not None:
                    before = self.predict(q_then)
                    if then2 is not None:
                        # and twice as far back: the motion carried on from the two in a
                        # straight line (a steady change of speed or turn, a ramp)
                        q2 = self._solve(then2, self._read_then(then2, kept))
                        if q2 is not None:
                            ahead = 2.0 * before - self.predict(q2)
            change.append((_moved_by(p, before, s2), combo))
            if ahead is not None:
                trend.append((_moved_by(p, ahead, s2), combo))
        change.sort(key=lambda c: c[0])
        trend.sort(key=lambda c: c[0])
        # The other explanation must need a change of motion beyond the tolerance itself:
        # at a standstill every explanation's change is noise, and ratios of noise decide
        # nothing.  Nor may the motion decide where a ramp would choose otherwise: as the
        # robot speeds up or a turn eases off, a mouse that under-reads makes the smaller
        # change, and the healthy mouse was taken out (a triangle's mouse reading half as
        # a pivot began: 0.64 m and 13 degrees off; a far-one rig's mouse behind the far
        # one as a turn eased off: 2.9 m and 104 degrees, fault handling off 0.17 m).  The
        # smoother explanation must also be the smoother by the margin against the motion
        # carried on from twice as far back (its threshold left out: that line's two
        # windows' noise is the larger); else the rule after this one or the windows
        # after, summed, decide.  Where the ramp is not known for every explanation (the
        # first 100 ms, an explanation without rank then), the look-back alone decides.
        ramp_agrees = len(trend) < len(change) or (
            trend[0][1] == change[0][1] and trend[0][0] * _CONTINUITY_MARGIN < trend[1][0]
        )
        # Nor for an explanation that fits worse than another, where its fit summed over
        # the tie is beyond its own FIT_VETO quantile: the fit speaks against it, short
        # of its margin (a wide rig's mouse under-reading as a turn began: two windows
        # summed 0.2 leaving it out and 8.0 leaving a healthy one out, the motion chose
        # the healthy one, and the drive ended 1.24 m off, fault handling off 0.71 m).
        # Below that quantile the sums are noise, and a jump, which the motion tells,
        # would be let into the pose while the windows after decide.
        smooth = change[0][1]
        if (change[0][0] * _CONTINUITY_MARGIN < change[1][0]
                and change[1][0] > self._thresholds[2 * self.n]
                and ramp_agrees
                and (smooth == ranked[0].excluded
                     or sums[tuple(smooth)] <= chi2.sum_quantile(
                         FIT_VETO, ranked[0].stat.dof * run))):  # fmt: skip
            return smooth
        return silent[0] if len(silent) == 1 else None

    def _lifted(self, d: np.ndarray, p: np.ndarray, s2: np.ndarray, j: int) -> bool:
        """Whether mouse j reads as a lifted mouse does under an explanation that
        predicts ``p``: nothing beyond its own noise floor (an optical sensor off the floor
        reads nothing, or noise: a noisy lift's 1.5 counts a report), where the rest say
        it moved beyond its error, and the window before's solution moved it beyond its
        floor too (a 125 Hz mouse's first window of a motion may hold no report yet: a
        far-one rig's far mouse was blamed for it, 2.0 m off at the end).  Judged on its floor,
        not on its prediction: a fault that bends an explanation's motion makes a
        healthy mouse read short of it (a close pair's under-reading mouse made the far
        mouse read a tenth of the spin it implied: 1.6-5.8 m off).  Exact silence alone
        missed a noisy lift: a triangle, both the lift and the spin about the lifted
        mouse passing, was suspect for the lift's 1.5 s and ended 0.45 m and 45 degrees
        off (told the lift: 1 mm)."""
        floor2 = self._thresholds[2] * self.noise.f_floor[j]
        prev = self._prev[j]
        return bool(
            d[j] @ d[j] <= floor2
            and p[j] @ p[j] > self._thresholds[2] * s2[j]
            and prev[0] * prev[0] + prev[1] * prev[1] > floor2
        )

    def _fit_sums(
        self, used: np.ndarray, fits: dict[tuple[int, ...], float]
    ) -> tuple[dict[tuple[int, ...], float], int]:
        """Each explanation's statistic (``fits``: every exclusion of the tied size, passing
        or not) summed over this window and the failing windows before it in which the same
        mice were tested, and the number of windows summed: independent windows'
        likelihoods multiply, so the summed statistics' difference is the likelihood ratio
        of all of them.  A window alone may not tell (a triangle's front mouse reading half
        in a spin, with learnt tolerances that a 125 Hz mouse's report timing widens,
        passes either way with a difference of 7-8 where the margin is 10.8); five in a row
        do, and without it the continuity of motion took a healthy mouse out instead, 64
        degrees lost in the fault's 3 s.  The sum goes on across windows that passed whole
        (fewer than HISTORY_S of them in a row: they tell the explanations nothing apart) and
        across windows where other explanations passed too (each is summed whether it
        passed or not): a wide rig's mouse under-reading in an arc, a window in four
        passing or a third explanation passing now and then cut every run short of the
        margin, the fit's evidence against the healthy mouse (10.9 against 1.2 in nine
        windows) was lost, and continuity took the healthy mouse out: 3.5 m off at the
        end, fault handling off 1.7 m."""
        key = tuple(used.tolist())
        last, sums, run = self._ties.get(key, (-2, {}, 0))
        if last >= self._windows - self.history_len and sums.keys() == fits.keys():
            fits = {c: sums[c] + t for c, t in fits.items()}
            run += 1
        else:
            run = 1
        # (entries too old to continue a run are dropped)
        self._ties = {
            k: v for k, v in self._ties.items() if v[0] >= self._windows - self.history_len
        }
        self._ties[key] = (self._windows, fits, run)
        return fits, run

    def _read_then(self, then: np.ndarray, kept: np.ndarray) -> np.ndarray:
        """Of the ``kept`` mice, those whose readings ``then`` can say how the rig moved:
        a mouse that read nothing is left out where the rest (every other kept mouse,
        its zero or not) moved it beyond its sigma (a lift, or a fault creeping in); one
        the rest leave still, or that the rest cannot place without, read what it did.
        A mouse at a spin's pivot truly reads nothing: left out, the motion before of an
        explanation that blames another mouse had no rank and fell back on the previous
        window's, bent by the fault's onset, and a line of three blamed its healthy
        middle mouse for a lift at its end (1.3 m off at the end of a drive, against 5 mm
        informed)."""
        out = kept
        nothing = norm2(then) <= SILENT_SHARE * self.noise.sig2  # (``_silent``'s rule)
        for i in np.flatnonzero(kept & nothing).tolist():
            q = self._solve(then, _but(kept, i))
            if (
                q is not None
                and norm2(self.predict(q)[i]) > self._thresholds[2] * self.noise.sig2[i]
            ):
                out = _but(out, i)
        return out

    def _then(self, k: int = 1) -> np.ndarray | None:
        """The readings of the window k times HISTORY_S back, (N, 2); None before there
        are as many."""
        h = self.history
        if len(h) < k * self.history_len:
            return None
        return np.asarray(h[-k * self.history_len], dtype=float).reshape(self.n, 2)

    def _update(self, d, p, live, used, suspect, reason, consistent, floor, prop) -> None:
        """Health after the window: exclusions, suspicion, re-admission (module step 4)."""
        self._steady_known = False
        s2 = floor + prop
        m2 = np.maximum(np.sum(d * d, axis=1), np.sum(p * p, axis=1))
        not_proportional = s2 - self.noise.lam_r * self.noise.rho2 * m2
        held = live & ~used
        pc = (self.prediction_cov(used, s2) if held.any() and used.any()
              else np.zeros((self.n, 2, 2)))  # fmt: skip
        for i, h in enumerate(self.health):
            if not live[i]:
                h.state, h.reason, h.good = MISSING, NONE, 0
                fresh_wait(h)
                continue
            if h.state == MISSING:
                h.state, h.reason, h.good = TRACKING, NONE, 0
            if not used[i]:
                self._held_out(i, h, d, p, reason[i], s2[i], not_proportional[i], pc[i])
                continue
            if suspect[i]:
                h.state, h.reason, h.good = SUSPECT, reason[i] or INCONSISTENT, 0
            elif h.state in (EXCLUDED, LATE):  # back by a re-examination, or for rank
                h.state, h.good = SUSPECT, 0
                self.ledger.readmit(i)  # in use again: what it is owed is settled now
            elif h.state == SUSPECT and consistent:
                h.good += 1
                if h.good >= self.readmission.readmit:
                    h.state, h.reason, h.good = TRACKING, NONE, 0

    def _held_out(self, i: int, h: MouseHealth, d: np.ndarray, p: np.ndarray, why: int,
                  s2: float, not_proportional: float, pred_cov: np.ndarray) -> None:  # fmt: skip
        """_update for a live mouse left out of this window's solve: held out by it
        (blamed, or gated by its sensor's evidence), or held out before (late, or
        excluded and counting toward re-admission).  ``pred_cov``: the covariance (2, 2) of
        its prediction ``p[i]`` from the mice in use (``prediction_cov``)."""
        thr2 = self._thresholds[2]
        if h.state in (EXCLUDED, LATE) and why in (SATURATED, LOW_QUALITY):
            # its sensor's word on a mouse held out already: out for that now, and what it
            # owes goes on (a late mouse's debt is still to be paid back)
            self.ledger.carry(i, d[i] - p[i], s2, pred_cov)
            self.readmission.end_run(self.ledger, i, h)
            fresh_wait(h)
            h.state, h.reason, h.good = EXCLUDED, why, 0
            return
        if h.state not in (EXCLUDED, LATE) or why != NONE:
            # late where it is short by its last moments' motion (lateness), unless it
            # was excluded already (held out again by a re-examination)
            self.ledger.hold(i, d[i] - p[i], s2, pred_cov)
            fresh_wait(h)
            h.good = 0
            tol2 = thr2 * 2.0 * s2
            if (h.state != EXCLUDED and why in (SILENT, INCONSISTENT)
                    and self.lateness.explains(i, self.ledger.owed[i], p[i], tol2)):  # fmt: skip
                h.state, h.reason = LATE, why
                self.lateness.held[i] = 1
            else:
                h.state, h.reason = EXCLUDED, why or INCONSISTENT
            return
        self.ledger.carry(i, d[i] - p[i], s2, pred_cov)
        if h.state == LATE:
            self._late(d, p, i, h, thr2 * 2.0 * self.ledger.owed_s2[i])
            return
        back = self.readmission
        grouped = back.grouped(h, d[i], p[i], s2, not_proportional, pred_cov)
        if grouped is not None:  # (None: the group goes on)
            back.waiting(self.ledger, i, h, *grouped, beyond=i in self._held_beyond,
                         reads_nothing=self._reads_nothing(grouped[0], i))  # fmt: skip

    def _late(self, d: np.ndarray, p: np.ndarray, i: int, h: MouseHealth, tol2: float) -> None:
        """A late mouse after one more window: back once its debt is paid (what it owed is
        then added to the pose, ``ledger``); excluded once it has lagged beyond
        ``late_s`` or owes what no lateness explains (``lateness``)."""
        owed = self.ledger.owed[i]
        if self.ledger.paid(i) and not self._short_now[i]:
            # paid back, and not short in this window (a mouse reading noise, lifted, can
            # owe little over a window or two while its shortfall goes on); its
            # shortfall's sum is settled with its debt
            self._quiet_reset(i)
            h.state, h.reason, h.good = TRACKING, NONE, 0
            self.ledger.readmit(i)
            return
        late = self.lateness
        late.held[i] += 1
        if late.held[i] > late.limit or not late.explains(i, owed, p[i], tol2):
            h.state, h.good = EXCLUDED, 0
            if self._silent(d, i):
                h.reason = SILENT
