"""What the tracker's two solving paths share: the rig's fixed terms and the carried pose.

``Tracker`` composes two parts that turn closed windows' counts into poses: the array path
(``tracker_batch.ArrayPath``, replay's millions of windows at once) and the one-window path
(``tracker_one.OneWindowPath``, the daemon's one window per poll).  Both are built from the
same ``PathSetup`` and carry the pose in the same ``Carried`` object, so a window closed by
either continues from where the other left off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mousedom.fusion import robust


@dataclass(frozen=True)
class PathSetup:
    """The terms of the solve that do not change while the tracker runs."""

    model: str  # models.MODELS
    integrator: str  # integrate.INTEGRATORS
    positions: np.ndarray  # (N, 2) mounts in the body frame, metres
    sigma: np.ndarray  # (N,) each mouse's reading error, metres
    period: float  # the window's length, seconds
    screen: robust.Screen | None  # the fault-tolerant screen (None: robust off)

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

    def give_back(self, turn: float, walk: list[float]) -> None:
        """Turn and move the pose by what renewed scales would have given meanwhile
        (``ScaleLearner.take_turn``); the covariance is carried with the position."""
        self.pose[2] += turn
        for k in range(2):
            self.pose[k] += walk[k]
            self.at[k] += walk[k]
