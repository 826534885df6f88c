"""``mousedom run --record FILE``: what the daemon fused, kept as a native capture.

Every report that reaches the tracker is appended (decoded motion, host monotonic time,
evdev convention), and the gyro's samples if the rig has one (stamps and yaw rates in
rad/s, as fused), with the config in the header, so that ``mousedom replay FILE`` shows
afterwards what the robot saw.  The native format survives a crash up to the last SYNC,
written once a second; SIGTERM/SIGINT flush and close it.  (``mousedom record`` is the
bench tool that keeps a serial sensor's raw bytes too.)
"""

from __future__ import annotations

import logging

import numpy as np

from mousedom import saferead
from mousedom.capture.base import GYRO_KIND, DeviceInfo
from mousedom.capture.native import NativeWriter
from mousedom.config import Config, GyroConfig, MouseConfig
from mousedom.errors import UserError
from mousedom.fusion.choices import GYRO
from mousedom.fusion.posebatch import PoseRow
from mousedom.service.output import Output

log = logging.getLogger(__name__)


def _device(mouse: MouseConfig, source_kind: str) -> DeviceInfo:
    extra: dict[str, object] = {"source": source_kind}
    if mouse.evdev is not None and mouse.evdev.path:
        extra["node"] = mouse.evdev.path
    if mouse.serial is not None:
        extra["port"] = mouse.serial.port
    # Decoded reports of every kind of sensor are motion, as an evdev mouse's are.
    return DeviceInfo(name=mouse.name, kind="evdev", mouse=mouse.name, rel_xy=True, extra=extra)


def _gyro_device(gyro: GyroConfig, source_kind: str) -> DeviceInfo:
    """The gyro as the config names it (the daemon may open it only later: its scale is
    not known here; ``mousedom record`` keeps it)."""
    extra: dict[str, object] = {"source": source_kind, "axis": gyro.axis, "sign": gyro.sign}
    if gyro.path:
        extra["node"] = gyro.path
    if gyro.sample_hz is not None:
        extra["sample_hz"] = gyro.sample_hz
    topic = gyro.ros2.topic if gyro.ros2 is not None else None
    if gyro.ros2 is not None:  # as `mousedom record` names one (its domain as configured)
        extra.update(topic=gyro.ros2.topic, domain_id=gyro.ros2.domain(),
                     stamps=gyro.ros2.stamps)  # fmt: skip
    return DeviceInfo(name=gyro.name or gyro.path or topic or GYRO, kind=GYRO_KIND,
                      rel_xy=False, extra=extra)  # fmt: skip


class Recording(Output):
    """An open native capture of the daemon's input: an output that keeps the reports.

    A recording that cannot be written (full disk, file size limit) fails as any output
    does: it is logged and stopped, the file keeps what reached it (all but the torn last
    chunk), and the fusion, which robots rely on, goes on."""

    def __init__(
        self, path: str, config: Config, source_kinds: list[str], grid_start: float | None = None
    ) -> None:
        """``source_kinds``: each sensor's source kind, the mice's and then, for a rig
        with a gyro, the gyro's (the daemon's slots in the tracker's order); ``grid_start``:
        where the daemon's windows began, written in the header so that replay's windows
        are the daemon's (replay anchored them at the first report instead: no POSE time
        of the daemon was a row of the replay of its own recording)."""
        text = None
        if config.path:
            try:
                text = saferead.read_text(config.path)
            except (OSError, UnicodeDecodeError):
                text = None
        n = len(config.mice)
        devices = [_device(m, k) for m, k in zip(config.mice, source_kinds[:n], strict=True)]
        # The gyro's samples go to the device after the mice's (None: no gyro)
        self.gyro_device: int | None = None
        if config.gyro is not None:
            kind = source_kinds[n] if len(source_kinds) > n else GYRO_KIND
            devices.append(_gyro_device(config.gyro, kind))
            self.gyro_device = n
        from mousedom.capture.assignment import config_inputs

        try:
            self.writer = NativeWriter(
                path,
                devices,
                config_text=text,
                time_base="monotonic",
                meta={
                    "recorder": "mousedom run --record",
                    "config_path": config.path,
                    "grid_start": grid_start,
                },
                inputs=config_inputs(config),
            )
        except OSError as e:
            raise UserError(f"{path}: cannot write the recording: {e.strerror}") from None
        self.path = path
        self.names = config.names
        self.reports_kept = 0
        self.samples_kept = 0  # the gyro's

        self.closed = False

    def __str__(self) -> str:
        return f"the recording {self.path}"

    def publish(self, row: PoseRow) -> None:
        pass  # the poses are made again by replaying the reports

    def reports(self, index: int, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
        # Live sources deliver whole counts; the format stores them as int32.
        self.writer.motion(index, t, np.rint(dx), np.rint(dy))
        self.reports_kept += len(t)

    def gyro(self, t: np.ndarray, rate: np.ndarray, saturated: np.ndarray | None = None) -> None:
        if self.gyro_device is not None:
            self.writer.gyro(self.gyro_device, t, rate, saturated)
            self.samples_kept += len(t)

    def checkpoint(self, complete: float) -> None:
        """Everything stamped up to ``complete`` is in the file (a crash keeps it)."""
        self.writer.sync(complete)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.writer.close()
        gyro = f", {self.samples_kept} gyro samples" if self.gyro_device is not None else ""
        log.info("recording %s closed: %d reports%s", self.path, self.reports_kept, gyro)
