"""A live view without ROS: the daemon's pose in Foxglove, over Foxglove's WebSocket protocol.

``foxglove-sdk`` (the ``foxglove`` extra) serves the protocol; Foxglove (the desktop app or
app.foxglove.dev) connects with "Open connection" -> "Foxglove WebSocket" ->
``ws://localhost:8765`` (docs/ros2.md, "Foxglove without ROS").  Opt in with ``outputs:
{foxglove: {}}``; it listens on 127.0.0.1 unless the config says otherwise.

Channels, in Foxglove's own schemas (its 3D panel draws them as they are):

- ``/mousedom/pose``: ``foxglove.PoseInFrame`` in the odom frame, every window;
- ``/tf``: ``foxglove.FrameTransforms``: odom -> base_link every window, base_link ->
  <mouse>_mouse (each mouse's mount) once a second;
- ``/mousedom/path``: ``foxglove.PosesInFrame``, the path so far (a pose every 0.1 s of
  motion, the last ``PATH_POSES``), twice a second;
- ``/mousedom/mice``: JSON, every window: each mouse's counts in the window (REL_X and
  REL_Y as the mouse reported them, split at the window's edges) and its state (tracking,
  suspect, excluded, missing);
- ``/mousedom/sources``: JSON, the SOURCE messages of the socket, once a second.

Times are the daemon's (monotonic) stamps, as the socket's POSE carries them.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from typing import Any

from mousedom.config import FoxgloveConfig, MouseConfig
from mousedom.errors import UserError
from mousedom.fusion import robust
from mousedom.fusion.posebatch import PoseRow
from mousedom.service import ros2conv
from mousedom.service.output import Output, PerMouse

log = logging.getLogger(__name__)

INSTALL_HINT = (
    "the Foxglove live view needs foxglove-sdk, which is not installed: "
    "pip install 'mousedom[foxglove]' (or: pip install foxglove-sdk)"
)
PATH_POSES = 3000
PATH_STEP_S = 0.1
# a pose this close to the path's last is no motion (a tenth of a millimetre, a
# twentieth of a degree: below what the view can draw)
PATH_STILL_M = 1e-4
PATH_STILL_RAD = 1e-3

MICE_SCHEMA = {
    "type": "object",
    "properties": {
        "t": {"type": "number"},
        "mice": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "name": {"type": "string"},
                    "dx": {"type": "number"},
                    "dy": {"type": "number"},
                    "state": {"type": "string"},
                },
            },
        },
    },
}
SOURCES_SCHEMA = {"type": "object", "properties": {"t": {"type": "number"}, "sources": {}}}


def require() -> None:
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise UserError(INSTALL_HINT) from None


def _time(t: float) -> Any:
    from foxglove.messages import Timestamp

    ns = max(0, round(t * 1e9))
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _quat(yaw: float) -> Any:
    from foxglove.messages import Quaternion

    return Quaternion(x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw))


def mount_frames(mice: tuple[MouseConfig, ...] | list[MouseConfig], stamp: Any) -> list[Any]:
    """base_link -> each mouse's frame, as ROS 2's /tf_static has them (``ros2conv``): the
    frame named by the mouse's ROS token, a mirrored sensor turned upside down."""
    from foxglove.messages import FrameTransform, Quaternion, Vector3

    out = []
    for m in mice:
        rot = ros2conv.mount_rotation(m.mount.yaw, m.flip)
        out.append(FrameTransform(
            timestamp=stamp, parent_frame_id="base_link",
            child_frame_id=ros2conv.mouse_frame(m.name),
            translation=Vector3(x=m.mount.x, y=m.mount.y, z=0.0),
            rotation=Quaternion(**rot)))  # fmt: skip
    return out


class FoxgloveOutput(PerMouse, Output):
    """A Foxglove WebSocket server and its channels; ``publish`` per window."""

    def __init__(
        self, cfg: FoxgloveConfig, sensors: tuple[str, ...], mice: tuple[MouseConfig, ...] = ()
    ) -> None:
        require()
        import foxglove
        from foxglove.channels import (
            FrameTransformsChannel,
            PoseInFrameChannel,
            PosesInFrameChannel,
        )

        self.cfg, self.sensors, self.mice = cfg, sensors, mice
        # The SDK's own log lines (its server's, through Python logging) stay out of the
        # daemon's log unless it runs with --verbose: a connection is two INFO lines, and a
        # viewer that stalled and then went logged one ERROR per message queued for it (up
        # to 639 lines for one disconnect).
        sdk = logging.getLogger("foxglove")
        if not sdk.isEnabledFor(logging.DEBUG):
            sdk.setLevel(logging.CRITICAL)
        self.ctx = foxglove.Context()
        self.closed = False
        try:
            self.server = foxglove.start_server(
                name="mousedom", host=cfg.host, port=cfg.port, context=self.ctx
            )
        except Exception as e:  # noqa: BLE001 - the SDK's errors carry the OS's reason
            raise UserError(
                f"Foxglove live view: cannot listen on {cfg.host}:{cfg.port}: {e} "
                "(outputs.foxglove.host, port)"
            ) from None
        ctx = self.ctx
        self.pose_ch = PoseInFrameChannel("/mousedom/pose", context=ctx)
        self.tf_ch = FrameTransformsChannel("/tf", context=ctx)
        self.path_ch = PosesInFrameChannel("/mousedom/path", context=ctx)
        self.mice_ch = foxglove.Channel("/mousedom/mice", schema=MICE_SCHEMA,
                                        message_encoding="json", context=ctx)  # fmt: skip
        self.sources_ch = foxglove.Channel("/mousedom/sources", schema=SOURCES_SCHEMA,
                                           message_encoding="json", context=ctx)  # fmt: skip
        self.path: deque[tuple[float, float, float]] = deque(maxlen=PATH_POSES)
        self._path_t = -math.inf
        self._path_sent = -math.inf
        self._mounts_sent = -math.inf
        self.port = self.server.port
        host = f"[{cfg.host}]" if ":" in cfg.host else cfg.host  # (an IPv6 address)
        log.info("Foxglove live view on ws://%s:%d", host, self.port)

    def _pose(self, x: float, y: float, yaw: float) -> Any:
        from foxglove.messages import Pose, Vector3

        return Pose(position=Vector3(x=x, y=y, z=0.0), orientation=_quat(yaw))

    def publish(self, row: PoseRow) -> None:
        """One window: the pose, odom -> base_link, each mouse's counts and state; the
        mounts and the path at their own slower rates."""
        from foxglove.messages import FrameTransform, FrameTransforms, PoseInFrame, Vector3

        t = float(row.t)
        stamp = _time(t)
        x, y, yaw = float(row.x), float(row.y), float(row.theta)
        self.pose_ch.log(PoseInFrame(timestamp=stamp, frame_id="odom",
                                     pose=self._pose(x, y, yaw)))  # fmt: skip
        transforms = [FrameTransform(timestamp=stamp, parent_frame_id="odom",
                                     child_frame_id="base_link",
                                     translation=Vector3(x=x, y=y, z=0.0),
                                     rotation=_quat(yaw))]  # fmt: skip
        if self.per_mouse and t - self._mounts_sent >= 1.0:  # (output.PerMouse)
            self._mounts_sent = t
            transforms += mount_frames(self.mice, stamp)
        self.tf_ch.log(FrameTransforms(transforms=transforms))
        if self.per_mouse:
            self._mice(t, row)
        # a pose every PATH_STEP_S of motion: none while the robot stands (3,000 copies of
        # one pose had pushed the drive before them out), and the step allowed its last
        # bit (50 Hz windows gave steps of 0.1 or 0.12 s by float rounding)
        if t - self._path_t >= PATH_STEP_S - 1e-9 and self._moved(x, y, yaw):
            self._path_t = t
            self.path.append((x, y, yaw))
        if t - self._path_sent >= 0.5:
            self._path_sent = t
            self._send_path(stamp)

    def _moved(self, x: float, y: float, yaw: float) -> bool:
        """Whether the pose moved from the path's last by more than PATH_STILL."""
        if not self.path:
            return True
        px, py, pyaw = self.path[-1]
        return math.hypot(x - px, y - py) > PATH_STILL_M or abs(yaw - pyaw) > PATH_STILL_RAD

    def _mice(self, t: float, row: PoseRow) -> None:
        states = list(row.state) if row.state is not None else []
        counts = list(row.counts) if row.counts is not None else []
        mice = []
        for k, name in enumerate(self.sensors):
            cx, cy = counts[k] if k < len(counts) else (0.0, 0.0)
            state = robust.STATES[int(states[k])] if k < len(states) else None
            mice.append({"name": name, "dx": float(cx), "dy": float(cy), "state": state})
        self.mice_ch.log({"t": t, "mice": mice})

    def _send_path(self, stamp: Any) -> None:
        from foxglove.messages import PosesInFrame

        poses = [self._pose(px, py, pyaw) for px, py, pyaw in self.path]
        self.path_ch.log(PosesInFrame(timestamp=stamp, frame_id="odom", poses=poses))

    def moved(self, before: Any, after: Any) -> None:
        """The socket's reset or fix: the path starts again from the new pose."""
        self.path.clear()
        self._path_t = -math.inf

    def sources(self, messages: list[dict[str, Any]], t: float) -> None:
        self.sources_ch.log({"t": t, "sources": messages})

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.server.stop()
