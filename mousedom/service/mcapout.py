"""ROS 2 recordings: the poses as an MCAP file (schema encoding ros2msg, message encoding
cdr) that Foxglove and ``ros2 bag`` open.  ``replay --mcap`` and ``run --record-mcap``.

Topics: /odom (nav_msgs/msg/Odometry), /tf (tf2_msgs/msg/TFMessage: odom -> base_link,
and map -> odom after a reset or fix), /mousedom/<mouse>/counts
(geometry_msgs/msg/Vector3Stamped: the REL_X, REL_Y counts each mouse gave the window) and,
from the daemon, /diagnostics.  Log times are the windows' stamps: the capture's own time in
a replay, ROS time (the system clock) from the daemon unless ``stamps: monotonic``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from mousedom.config import Ros2Config
from mousedom.errors import UserError
from mousedom.fusion.posebatch import PoseBatch, PoseRow
from mousedom.safewrite import open_stream
from mousedom.service import ros2cdr as cdr
from mousedom.service import ros2conv as conv
from mousedom.service import ros2msgs as msgs
from mousedom.service.output import Output, PerMouse
from mousedom.service.rostime import system_lead

INSTALL_HINT = "MCAP output needs mcap, which is not installed: pip install 'mousedom[ros2]'"


def system_offset(cfg: Ros2Config | None) -> float:
    """How far the system clock is ahead of the monotonic one (0 for monotonic stamps)."""
    if cfg is not None and cfg.stamps == "monotonic":
        return 0.0
    return system_lead()


def require() -> None:
    try:
        import mcap.writer  # noqa: F401
    except ImportError:
        raise UserError(INSTALL_HINT) from None


# Bytes of one window's messages before compression: /odom (two 6 x 6 covariances: about
# 730), /tf (one or two transforms: about 200), each mouse's counts (about 100), and the
# records' own framing.
ODOM_TF_BYTES, COUNTS_BYTES = 1000, 120


def live_chunk_bytes(mice: int, rate_hz: float) -> int:
    """A chunk of about one second of windows (at least 4 KiB)."""
    return max(4096, int(rate_hz * (ODOM_TF_BYTES + COUNTS_BYTES * mice)))


class McapRecorder(PerMouse, Output):
    def __init__(
        self,
        path: str,
        cfg: Ros2Config,
        sensors: tuple[str, ...],
        rate_hz: float,
        inputs: Sequence[str | None] = (),  # files the recording was made from (None: none)
        offset: float = 0.0,
        live: bool = False,
    ) -> None:
        """``live``: a daemon's recording, which a crash may end (see ``checkpoint``)."""
        require()
        from mcap.writer import CompressionType, Writer

        from mousedom import __version__

        self.cfg, self.sensors, self.rate, self.offset = cfg, sensors, rate_hz, offset
        self.path = path
        self.file = open_stream(path, list(inputs))
        # A chunk is written when it is full; one killed before that is lost, so a live
        # recording's chunks hold about a second (a replay's the library's 1 MiB: 12 s of
        # a 3-mouse rig at 50 Hz, the last 12 s before a crash, or the whole file).
        chunk = live_chunk_bytes(len(sensors), rate_hz) if live else 1 << 20
        self.writer = Writer(self.file, chunk_size=chunk, compression=CompressionType.ZSTD)
        self.live = live
        self.closed = False
        self.writer.start(profile="ros2", library=f"mousedom {__version__}")
        schemas = {
            t: self.writer.register_schema(msgs.ros2_name(t), "ros2msg", msgs.msgdef(t).encode())
            for t in (msgs.ODOMETRY, msgs.TF, msgs.DIAGNOSTICS, msgs.COUNTS)
        }

        def channel(topic: str, kind: str) -> int:
            return self.writer.register_channel(conv.topic(cfg, topic), "cdr", schemas[kind])

        self.odom_ch = channel(cfg.odom_topic, msgs.ODOMETRY)
        self.tf_ch = channel(cfg.tf_topic, msgs.TF)
        self.diag_ch = channel(cfg.diagnostics_topic, msgs.DIAGNOSTICS)
        self.count_ch = [channel(conv.counts_topic(s), msgs.COUNTS) for s in sensors]
        self.odom_cdr = cdr.OdometryCdr(cfg.odom_frame, cfg.base_frame)
        self.tf_cdr = {
            False: cdr.TfCdr([(cfg.odom_frame, cfg.base_frame)]),
            True: cdr.TfCdr([(cfg.odom_frame, cfg.base_frame), (cfg.map_frame, cfg.odom_frame)]),
        }
        self.counts_cdr = [
            cdr.Vector3StampedCdr(conv.mouse_frame(s, cfg.base_frame)) for s in sensors
        ]
        self.rep = conv.Rep105()
        self.written = 0

    def _write(self, channel: int, data: bytes, ns: int) -> None:
        self.writer.add_message(channel, log_time=ns, data=data, publish_time=ns)

    def publish(self, row: PoseRow) -> None:
        cfg = self.cfg
        ns = conv.stamp_ns(row.t, self.offset)
        st = {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}
        odom = self.rep.odom_pose((row.x, row.y, row.theta))
        msg = conv.odometry(cfg, st, odom, self.rep.odom_cov(row.cov, odom), row, self.rate)
        self._write(self.odom_ch, self.odom_cdr.encode(st, msg), ns)
        tfs = [conv.transform(cfg.odom_frame, cfg.base_frame, st, odom)]
        both = self.rep.map_odom != (0.0, 0.0, 0.0) or cfg.publish_map_tf
        if both:
            tfs.append(conv.transform(cfg.map_frame, cfg.odom_frame, st, self.rep.map_odom))
        self._write(self.tf_ch, self.tf_cdr[both].encode(st, tfs), ns)
        if self.per_mouse:  # (unless the mice changed: output.PerMouse)
            for ch, enc, name, (cx, cy) in zip(self.count_ch, self.counts_cdr, self.sensors,
                                               row.counts, strict=False):  # fmt: skip
                self._write(ch, enc.encode(st, conv.counts(st, name, cx, cy, cfg.base_frame)),
                            ns)  # fmt: skip
        self.written += 1

    def batch(self, b: PoseBatch) -> None:
        """A replay sink: every window of a PoseBatch."""
        for row in b.rows():
            self.publish(row)

    def moved(self, before: conv.Pose2, after: conv.Pose2) -> None:
        self.rep.moved(before, after)

    def sources(self, messages: list[dict[str, Any]], t: float) -> None:
        ns = conv.stamp_ns(t, self.offset)
        st = {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}
        self._write(self.diag_ch, cdr.diagnostics(st, conv.diagnostics(st, messages)), ns)

    def checkpoint(self, complete: float) -> None:
        """Once a second from the daemon: the chunks written so far reach the file (a
        killed daemon's MCAP then holds all but its last second or two: a streaming
        reader such as Foxglove's, or `mcap recover`, reads it)."""
        if self.live and not self.closed:
            try:
                self.file.flush()
            except OSError as e:
                raise UserError(f"{self.path}: cannot write: {e.strerror or e}") from None

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.writer.finish()
            self.file.close()
        except OSError as e:
            raise UserError(f"{self.path}: cannot write: {e.strerror or e}") from None
