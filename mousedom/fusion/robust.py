"""Fault-tolerant fusion: test each window's mice against the rigid-body model, exclude the
mouse (or mice) whose readings the others contradict, and keep a health state per mouse.

A lifted mouse goes silent, a glossy patch makes one under-read, a seam makes one jump, a
fast turn saturates one: each is a reading that no rigid motion of the rig explains
together with the others.  Per window (docs/models.md, "Faults"):

1. The live mice's readings d are solved as today (weighted least squares, W = sigma^-2),
   and their residuals are normalised by each mouse's expected error over the window,
       s_i^2 = sigma_i^2 + (rho max(|d_i|, |p_i|))^2 + (g_i |p_i - p_i'|)^2,
   where p_i is the solution's prediction of the mouse's displacement (p_i' the previous
   window's), rho the relative reading error (CPI error, stamp jitter: ``relative_noise``)
   and g_i = min(1, P_i / T) / 4 for a mouse reporting every P_i into windows of T: a
   report that straddles a window edge is split in proportion to time, which is wrong by up
   to a quarter of the change of motion within it.  The s_i are taken from the solution
   with every candidate mouse and kept while mice are left out in turn, so that a faulty
   mouse cannot widen its own tolerance by moving the solution.
2. T = min_q sum_i |d_i - A_i q|^2 / s_i^2 is chi-square with 2L - k degrees of freedom on
   a healthy rig of L mice and k unknowns, whatever the layout.  Above its (1 - alpha)
   quantile (``false_alarm`` alpha, 1e-4 by default) the window is inconsistent.
3. Then each mouse (then each pair) is left out in turn, where the rest still determine the
   model with at least one redundant reading; if exactly one choice makes the rest
   consistent, those mice are excluded.  Where several do (the geometry cannot tell, e.g.
   mice on one line), a mouse that is silent while the others say it moved is the one;
   otherwise nobody is blamed: the window keeps all mice, its covariance is multiplied by
   T / dof, and the mice become ``suspect``.
4. An excluded mouse is re-admitted after ``readmit_s`` of windows in which it agreed with
   the others while they moved enough to have shown the fault.

Sensor evidence gates a mouse before any of this: SQUAL below ``min_squal`` or the
sensor's overflow flag ("low quality"), a reading or a prediction beyond ``max_speed``
("saturated").  Decisions use only the window and the ones before it: nothing reaches back
to change a window already published, so the daemon and replay give the same poses.

The common case (every mouse tracking, the window consistent) is decided by ``fast_one`` on
Python floats (the daemon) or ``batch`` for whole arrays (replay); only windows where
something happens take ``decide``, the one exact path both share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mousedom.config import RobustConfig
from mousedom.fusion import chi2, models

TRACKING, SUSPECT, EXCLUDED, MISSING = 0, 1, 2, 3
STATES = ("tracking", "suspect", "excluded", "missing")
NONE, INCONSISTENT, SILENT, SATURATED, LOW_QUALITY = 0, 1, 2, 3, 4
REASONS = ("", "inconsistent", "silent while others move", "saturated", "low quality")

# A SQUAL at this value or above leaves the noise as configured; below it (and above the
# gate) the expected error grows as 1/sqrt(SQUAL): fewer features, a noisier correlation.
SQUAL_FULL = 30

# How much smoother than the next one the winning explanation's motion must be (tie_break).
_CONTINUITY_MARGIN = 10.0


@dataclass
class MouseHealth:
    state: int = TRACKING
    reason: int = NONE
    good: int = 0  # consecutive windows of agreement toward re-admission


@dataclass(frozen=True)
class Decision:
    """What ``decide`` made of one window."""

    used: np.ndarray  # (N,) bool: the mice the window is solved with
    inflate: float  # the q covariance's factor (1 unless inconsistent and unattributed)
    consistent: bool


class Screen:
    """The per-window test and the mice's health (module docstring).  No I/O, no clock."""

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
        self.settings = settings
        self.n = len(positions)
        self.positions = np.asarray(positions, dtype=float)
        self.sigma = np.asarray(sigma, dtype=float)
        self.cols = (0, 2) if model == "diff-drive" else (0, 1, 2)
        self.k = len(self.cols)
        self.alpha = settings.false_alarm
        self.rho2 = settings.relative_noise**2
        periods = np.asarray(report_periods, dtype=float)
        self.gran2 = (0.25 * np.minimum(1.0, periods / window)) ** 2
        speed = np.full(self.n, np.inf) if max_speed is None else np.asarray(max_speed, float)
        self.max_step2 = (speed * window) ** 2  # inf: no limit
        self.readmit = max(1, math.ceil(settings.readmit_s / window - 1e-9))
        self.health = [MouseHealth() for _ in range(self.n)]
        self.prev_d = np.zeros((self.n, 2))
        self.prev_p = np.zeros((self.n, 2))
        # Python copies for fast_one
        self._xy = self.positions.tolist()
        self._sig2 = (self.sigma**2).tolist()
        self._gran2 = self.gran2.tolist()
        self._max2 = self.max_step2.tolist()
        self._prev = [[0.0, 0.0, 0.0, 0.0] for _ in range(self.n)]  # dx, dy, px, py

    # ----------------------------------------------------------------- thresholds

    def threshold(self, dof: int) -> float:
        return chi2.quantile(1.0 - self.alpha, dof)

    def dof(self, n_used: int) -> int:
        return 2 * n_used - self.k

    # ----------------------------------------------------------------- common case

    def steady(self) -> tuple[bool, ...] | None:
        """The live pattern under which the common case applies (every tracking mouse
        live, every missing one not), or None while some mouse is suspect or excluded."""
        out = []
        for h in self.health:
            if h.state == TRACKING:
                out.append(True)
            elif h.state == MISSING:
                out.append(False)
            else:
                return None
        return tuple(out)

    def fast_one(
        self, d: list[list[float]], q: list[float], live: tuple[bool, ...], evidence: bool
    ) -> bool:
        """The common case on floats: True (and the window is accepted as solved) when the
        state is steady for ``live``, no sensor evidence (SQUAL, overflow) is in the window,
        no mouse is beyond its speed and the test passes."""
        if evidence or live != self.steady():
            return False
        ux, uy, a = q
        total = 0.0
        n_used = 0
        for i, (x, y) in enumerate(self._xy):
            px, py = ux - a * y, uy + a * x
            dx, dy = d[i]
            prev = self._prev[i]
            if live[i]:
                m2 = max(dx * dx + dy * dy, px * px + py * py)
                if m2 >= self._max2[i]:
                    return False  # saturated: decide
                fx, fy = px - prev[2], py - prev[3]
                s2 = self._sig2[i] + self.rho2 * m2 + self._gran2[i] * (fx * fx + fy * fy)
                rx, ry = dx - px, dy - py
                total += (rx * rx + ry * ry) / s2
                n_used += 1
        dof = 2 * n_used - self.k
        if dof > 0 and total > self.threshold(dof):
            return False
        for i, (x, y) in enumerate(self._xy):
            self._prev[i] = [d[i][0], d[i][1], ux - a * y, uy + a * x]
        return True

    def _sync_prev_from_floats(self) -> None:
        arr = np.array(self._prev)
        self.prev_d, self.prev_p = arr[:, :2].copy(), arr[:, 2:].copy()

    def _sync_prev_to_floats(self) -> None:
        self._prev = np.concatenate([self.prev_d, self.prev_p], axis=1).tolist()

    # ----------------------------------------------------------------- the exact path

    def _predict(self, q: np.ndarray) -> np.ndarray:
        """Each mouse's displacement (N, 2) under the body twist increment q."""
        x, y = self.positions[:, 0], self.positions[:, 1]
        return np.stack([q[0] - q[2] * y, q[1] + q[2] * x], axis=1)

    def _solve(self, d: np.ndarray, used: np.ndarray) -> np.ndarray | None:
        """q (3,) by the configured weights on the ``used`` mice; None without rank."""
        if not used.any():
            return None
        est = models._estimator(
            self.positions.tobytes(), self.sigma.tobytes(), used.tobytes(), self.cols
        )
        if est is None:
            return None
        q = np.zeros(3)
        q[list(self.cols)] = est[1] @ d[used].reshape(-1)
        return q

    def _s2(self, d: np.ndarray, p: np.ndarray, squal_scale: np.ndarray) -> np.ndarray:
        m2 = np.maximum(np.sum(d * d, axis=1), np.sum(p * p, axis=1))
        a2 = np.sum((p - self.prev_p) ** 2, axis=1)
        return self.sigma**2 * squal_scale + self.rho2 * m2 + self.gran2 * a2

    def _statistic(self, d: np.ndarray, used: np.ndarray, s2: np.ndarray):
        """(T, dof, q) for the ``used`` mice, or None without rank: T is the minimum over
        q of sum |d_i - A_i q|^2 / s2_i."""
        q = self._solve(d, used)
        if q is None:
            return None
        dof = self.dof(int(used.sum()))
        if dof <= 0:
            return 0.0, dof, q
        s = np.sqrt(s2)[used]
        a = np.zeros((int(used.sum()), 2, 3))
        pos = self.positions[used]
        a[:, 0, 0] = 1.0
        a[:, 1, 1] = 1.0
        a[:, 0, 2] = -pos[:, 1]
        a[:, 1, 2] = pos[:, 0]
        a = (a[:, :, list(self.cols)] / s[:, None, None]).reshape(-1, self.k)
        b = (d[used] / s[:, None]).reshape(-1)
        sol = np.linalg.lstsq(a, b, rcond=None)[0]
        r = b - a @ sol
        return float(r @ r), dof, q

    def _passes(self, stat) -> bool:
        return stat is not None and stat[1] > 0 and stat[0] <= self.threshold(stat[1])

    def decide(
        self,
        d: np.ndarray,
        live: np.ndarray,
        squal_scale: np.ndarray | None = None,
        low_quality: np.ndarray | None = None,
    ) -> Decision:
        """The exact per-window decision (module docstring, steps 1-4); updates health."""
        n = self.n
        d = np.asarray(d, dtype=float).reshape(n, 2)
        live = np.asarray(live, dtype=bool)
        scale = np.ones(n) if squal_scale is None else np.asarray(squal_scale, dtype=float)
        lowq = np.zeros(n, dtype=bool) if low_quality is None else np.asarray(low_quality)
        health = self.health
        excluded = np.array([h.state == EXCLUDED for h in health])
        used = live & ~excluded
        if self._solve(d, used) is None:
            used = live.copy()  # the healthy ones alone cannot: the excluded must serve
        q = self._solve(d, used)
        p = self._predict(q) if q is not None else np.zeros((n, 2))
        # Sensor evidence first.
        d2, p2 = np.sum(d * d, axis=1), np.sum(p * p, axis=1)
        gate = np.zeros(n, dtype=int)
        gate[live & (np.maximum(d2, p2) >= self.max_step2)] = SATURATED
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
            p = self._predict(q) if q is not None else p
        inflate, consistent = 1.0, True
        s2 = self._s2(d, p, scale)
        stat = self._statistic(d, used, s2)
        if stat is not None and stat[1] > 0 and not self._passes(stat):
            blamed = self._identify(d, used, s2)
            if blamed is not None:
                for j in blamed:
                    reason[j] = SILENT if not d[j].any() else INCONSISTENT
                used = used.copy()
                used[list(blamed)] = False
                q = self._solve(d, used)
                p = self._predict(q)
            else:
                consistent = False
                inflate = stat[0] / stat[1]
                suspect |= used
                reason[used & (reason == NONE)] = INCONSISTENT
        self._update(d, p, live, used, suspect, reason, consistent, scale)
        self.prev_d, self.prev_p = d.copy(), p
        self._sync_prev_to_floats()
        return Decision(used=used, inflate=inflate, consistent=consistent)

    def _identify(self, d: np.ndarray, used: np.ndarray, s2: np.ndarray):
        """The mice whose exclusion alone restores consistency, or None (module step 3)."""
        idx = np.flatnonzero(used)
        for size in (1, 2):
            if self.dof(len(idx) - size) < 1:
                return None
            passing = []
            tested = 0
            for combo in _combinations(idx.tolist(), size):
                sub = used.copy()
                sub[combo] = False
                stat = self._statistic(d, sub, s2)
                if stat is None:
                    continue
                tested += 1
                if self._passes(stat):
                    passing.append((combo, stat))
            if len(passing) == 1:
                return passing[0][0]
            if len(passing) > 1:
                return self._tie_break(d, passing, s2)
            if tested == 0:
                return None
        return None

    def _tie_break(self, d: np.ndarray, passing: list, s2: np.ndarray):
        """Several exclusions explain the window (the geometry cannot tell the fault's
        direction apart): the physical priors decide, or nobody is blamed.  First a mouse
        that is silent while the rest say it moved (a lift); then continuity of motion: a
        robot does not change its motion by a multiple of its tolerance between two
        windows, a glitching sensor does, so the explanation whose motion is by far the
        closest to the previous window's wins."""
        thr2 = self.threshold(2)
        silent = []
        change = []
        for combo, stat in passing:
            p = self._predict(stat[2])
            if all(not d[j].any() and p[j] @ p[j] > thr2 * s2[j] for j in combo):
                silent.append(combo)
            change.append((float(np.sum(np.sum((p - self.prev_p) ** 2, axis=1) / s2)), combo))
        if len(silent) == 1:
            return silent[0]
        if silent:
            return None
        change.sort(key=lambda c: c[0])
        if change[0][0] * _CONTINUITY_MARGIN < change[1][0]:
            return change[0][1]
        return None

    def _update(self, d, p, live, used, suspect, reason, consistent, scale) -> None:
        """Health after the window: exclusions, suspicion, re-admission (module step 4)."""
        s2 = self._s2(d, p, scale)
        a2 = np.sum((p - self.prev_p) ** 2, axis=1)
        floor2 = self.sigma**2 * scale + self.gran2 * a2  # the error not in proportion
        thr2 = self.threshold(2)
        for i, h in enumerate(self.health):
            if not live[i]:
                h.state, h.reason, h.good = MISSING, NONE, 0
                continue
            if h.state == MISSING:
                h.state, h.reason, h.good = TRACKING, NONE, 0
            if not used[i]:
                if h.state != EXCLUDED or reason[i] != NONE:
                    # excluded by this window (blamed, or gated by its sensor's evidence)
                    h.state, h.reason, h.good = EXCLUDED, reason[i] or INCONSISTENT, 0
                    continue
                # Excluded earlier: count the windows that would have shown its fault
                # (the others moved it well beyond its error) and where it agreed.
                r = d[i] - p[i]
                if r @ r > thr2 * s2[i]:
                    h.good = 0
                    h.reason = SILENT if not d[i].any() else INCONSISTENT
                elif p[i] @ p[i] > 4.0 * thr2 * floor2[i]:
                    h.good += 1
                    if h.good >= self.readmit:
                        h.state, h.reason, h.good = TRACKING, NONE, 0
                continue
            if suspect[i]:
                h.state, h.reason, h.good = SUSPECT, reason[i] or INCONSISTENT, 0
            elif h.state == EXCLUDED:  # in use only because the rest lack rank
                h.state, h.good = SUSPECT, 0
            elif h.state == SUSPECT and consistent:
                h.good += 1
                if h.good >= self.readmit:
                    h.state, h.reason, h.good = TRACKING, NONE, 0

    # ----------------------------------------------------------------- arrays (replay)

    def batch(
        self,
        d: np.ndarray,
        mask: np.ndarray,
        q: np.ndarray,
        squal_scale: np.ndarray | None = None,
        low_quality: np.ndarray | None = None,
    ):
        """``decide`` for consecutive windows, fast where nothing happens.

        d: (n, N, 2) readings; mask: (n, N) live mice; q: (n, 3) today's solution with that
        mask.  Returns (used (n, N), inflate (n,), consistent (n,), state (n, N),
        reason (n, N)).
        """
        n, nm = mask.shape
        used = mask.copy()
        inflate = np.ones(n)
        consistent = np.ones(n, dtype=bool)
        state = np.where(mask, TRACKING, MISSING).astype(np.int8)
        reason = np.zeros((n, nm), dtype=np.int8)
        if n == 0:
            return used, inflate, consistent, state, reason
        p = (
            q[:, None, :2]
            + q[:, None, 2:3]
            * np.stack([-self.positions[:, 1], self.positions[:, 0]], axis=1)[None]
        )
        fast = self._fast_rows(d, p, mask, squal_scale, low_quality)
        codes = mask.astype(np.int64) @ (np.int64(1) << np.arange(nm, dtype=np.int64))
        bad = np.flatnonzero(~fast)
        changes = np.flatnonzero(codes[1:] != codes[:-1]) + 1
        self._sync_prev_from_floats()
        i = 0
        prev_altered = False
        while i < n:
            steady = self.steady()
            if steady is not None and not prev_altered:
                code = sum(1 << k for k, v in enumerate(steady) if v)
                if codes[i] == code:
                    j = min(_next(bad, i, n), _next(changes, i + 1, n))
                    if j > i:
                        self.prev_d, self.prev_p = d[j - 1].copy(), p[j - 1].copy()
                        i = j
                        continue
            sq = None if squal_scale is None else squal_scale[i]
            lq = None if low_quality is None else low_quality[i]
            dec = self.decide(d[i], mask[i], sq, lq)
            used[i] = dec.used
            inflate[i] = dec.inflate
            consistent[i] = dec.consistent
            state[i] = [h.state for h in self.health]
            reason[i] = [h.reason for h in self.health]
            # the next window's changes are from this one's own solution: decide them too
            prev_altered = not np.array_equal(dec.used, mask[i])
            i += 1
        self._sync_prev_to_floats()
        return used, inflate, consistent, state, reason

    def _fast_rows(self, d, p, mask, squal_scale, low_quality) -> np.ndarray:
        """The common case's test for every row at once, with the previous row taken as
        the unaltered one (``batch`` sends a row after an altered one to ``decide``)."""
        prev_p = np.concatenate([self.prev_p[None], p[:-1]])
        d2, p2 = np.sum(d * d, axis=2), np.sum(p * p, axis=2)
        m2 = np.maximum(d2, p2)
        a2 = np.sum((p - prev_p) ** 2, axis=2)
        s2 = self.sigma**2 + self.rho2 * m2 + self.gran2 * a2
        r = d - p
        t = np.sum(np.where(mask, np.sum(r * r, axis=2) / s2, 0.0), axis=1)
        dof = 2 * mask.sum(axis=1) - self.k
        thr = np.array([self.threshold(k) if k > 0 else np.inf for k in range(2 * self.n + 1)])
        ok = (dof <= 0) | (t <= thr[np.maximum(dof, 0)])
        ok &= ~np.any(mask & (m2 >= self.max_step2), axis=1)
        if squal_scale is not None:
            ok &= ~np.any(mask & (squal_scale != 1.0), axis=1)
        if low_quality is not None:
            ok &= ~np.any(mask & low_quality, axis=1)
        return ok


def _next(sorted_idx: np.ndarray, i: int, n: int) -> int:
    k = int(np.searchsorted(sorted_idx, i))
    return int(sorted_idx[k]) if k < len(sorted_idx) else n


def _combinations(items: list[int], size: int):
    if size == 1:
        for a in items:
            yield [a]
    else:
        for x, a in enumerate(items):
            for b in items[x + 1 :]:
                yield [a, b]
