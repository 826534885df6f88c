"""``mousedom run --record FILE``: what the daemon fused, kept as a native capture.

Every report that reaches the tracker is appended (decoded motion, host monotonic time,
evdev convention), with the config in the header, so that ``mousedom replay FILE`` shows
afterwards what the robot saw.  The native format survives a crash up to the last SYNC,
written once a second; SIGTERM/SIGINT flush and close it.  (``mousedom record`` is the
bench tool that keeps a serial sensor's raw bytes too.)
"""

from __future__ import annotations

import logging

import numpy as np

from mousedom import saferead
from mousedom.capture.base import DeviceInfo
from mousedom.capture.native import NativeWriter
from mousedom.config import Config, MouseConfig
from mousedom.errors import UserError
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


class Recording(Output):
    """An open native capture of the daemon's input: an output that keeps the reports.

    A recording that cannot be written (full disk, file size limit) fails as any output
    does: it is logged and stopped, the file keeps what reached it (all but the torn last
    chunk), and the fusion, which robots rely on, goes on."""

    def __init__(self, path: str, config: Config, source_kinds: list[str]) -> None:
        text = None
        if config.path:
            try:
                text = saferead.read_text(config.path)
            except (OSError, UnicodeDecodeError):
                text = None
        try:
            self.writer = NativeWriter(
                path,
                [_device(m, k) for m, k in zip(config.mice, source_kinds, strict=True)],
                config_text=text,
                time_base="monotonic",
                meta={"recorder": "mousedom run --record", "config_path": config.path},
                inputs=(config.path, config.calibration),
            )
        except OSError as e:
            raise UserError(f"{path}: cannot write the recording: {e.strerror}") from None
        self.path = path
        self.names = config.names
        self.reports_kept = 0

        self.closed = False

    def __str__(self) -> str:
        return f"the recording {self.path}"

    def publish(self, row: PoseRow) -> None:
        pass  # the poses are made again by replaying the reports

    def reports(self, index: int, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
        # Live sources deliver whole counts; the format stores them as int32.
        self.writer.motion(index, t, np.rint(dx), np.rint(dy))
        self.reports_kept += len(t)

    def checkpoint(self, complete: float) -> None:
        """Everything stamped up to ``complete`` is in the file (a crash keeps it)."""
        self.writer.sync(complete)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.writer.close()
        log.info("recording %s closed: %d reports", self.path, self.reports_kept)
