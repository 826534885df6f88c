"""Online scale calibration from the redundancy of three or more mice (issue 31, item 3).

A CPI a few per cent off hides inside each window's noise but is plain over many: with
three or more mice, each mouse's reading can be predicted from the others alone (leave it
out, solve, predict it), and in every window where the rig moves, the ratio of the
prediction to its reading along each of its count axes is its scale error there.  Per
mouse i and axis a (REL_X, REL_Y), with x the raw counts and y the counts the others
predict (both at the configured CPI), each summed over a tenth of a second (X, Y: a count
read a few ms late moves between windows, not out of their sum, so the timing noise that
would bias a fit towards 0 cancels), the scale g = sum(X Y) / sum(X^2) is the least
squares fit of Y = g X over the sums where |Y| is well above the counts' noise, and
sigma_g^2 = s^2 / sum(X^2) its variance, s^2 the fit's residual variance: the estimate
moves as fast as the evidence allows (a metre of motion
at 1000 CPI is tens of thousands of counts: a few per cent is plain within it) and no
faster.  The sums forget with a half-life of ``HALF_LIFE_S`` of moving windows, so that a
mouse whose scale changes (a new floor) is followed.

Where the config says so (``robust.learn_scale``, off by default: see below) the learnt
scale is applied, clipped to 1 +- ``limit``, by multiplying the mouse's counts (its
counts-to-body matrix) from the next block of windows on.  Either way the estimate is
reported (PoseBatch.scale, the replay summary and CSV) and a mouse 10 % or more off is
warned of (``warnings``).

Not yet good enough to apply by default (issue 31, measured on the triangle rig with one
mouse 3 % off): the forward axes come out right to 0.1 %, but the sideways axes, which
read the turn, come out biased by about 0.5 % (each mouse is predicted from the others,
which are themselves being corrected), and at a hundred radians of turning in a minute
that is degrees of heading: worse than not correcting at all.  A joint fit of all the
scales with the motion is the way on.  The other mice's predictions are made with their
current scales, and the common mode of each axis is pinned by its median mouse.

What is observable is each mouse's scale relative to the others:
all mice wrong together (a common-mode error) changes no prediction and is not seen
(docs/calibration.md).

Evidence comes in blocks of windows (``block``, a second's worth): the rows of a block are
kept and the block is evaluated at once with numpy, the same operations for the daemon's
one window at a time and replay's arrays (the same scales, to the rounding in which the
screen's float path and its arrays differ).  Only
windows the fault screen found consistent, with the mouse tracking (used, not suspect),
at least two others used and the mouse moving well beyond its noise floor, count.
"""

from __future__ import annotations

import math

import numpy as np

from mousedom.fusion import models

GROUP_S = 0.1  # windows are summed over this long before they are compared
HALF_LIFE_S = 120.0  # seconds of evidence after which old sums count half
WARN = 0.10  # a scale this far from 1 (beyond its uncertainty) is a clear CPI mistake
_MIN_COUNTS = 8.0  # a prediction under this many counts (per window and axis) says little


class ScaleLearner:
    """Each mouse's scale per count axis, learnt from the others (module docstring)."""

    def __init__(
        self,
        model: str,
        to_body: np.ndarray,
        positions: np.ndarray,
        sigma: np.ndarray,
        window: float,
        limit: float,
    ) -> None:
        self.model = model
        self.n = len(positions)
        self.base = np.asarray(to_body, dtype=float)  # (N, 2, 2) counts -> body, as configured
        self.inverse = np.linalg.inv(self.base) if self.n else self.base
        self.positions = np.asarray(positions, dtype=float)
        self.sigma = np.asarray(sigma, dtype=float)
        self.limit = float(limit)
        self.block = max(20, math.ceil(1.0 / window - 1e-9))
        self.forget = 0.5 ** (self.block * window / HALF_LIFE_S)
        self.group = max(1, round(GROUP_S / window))  # windows summed into one reading
        # per mouse and axis, forgetting: sum X^2, sum X Y, sum Y^2, groups of evidence
        self.sums = np.zeros((4, self.n, 2))
        self.estimate = np.ones((self.n, 2))  # the fit, unclipped
        self.spread = np.full((self.n, 2), np.inf)  # its standard deviation
        self.scale = np.ones((self.n, 2))  # applied: the fit clipped to 1 +- limit
        self._rows: list[tuple[np.ndarray, np.ndarray]] = []  # this block's (counts, usable)
        self._held = 0  # windows in _rows
        self.version = 0  # bumped whenever the estimates are renewed

    @property
    def active(self) -> bool:
        """Whether anything can be learnt: three or more mice (two others to predict)."""
        return self.n >= 3

    def matrices(self) -> np.ndarray:
        """(N, 2, 2) counts -> body with the learnt scales applied (column a times g_a)."""
        return self.base * self.scale[:, None, :]

    def until_block_end(self) -> int:
        """Windows still to add before the current block ends (at least 1)."""
        return self.block - self._held

    def add(self, counts: np.ndarray, usable: np.ndarray) -> bool:
        """Add windows (``counts`` (n, N, 2) raw REL_X/REL_Y, ``usable`` (n, N) bool) of the
        current block, at most ``until_block_end()`` of them; at the block's end, learn.
        Returns whether a block ended (and the estimates were renewed)."""
        if not self.active or not len(counts):
            return False
        self._rows.append((np.asarray(counts, dtype=float), np.asarray(usable, dtype=bool)))
        self._held += len(counts)
        if self._held < self.block:
            return False
        counts = np.concatenate([c for c, _ in self._rows])
        usable = np.concatenate([u for _, u in self._rows])
        self._rows, self._held = [], 0
        return self._learn(counts, usable)

    def _learn(self, counts: np.ndarray, usable: np.ndarray) -> bool:
        # each mouse's body displacement with the scales of this block applied
        d = np.einsum("nij,knj->kni", self.matrices(), counts)
        x = counts
        y = np.zeros_like(counts)
        ok = np.zeros(usable.shape, dtype=bool)
        for i in range(self.n):
            others = usable.copy()
            others[:, i] = False
            rows = usable[:, i] & (others.sum(axis=1) >= 2)
            if not rows.any():
                continue
            sol = models.solve(self.model, d[rows], self.positions, self.sigma, others[rows])
            q = np.where(sol.ok[:, None], sol.q, np.nan)
            px = q[:, 0] - q[:, 2] * self.positions[i, 1]
            py = q[:, 1] + q[:, 2] * self.positions[i, 0]
            pred = np.stack([px, py], axis=1) @ self.inverse[i].T  # counts as configured
            y[rows, i] = pred
            ok[rows, i] = sol.ok
        # Sums over groups of consecutive windows (GROUP_S): a count read a few ms late
        # moves between neighbouring windows, not out of their sum, so the readings'
        # timing noise (which would bias a fit towards 0) mostly cancels.
        n_rows = len(x)
        group = np.arange(n_rows) // self.group
        n_groups = int(group[-1]) + 1
        gx = np.zeros((n_groups, self.n, 2))
        gy = np.zeros((n_groups, self.n, 2))
        take = ok[:, :, None] & np.isfinite(y)
        np.add.at(gx, group, np.where(take, x, 0.0))
        np.add.at(gy, group, np.where(take, y, 0.0))
        big = np.abs(gy) >= _MIN_COUNTS * self.group
        gx, gy = np.where(big, gx, 0.0), np.where(big, gy, 0.0)
        sums = self.sums
        sums *= self.forget
        sums[0] += np.sum(gx * gx, axis=0)
        sums[1] += np.sum(gx * gy, axis=0)
        sums[2] += np.sum(gy * gy, axis=0)
        sums[3] += np.sum(big, axis=0)
        xx, xy, yy, count = sums
        known = (count >= 10) & (xx > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(known, xy / xx, 1.0)
            # the fit's residual variance per group, and the estimate's variance from it
            ss = np.maximum(yy - g * xy, 0.0)
            spread = np.where(known, np.sqrt(ss / np.maximum(count - 1.0, 1.0) / xx), np.inf)
        # Only scales relative to the others are observable: the common mode of each axis
        # is pinned by its median mouse (with one mouse wrong, a right one).
        g = g / np.median(g, axis=0, keepdims=True)
        self.estimate, self.spread = g, spread
        new = np.clip(g, 1.0 - self.limit, 1.0 + self.limit)
        self.scale = np.where(known, new, 1.0)
        self.version += 1
        return True

    def warnings(self, names: tuple[str, ...] | list[str]) -> list[str]:
        """A line per mouse whose scale is WARN or more from 1, beyond three of its
        standard deviations: a CPI typo, or the wrong mouse's CPI."""
        out = []
        for i, name in enumerate(names):
            # on the axis with the most evidence (for a mouse facing forward, REL_Y: the
            # sideways one reads the turn, and is not yet found well when another mouse is
            # far off, see the module docstring)
            a = int(np.argmax(self.sums[0, i]))
            axis = "xy"[a]
            g, s = float(self.estimate[i, a]), float(self.spread[i, a])
            if abs(g - 1.0) >= WARN and abs(g - 1.0) > 3.0 * s:
                word = "less" if g > 1.0 else "more"  # it needs g times its counts
                out.append(
                    f"mouse {name} reads {abs(1.0 / g - 1.0) * 100:.0f} % {word} than "
                    f"the others on its {axis} axis: check its cpi (learnt scale "
                    f"{g:.3f} +- {s:.3f})"
                )
        return out
