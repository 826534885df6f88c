"""How fast each mouse's reading error accumulates, learnt from the redundancy (issue 31).

A window's reading error has two parts.  One telescopes: a count read a few ms late, a
report split at a window edge in proportion to time, a count's rounding carried to the
next report, all move counts between neighbouring windows and not out of their sum.  The
other accumulates: noise in what the sensor measured, which no later window gives back.
Only the second moves the pose for good, so only it belongs in the pose's covariance;
the first is what a window's residual mostly shows (at 0.4 m/s a stamp 1 ms late moves
16 counts between windows, against a fraction of a count of noise).  So the per-window
residual, which the consistency test learns from (``noisemodel``), is the wrong measure
here: the covariance built on it was too wide, and the config's sigma, a guess, too
narrow (NEES 5 on healthy drives where 3 is expected).

The two parts separate in the residuals summed over spans of consecutive windows (R, a
mouse's residual in body axes, under one pattern of mice in use).  Over a span of L
windows in which the rig moved in m of them,

    E |R(t + L) - R(t)|^2 / 2 = (K v)_i m + c_i

per axis: the accumulating part grows with the motion in the span, the telescoping part
(c) comes from the span's two ends only.  K (N x N) maps the mice's per-axis variances v
to their residuals' (K_ij = |P_ij|_F^2 / 2 with P = I - H the residual projection of the
least squares with the config's weights, all mice in use).  Spans of two lengths (SHORT_S
and LONG_S) give Kv as the difference of their mean squares over the difference of their
motion; v = K^-1 (K v), none below a floor.  Spans count only while every mouse is in use
in consistent windows (a fault's windows are not noise).

Where K has full rank (three or more mice on ``lsq``, two or more on ``diff-drive``),
each mouse's variance is learnt.  Where it has less (two mice on ``lsq``: one redundant
reading, the distance along the line joining them, so K has rank 1 and only a weighted
sum shows), the variances are taken in the proportions of the config's sigma^2 and one
factor is learnt, the least-squares fit of f K sigma^2 to K v: the config's guess of the
noise's level, which left two-mouse rigs' covariance too narrow (NEES 6.6 on healthy
drives, 11.7 with late stamps, where 3 is expected), is what the redundancy corrects.
With no redundant reading (one mouse on ``diff-drive``), nothing is learnt.  With fewer
than FEW_READINGS redundant readings (two mice), the learnt variance may raise the
config's sigma^2, not lower it: one or two readings' worth of residuals over the first
seconds make a noisy estimate, and a covariance too narrow by chance costs NEES far more
than one as much too wide saves (a drive of 9 s with the config's sigma right: NEES 3.4
with the config's, 4.8 with the estimate alone).  Learnt in
blocks of windows, the tracker's scale learner's (so the array and one-window paths
change at the same window), forgetting with a half-life of HALF_LIFE_S; until
MIN_MOVING_S of motion has been seen, ``noise`` is None and the covariance keeps the
config's sigma.
"""

from __future__ import annotations

import numpy as np

from mousedom.fusion.models import StepNoise
from mousedom.fusion.scalelearn import joined

SHORT_S = 0.1  # the shorter span: past the telescoping part's reach (a report or two)
LONG_S = 1.0  # the longer: ten times the motion, the same two ends
HALF_LIFE_S = 120.0  # of the evidence
MIN_MOVING_S = 5.0  # of motion in long spans before the estimate is used
# The least variance a mouse is given while moving, and the one in windows without a count
# (a still mouse reports nothing and so errs by nothing; kept above 0 so that the
# twist's covariance stays invertible), both relative to the config's sigma^2.
FLOOR = 1e-3
REST = 1e-4
RANK_TOL = 1e-6  # of K's singular values, relative to its largest
FEW_READINGS = 3  # redundant readings below which the config's sigma^2 is a floor


class NoiseRate:
    """Each mouse's accumulating reading error (module docstring)."""

    def __init__(
        self,
        positions: np.ndarray,
        sigma: np.ndarray,
        window: float,
        block: int,
        cols: tuple[int, ...] = (0, 1, 2),
    ) -> None:
        self.n = len(positions)
        pos = np.asarray(positions, dtype=float)
        sig2 = np.asarray(sigma, dtype=float) ** 2
        self.sig2 = sig2
        n2 = 2 * self.n
        a = np.zeros((n2, 3))
        a[0::2, 0] = 1.0
        a[1::2, 1] = 1.0
        a[0::2, 2] = -pos[:, 1]
        a[1::2, 2] = pos[:, 0]
        a = a[:, list(cols)]
        w = np.repeat(1.0 / sig2, 2)
        aw = a.T * w
        project = np.eye(n2) - a @ np.linalg.solve(aw @ a, aw)
        blocks = project.reshape(self.n, 2, self.n, 2)
        self.k = np.einsum("iajb,iajb->ij", blocks, blocks) / 2.0
        # K's rank: all of v where full, else one common factor of sigma^2 (docstring).
        # Relative to K's largest singular value (about 1: P is a projection), a rank-1 K
        # of two mice leaves 1e-17; a rig whose second value is below this is too near one
        # (mice almost at one point) for each mouse's share to be told.
        values = np.linalg.svd(self.k, compute_uv=False) if self.n else np.zeros(0)
        top = float(values[0]) if values.size else 0.0
        self.rank = int(np.sum(values > RANK_TOL * top)) if top > 0 else 0
        self._k_sig2 = self.k @ sig2
        # the redundant readings: the residual projection's rank (its trace)
        self.redundant = round(float(np.trace(project))) if self.n else 0
        self._floor = (1.0 if self.redundant < FEW_READINGS else FLOOR) * sig2
        self.block = int(block)
        self.short = max(1, round(SHORT_S / window))
        self.long = max(self.short + 1, round(LONG_S / window))
        self.forget = 0.5 ** (self.block * window / HALF_LIFE_S)
        self.min_moving = MIN_MOVING_S / window
        # Per span length (short, long): summed squared increments per mouse (axes
        # summed), spans, windows moved in them; all forgetting.
        self.square = np.zeros((2, self.n))
        self.spans = np.zeros(2)
        self.moved = np.zeros(2)
        # The current run of eligible windows: its last `long` residuals and moving flags
        # (the spans that end in the next block start in them).
        self._run_r = np.zeros((0, self.n, 2))
        self._run_m = np.zeros(0)
        self._rows: list[tuple] = []
        self._held = 0
        self.windows = 0  # windows learnt from so far (eligible or not)
        self.learnt_after: int | None = None  # windows seen when the estimate was first made
        self.noise: StepNoise | None = None
        self.variance: np.ndarray | None = None  # per mouse, per axis, metres^2 (moving)

    @property
    def active(self) -> bool:
        """Whether the rig has a redundant reading to learn from (K not zero)."""
        return self.rank > 0

    def until_block_end(self) -> int:
        """Windows still to add before the current block ends (at least 1)."""
        return self.block - self._held

    def add(self, residual: np.ndarray, eligible: np.ndarray, moving: np.ndarray) -> bool:
        """Add windows: ``residual`` (n, N, 2) body metres, ``eligible`` (n,) every mouse in
        use in a consistent window, ``moving`` (n,) a mouse counted.  At most the block's
        rest (the caller splits as for the scale learner); returns whether a block ended
        and the estimate was renewed."""
        if not self.active or not len(residual):
            return False
        self._rows.append((np.asarray(residual, dtype=float), np.asarray(eligible, dtype=bool),
                           np.asarray(moving, dtype=bool)))  # fmt: skip
        self._held += len(residual)
        return self.end_block()

    def add_row(self, residual: list, eligible: bool, moving: bool) -> bool:
        """``add`` for one window as Python values (the daemon's), without the learning:
        True when the block is full, and ``end_block`` is due before the next window."""
        if not self.active:
            return False
        self._rows.append(([residual], [eligible], [moving]))
        self._held += 1
        return self._held >= self.block

    def end_block(self) -> bool:
        """At a full block, learn from it (True); otherwise nothing (False)."""
        if self._held < self.block:
            return False
        parts = list(zip(*self._rows, strict=True))
        r = joined(parts[0], float).reshape(-1, self.n, 2)
        ok, mv = joined(parts[1], bool), joined(parts[2], float)
        self._rows, self._held = [], 0
        self.windows += len(ok)
        self._learn(r, ok, mv)
        return True

    def _learn(self, r: np.ndarray, ok: np.ndarray, mv: np.ndarray) -> None:
        self.square *= self.forget
        self.spans *= self.forget
        self.moved *= self.forget
        # Runs of eligible windows; the first continues the carried one if it starts here.
        breaks = np.flatnonzero(~ok)
        edges = [0, *breaks.tolist(), len(ok)]
        carried = len(self._run_r)
        for j, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
            a = a if j == 0 else a + 1
            if b <= a:
                if j == 0:
                    continue
                self._run_r, self._run_m, carried = self._run_r[:0], self._run_m[:0], 0
                continue
            if j == 0:
                run_r = np.concatenate([self._run_r, r[a:b]])
                run_m = np.concatenate([self._run_m, mv[a:b]])
                new_from = carried
            else:
                run_r, run_m, new_from = r[a:b], mv[a:b], 0
            self._spans(run_r, run_m, new_from)
            # copies: r may be the caller's array (``joined``), and a view would follow it
            self._run_r, self._run_m = run_r[-self.long :].copy(), run_m[-self.long :].copy()
        if not ok[-1]:
            self._run_r, self._run_m = self._run_r[:0], self._run_m[:0]
        self._estimate()

    def _spans(self, run_r: np.ndarray, run_m: np.ndarray, new_from: int) -> None:
        """Add the spans of this run that end at or after index ``new_from`` (earlier
        ones were counted in their own block)."""
        cum_r = np.concatenate([np.zeros((1, self.n, 2)), np.cumsum(run_r, axis=0)])
        cum_m = np.concatenate([[0.0], np.cumsum(run_m)])
        for s, length in enumerate((self.short, self.long)):
            first = max(length, new_from + 1)  # cum index of the first span's end
            if first > len(run_r):
                continue
            inc = cum_r[first:] - cum_r[first - length : len(cum_r) - length]
            self.square[s] += np.sum(inc * inc, axis=(0, 2))
            self.spans[s] += len(inc)
            starts = cum_m[first - length : len(cum_m) - length]
            self.moved[s] += float(np.sum(cum_m[first:] - starts))

    def _estimate(self) -> None:
        if self.spans[1] <= 0 or self.spans[0] <= 0:
            return
        mean_m = self.moved / self.spans
        if self.moved[1] < self.min_moving * self.long or mean_m[1] - mean_m[0] <= 0:
            return
        mean_sq = self.square / self.spans[:, None] / 2.0  # per axis
        kv = (mean_sq[1] - mean_sq[0]) / (mean_m[1] - mean_m[0])
        if self.rank == self.n:
            v = np.linalg.lstsq(self.k, kv, rcond=None)[0]
        else:  # one factor of the config's sigma^2 (module docstring)
            ks = self._k_sig2
            v = float(ks @ kv) / float(ks @ ks) * self.sig2
        v = np.maximum(v, self._floor)
        if not np.all(np.isfinite(v)):
            return
        self.variance = v
        if self.learnt_after is None:
            self.learnt_after = self.windows
        self.noise = StepNoise(moving=v, rest=REST * self.sig2)
