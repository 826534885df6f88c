"""ROS 2 recordings: the poses as an MCAP file (schema encoding ros2msg, message encoding
cdr) that Foxglove and ``ros2 bag`` open.  ``replay --mcap`` and ``run --record-mcap``.

Topics: /odom (nav_msgs/msg/Odometry), /tf (tf2_msgs/msg/TFMessage: odom -> base_link,
and map -> odom after a reset or fix), /mousedom/<mouse>/counts
(geometry_msgs/msg/Vector3Stamped: the REL_X, REL_Y counts each mouse gave the window) and,
from the daemon, /diagnostics.  Log times are the windows' stamps: the capture's own time in
a replay, ROS time (the system clock) from the daemon unless ``stamps: monotonic``.
"""

from __future__ import annotations

from typing import Any

from mousedom.config import Ros2Config
from mousedom.errors import UserError
from mousedom.safewrite import open_stream
from mousedom.service import ros2conv as conv
from mousedom.service import ros2msgs as msgs

INSTALL_HINT = (
    "MCAP output needs mcap and mcap-ros2-support, which are not installed: "
    "pip install 'mousedom[ros2]'"
)


def system_offset(cfg: Ros2Config | None) -> float:
    """How far the system clock is ahead of the monotonic one (0 for monotonic stamps)."""
    import time

    if cfg is not None and cfg.stamps == "monotonic":
        return 0.0
    return time.time() - time.monotonic()


def require() -> None:
    try:
        import mcap_ros2.writer  # noqa: F401
    except ImportError:
        raise UserError(INSTALL_HINT) from None


class McapRecorder:
    def __init__(
        self,
        path: str,
        cfg: Ros2Config,
        sensors: tuple[str, ...],
        rate_hz: float,
        inputs: list[str] = (),  # type: ignore[assignment]
        offset: float = 0.0,
    ) -> None:
        require()
        from mcap_ros2.writer import Writer

        self.cfg, self.sensors, self.rate, self.offset = cfg, sensors, rate_hz, offset
        self.path = path
        try:
            self.file = open_stream(path, list(inputs))
        except OSError as e:
            raise UserError(f"{path}: cannot write: {e.strerror or e}") from None
        self.writer = Writer(self.file)
        self.schemas = {
            t: self.writer.register_msgdef(msgs.ros2_name(t), msgs.msgdef(t))
            for t in (msgs.ODOMETRY, msgs.TF, msgs.DIAGNOSTICS, msgs.COUNTS)
        }
        self.rep = conv.Rep105()
        self.topics = {
            "odom": conv.topic(cfg, cfg.odom_topic),
            "tf": conv.topic(cfg, cfg.tf_topic),
            "diag": conv.topic(cfg, cfg.diagnostics_topic),
        }
        self.count_topics = [conv.topic(cfg, f"/mousedom/{s}/counts") for s in sensors]
        self.written = 0

    def _write(self, topic: str, kind: str, message: dict[str, Any], ns: int) -> None:
        self.writer.write_message(topic, self.schemas[kind], message, log_time=ns,
                                  publish_time=ns)  # fmt: skip

    def publish(self, row: Any) -> None:
        cfg = self.cfg
        ns = conv.stamp_ns(row.t, self.offset)
        st = {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}
        odom = self.rep.odom_pose((row.x, row.y, row.theta))
        self._write(
            self.topics["odom"],
            msgs.ODOMETRY,
            conv.odometry(cfg, st, odom, -self.rep.map_odom[2], row, self.rate),
            ns,
        )
        tfs = [conv.transform(cfg.odom_frame, cfg.base_frame, st, odom)]
        if self.rep.map_odom != (0.0, 0.0, 0.0) or cfg.publish_map_tf:
            tfs.append(conv.transform(cfg.map_frame, cfg.odom_frame, st, self.rep.map_odom))
        self._write(self.topics["tf"], msgs.TF, {"transforms": tfs}, ns)
        for topic, name, (cx, cy) in zip(self.count_topics, self.sensors, row.counts,
                                          strict=False):  # fmt: skip
            self._write(topic, msgs.COUNTS, conv.counts(st, name, cx, cy), ns)
        self.written += 1

    def batch(self, b: Any) -> None:
        """A replay sink: every window of a PoseBatch."""
        for row in b.rows():
            self.publish(row)

    def moved(self, before: conv.Pose2, after: conv.Pose2) -> None:
        self.rep.moved(before, after)

    def sources(self, messages: list[dict[str, Any]], t: float) -> None:
        ns = conv.stamp_ns(t, self.offset)
        st = {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}
        self._write(self.topics["diag"], msgs.DIAGNOSTICS, conv.diagnostics(st, messages), ns)

    def close(self) -> None:
        if self.writer is None:
            return
        try:
            self.writer.finish()
            self.file.close()
        except OSError as e:
            raise UserError(f"{self.path}: cannot write: {e.strerror or e}") from None
        finally:
            self.writer = None
