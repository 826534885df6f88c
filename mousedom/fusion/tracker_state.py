"""What the tracker's two solving paths share: the rig's fixed terms and the carried pose.

``Tracker`` composes two parts that turn closed windows' counts into poses: the array path
(``tracker_batch.ArrayPath``, replay's millions of windows at once) and the one-window path
(``tracker_one.OneWindowPath``, the daemon's one window per poll).  Both are built from the
same ``PathSetup`` and carry the pose in the same ``Carried`` object, so a window closed by
either continues from where the other left off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mousedom.fusion import robust

if TYPE_CHECKING:
    from mousedom.fusion.gyro import GyroFusion


@dataclass(frozen=True)
class PathSetup:
    """The terms of the solve that do not change while the tracker runs."""

    model: str  # models.MODELS
    integrator: str  # integrate.INTEGRATORS
    positions: np.ndarray  # (N, 2) mounts in the body frame, metres
    sigma: np.ndarray  # (N,) each mouse's reading error, metres
    period: float  # the window's length, seconds
    screen: robust.Screen | None  # the fault-tolerant screen (None: robust off)
    gyro: GyroFusion | None = None  # the gyro's part of each window (None: no gyro)

    @property
    def n_mice(self) -> int:
        return len(self.sigma)


@dataclass(slots=True)
class Carried:
    """The state carried from window to window, as Python floats (the one-window path's
    currency; the array path converts on entry and exit): the pose, its covariance and the
    position that covariance is taken at.

    One object, shared: the paths write it as they close windows; the tracker sets it from
    outside through ``reset``, ``fix`` and ``give_back`` (the learnt scales' motion owed).
    Its fields are replaced or updated in place, the object never: every holder sees the
    same state."""

    pose: list[float]  # x, y, theta
    cov: list[list[float]]  # 3x3
    at: list[float]  # x, y

    @classmethod
    def origin(cls) -> Carried:
        return cls([0.0, 0.0, 0.0], [[0.0] * 3 for _ in range(3)], [0.0, 0.0])

    def reset(self, x: float, y: float, theta: float) -> None:
        """The pose set from outside, with zero uncertainty."""
        self.pose = [float(x), float(y), float(theta)]
        self.cov = [[0.0] * 3 for _ in range(3)]
        self.at = self.pose[:2]

    def fix(self, x: float | None, y: float | None, theta: float | None) -> None:
        """Some coordinates set from outside (None: kept): those lose their uncertainty;
        the others, and their correlations with each other, are kept."""
        cov = np.array(self.cov)
        for k, v in enumerate((x, y, theta)):
            if v is not None:
                self.pose[k] = float(v)
                cov[k, :] = 0.0
                cov[:, k] = 0.0
        self.cov = cov.tolist()
        self.at = self.pose[:2]

    def take(self, other: Carried) -> None:
        """``other``'s state as it is (a reload's new tracker goes on from the old one's
        pose and covariance, ``Tracker.carry``): copies, so that the two never share a
        list."""
        self.pose = [float(v) for v in other.pose]
        self.cov = [[float(v) for v in row] for row in other.cov]
        self.at = [float(v) for v in other.at]

    def give_back(self, turn: float, walk: list[float]) -> None:
        """Turn and move the pose by what renewed scales would have given meanwhile
        (``ScaleLearner.take_turn``); the covariance is carried with the position."""
        self.pose[2] += turn
        for k in range(2):
            self.pose[k] += walk[k]
            self.at[k] += walk[k]


class WindowGrid:
    """The windows' edges t0 + k T, and how many windows are closed.  ``t0`` is the
    tracker's, or the first report's or completion's stamp (``start``)."""

    def __init__(self, period: float, t0: float | None) -> None:
        self.period = period
        self.t0 = t0
        self.closed = 0  # number of windows closed so far

    def start(self, t: float) -> None:
        if self.t0 is None:
            self.t0 = float(t)

    @property
    def frontier(self) -> float:
        """End of the last closed window (the start of the grid before any)."""
        return (self.t0 or 0.0) + self.closed * self.period

    def start_time(self) -> float:
        """t0, once known: the window grid's callers run after the first report or
        completion set it (poll, skip_quiet and finish return before)."""
        t0 = self.t0
        if t0 is None:
            raise RuntimeError("the window grid has no start before the first report")
        return t0

    def edge(self, k: int) -> float:
        """End of window k-1: computed exactly as the array path's edges are."""
        return self.start_time() + self.period * k

    def ending_by(self, t: float) -> int:
        """The largest k with edge(k) <= t: no rounding tolerance, so whether a window may
        close never depends on how its end was rounded (batch and stream agree).

        The division is off by at most a step or two; where floats cannot tell edge k from
        edge k + 1 any more (times near 1e300 once looped here for ever), that is an input
        no window grid can hold, and it is refused."""
        k = math.floor((t - self.start_time()) / self.period)
        for _ in range(8):
            if self.edge(k + 1) <= t:
                k += 1
            elif k > 0 and self.edge(k) > t:
                k -= 1
            else:
                return k
        raise ValueError(
            f"time {t!r} is beyond what a window grid of {self.period!r} s from {self.t0!r} "
            "can resolve"
        )
