"""Where the daemon's windows and reports go: the ``Output`` interface.

Every destination implements it: the Unix socket's clients (publish.SocketOutput), ROS 2
over DDS (ros2out), an MCAP file (mcapout), the Foxglove view (foxgloveout), the live
recording of the sensors' reports (live_record) and the Prometheus figures (metrics).
The publisher (publish.py) calls them in one order, window by window; an optional output
that raises is logged and dropped, and the rest go on (the socket, which robots rely on,
is not optional).  Only ``publish`` must be written: the other hooks default to nothing.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from mousedom.fusion.posebatch import PoseRow

Pose2 = tuple[float, float, float]  # (x, y, theta): metres, metres, radians


class Output(ABC):
    """A destination of the daemon's windows (see the module docstring)."""

    @abstractmethod
    def publish(self, row: PoseRow) -> None:
        """One closed window, in time order."""

    def reports(self, index: int, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:  # noqa: B027
        """Reports of mouse ``index`` as read from its sensor (stamps, counts)."""

    def gyro(  # noqa: B027
        self, t: np.ndarray, rate: np.ndarray, saturated: np.ndarray | None = None
    ) -> None:
        """The rig's gyro's samples as read: stamps, yaw rates (rad/s, CCW positive), and
        which were read at the converter's limit (None: none)."""

    def checkpoint(self, complete: float) -> None:  # noqa: B027
        """Once a second: every report stamped up to ``complete`` has been handed over."""

    def sources(self, messages: list[dict[str, Any]], t: float) -> None:  # noqa: B027
        """Once a second: the SOURCE messages (each sensor's health) at time ``t``."""

    def moved(self, before: Pose2, after: Pose2) -> None:  # noqa: B027
        """The pose was set from outside (reset, fix): it jumped from ``before``."""

    def fixes(self) -> list[Pose2]:
        """Poses this output was told from outside (ROS 2's /initialpose), to apply."""
        return []

    def close(self) -> None:  # noqa: B027
        """Stop; called once more after a failure is harmless."""

    def __str__(self) -> str:
        return f"output {type(self).__name__}"

    @property
    def wants_reports(self) -> bool:
        """Whether ``reports`` or ``gyro`` does anything (they are called per read:
        skipped if not)."""
        return type(self).reports is not Output.reports or type(self).gyro is not Output.gyro
