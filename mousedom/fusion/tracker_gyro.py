"""The tracker's gyro: its samples' turn as a count function, closed with the mice's edges.

A gyro sample stamped t is the mean yaw rate since the sample before; times the span it
covers (at most one sample period, a mouse report's rule) it is the angle turned, which
rises over that span as a mouse's counts do.  So the gyro's turn is a ``CountFunction``
(its REL_X column) and a window's turn is its difference at the window's edges: split in
proportion to time, telescoping, nothing lost.

The REL_Y column is the time the samples cover and say something of, split at the edges by
the same rule, so a window's REL_Y is how much of it the gyro saw.  A window the gyro did
not see throughout has no gyro turn (None, NaN), and its heading is the mice's alone, on
any rig: one the samples left uncovered (a silence longer than a sample may bridge, the
late-report time: its turn is unknown, not none, where a mouse that does not report did
not move: a 0.19 s silence read as no turn took 2.4 degrees from a pivot), and one holding
a sample read at the limit of its converter (saturated: the robot turned at least that
fast, nothing exact), whose span counts as unseen.
"""

from __future__ import annotations

import math

import numpy as np

from mousedom.config import Config
from mousedom.fusion import models
from mousedom.fusion.countfunction import CountFunction
from mousedom.fusion.gyro import GyroFusion, gyro_noise, gyro_period, gyro_turns
from mousedom.fusion.gyrojudge import GyroJudge

# A window seen for all but this long was seen throughout: what the split at an edge leaves
# of a sample's span is at most rounding (a sample spans milliseconds)
UNSEEN_S = 1e-9


class GyroClock(CountFunction):
    """The gyro's turn over time (see the module docstring).  A window before its first
    sample's stamp has no turn (None): the first sample only starts the spans."""

    def __init__(self, period: float, late_report_s: float) -> None:
        super().__init__(period, late_report_s)
        # A sample's stamp is when it was measured (the driver's or the buffer's), not when
        # it reached us: samples close together were not held up on their way, so none
        # joins the span of the one before (a mouse's bunched reports do).  With the
        # config's rate unknown (a 50 Hz period) a 200 Hz gyro's every other sample
        # joined, its turn moved to the sample before: 2 degrees off in a half turn.
        self.join = 0.0
        self.first_t = math.inf  # the first sample's stamp: the turn is known from here

    def push(
        self,
        t: np.ndarray | list,
        rate: np.ndarray | list,
        saturated: np.ndarray | list | None = None,
    ) -> float | None:
        """Queue samples (stamps, rad/s, and where given which were saturated); the first
        stamp, or None if there were none.  ValueError for shapes that differ or values
        that are not finite numbers."""
        t = np.asarray(t, dtype=np.float64)
        rate = np.asarray(rate, dtype=np.float64)
        if not (t.ndim == 1 and t.shape == rate.shape):
            raise ValueError(f"push_gyro: t and rate must be 1-D of one length, got "
                             f"{t.shape}, {rate.shape}")  # fmt: skip
        sat = None if saturated is None else np.asarray(saturated, dtype=bool)
        if sat is not None and sat.shape != t.shape:
            raise ValueError(f"push_gyro: saturated must be as long as t, got {sat.shape}")
        if t.size == 0:
            return None
        if not math.isfinite(t.sum() + rate.sum()):
            raise ValueError("push_gyro: times and rates must be finite numbers")
        t, turn, spans = gyro_turns(t, rate, self.last_t, self.period, self.bridge)
        seen = spans if sat is None else np.where(sat, 0.0, spans)
        self.queue(t, turn, seen, float(t.max()))
        self.first_t = min(self.first_t, float(t[0]))
        return float(t[0])

    def turns(self, edges: np.ndarray) -> np.ndarray:
        """The turn in each window between ``edges``, NaN where the gyro was not live
        throughout (the array path's windows)."""
        n = len(edges) - 1
        closed = np.zeros((n, 2))
        self.close(edges, out=closed)
        live = np.ones(n, dtype=bool)
        self.close_live(edges, out=live)
        live &= edges[:-1] >= self.first_t
        live &= closed[:, 1] > np.diff(edges) - UNSEEN_S
        return np.where(live, closed[:, 0], np.nan)

    def turn_one(self, start: float, end: float) -> float | None:
        """The next window's turn (the one-window path's), None if the gyro was not live
        throughout, or did not see all of it (uncovered or saturated)."""
        turn, seen = self.close_one(end)
        if start < self.first_t or seen <= (end - start) - UNSEEN_S:
            return None
        return turn if not self.dead or self.live_in(start, end) else None


def gyro_parts(
    config: Config, model: str, positions: np.ndarray, sigma: np.ndarray
) -> tuple[GyroClock, GyroFusion]:
    """A rig's gyro in the tracker: its count function, and its part of each window's
    solve, judging disagreements with the mice where fault handling is on."""
    gyro = config.gyro
    if gyro is None:
        raise ValueError("the config has no gyro")
    judge = None
    period = 1.0 / config.rate_hz
    if config.robust.enabled:  # faults seen through the gyro (gyrojudge.py)
        cols = (0, 2) if model == "diff-drive" else (0, 1, 2)
        judge = GyroJudge(positions, sigma, cols, config.robust.false_alarm,
                          (models.STILL * sigma).tolist(), config.robust.relative_noise,
                          period)  # fmt: skip
    fusion = GyroFusion(gyro_noise(gyro), period, gyro.use, judge)
    return GyroClock(gyro_period(gyro), config.late_report_s), fusion
