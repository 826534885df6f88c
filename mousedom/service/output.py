"""Where the daemon's windows and reports go: the ``Output`` interface.

Every destination implements it: the Unix socket's clients (publish.SocketOutput), ROS 2
over DDS (ros2out), an MCAP file (mcapout), the Foxglove view (foxgloveout), the live
recording of the sensors' reports (live_record) and the Prometheus figures (metrics).
The publisher (publish.py) calls them in one order, window by window; an optional output
that raises is logged and dropped, and the rest go on (the socket, which robots rely on,
is not optional).  Only ``publish`` must be written: the other hooks default to nothing.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from mousedom.fusion.posebatch import PoseRow

Pose2 = tuple[float, float, float]  # (x, y, theta): metres, metres, radians

log = logging.getLogger(__name__)


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

    def mice_changed(self, names: tuple[str, ...]) -> None:  # noqa: B027
        """A reload changed the mice: ``names`` in the new config's order (the rows'
        per-mouse columns follow it from the next window on)."""

    def close(self) -> None:  # noqa: B027
        """Stop; called once more after a failure is harmless."""

    def __str__(self) -> str:
        return f"output {type(self).__name__}"

    @property
    def wants_reports(self) -> bool:
        """Whether ``reports`` or ``gyro`` does anything (they are called per read:
        skipped if not)."""
        return type(self).reports is not Output.reports or type(self).gyro is not Output.gyro


class PerMouse:
    """For an output whose per-mouse channels (counts topics, a mouse list, mount frames)
    are made for the mice it started with (``sensors``): after a reload that changes the
    mice (adds, removes or reorders them) a row's per-mouse columns no longer line up with
    those channels, and filling them would give one mouse's counts under another's name.
    They are left unfilled (``per_mouse`` False, said once in the log) until the mice are
    those again; the pose goes on.  The outputs are made at start (a SIGHUP does not
    change them: docs/daemon.md), so a restart takes the new mice."""

    sensors: tuple[str, ...]
    per_mouse = True

    def mice_changed(self, names: tuple[str, ...]) -> None:
        same = tuple(names) == tuple(self.sensors)
        if self.per_mouse and not same:
            log.warning("%s: the mice changed (now %s): its per-mouse channels stay those of "
                        "%s and are not filled until a restart", self, ", ".join(names),
                        ", ".join(self.sensors))  # fmt: skip
        self.per_mouse = same
