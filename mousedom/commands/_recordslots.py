"""``mousedom record``'s slots: one per configured source, with what it has recorded.

A loop of its own rather than the daemon's Sensors (service/slots.py): ``record`` writes a
downsampler's raw bytes and evdev's per-device notes, and has no tracker and no windows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

from mousedom.config import Config, GyroConfig, MouseConfig, SerialSource
from mousedom.errors import UserError
from mousedom.sources.base import Source
from mousedom.sources.discovery import SystemPaths

if TYPE_CHECKING:
    from mousedom.capture.base import DeviceInfo as CaptureDevice
    from mousedom.service.ros2imu import Ros2ImuSource
    from mousedom.sources.discovery import DeviceInfo
    from mousedom.sources.evdev import EvdevSource
    from mousedom.sources.iio import GyroSource
    from mousedom.sources.iio_sysfs import IioPaths


@dataclass
class SerialBytes:
    """What a downsampler's port gave, read by read (host arrival times), until the next
    flush; ``total`` counts every byte."""

    t: list[float] = field(default_factory=list)
    data: list[bytes] = field(default_factory=list)
    total: int = 0

    def add(self, t: float, data: bytes) -> None:
        self.t.append(t)
        self.data.append(bytes(data))
        self.total += len(data)


@dataclass
class Slot:
    """One configured source and its recording bookkeeping.

    ``mousedom record`` keeps a loop of its own rather than the daemon's Sensors
    (service/slots.py): it records raw serial bytes and evdev's per-device notes, has no
    tracker and no windows, and reads every source as it becomes readable."""

    index: int
    mouse: MouseConfig
    source: Source  # EvdevSource or AdnsSource
    # An ADNS-3080 downsampler's raw bytes, which are what is recorded (None: evdev)
    raw: SerialBytes | None = None
    connected: bool = True
    polled: bool = False  # no fd to select on (loop:// ports): read on every loop turn
    next_retry: float = 0.0
    reports: int = 0
    last_reports: int = 0

    @property
    def name(self) -> str:
        return self.mouse.name

    @property
    def serial(self) -> bool:
        return self.raw is not None

    @property
    def evdev(self) -> EvdevSource:
        """The evdev source of a mouse that is not serial."""
        from mousedom.sources.evdev import EvdevSource

        if not isinstance(self.source, EvdevSource):
            raise TypeError(f"{self.mouse.name}: not an evdev source")
        return self.source

    @property
    def device(self) -> DeviceInfo:
        """The evdev device a mouse's slot has open (it is recorded only once open)."""
        device = self.evdev.device
        if device is None:
            raise TypeError(f"{self.mouse.name}: not open")
        return device

    @property
    def port(self) -> SerialSource:
        """The serial settings of a downsampler's slot."""
        if self.mouse.serial is None:
            raise TypeError(f"{self.mouse.name}: not a serial source")
        return self.mouse.serial


def make_slot(
    cfg: Config, index: int, mouse: MouseConfig, paths: SystemPaths | None = None
) -> Slot:
    where = f"{cfg.path}: mice.{mouse.name}"
    if mouse.evdev is not None:
        from mousedom.sources.evdev import EvdevSource

        return Slot(index, mouse, EvdevSource(mouse, paths))
    if mouse.serial is not None:
        # The serial source configures the downsampler (K, CPI) as the daemon would, and
        # hands every chunk it reads to on_raw before decoding: those bytes are recorded.
        from mousedom.sources.adns import AdnsSource

        raw = SerialBytes()
        return Slot(index, mouse, AdnsSource(mouse, on_raw=raw.add), raw=raw)
    raise UserError(f"{where}: a replay source cannot be recorded (it is a recording already)")


@dataclass
class GyroSlot:
    """The rig's gyro (``gyro:``) and what it has recorded: its samples, as the daemon
    would fuse them (axis, sign and scale applied), into the capture's "iio" device."""

    index: int  # its device in the capture: after the mice
    config: GyroConfig
    source: GyroSource | Ros2ImuSource
    connected: bool = True
    polled: bool = False  # read on every loop turn (the source's polled fallback)
    next_retry: float = 0.0
    reports: int = 0  # samples
    last_reports: int = 0
    name: ClassVar[str] = "gyro"  # the tracker's name for it (fusion.gyro.GYRO)

    @property
    def node(self) -> str:
        if self.config.ros2 is not None:
            return self.config.ros2.topic
        dev = getattr(self.source, "device", None)
        if dev is None:
            return self.config.path or self.config.name or "gyro"
        return str(dev.node)


def make_gyro_slot(cfg: Config, index: int, iio: IioPaths | None = None) -> GyroSlot | None:
    """The gyro's slot, if the rig has one (``iio``: where IIO devices are, for --root)."""
    if cfg.gyro is None:
        return None
    if cfg.gyro.ros2 is not None:
        from mousedom.service.ros2imu import Ros2ImuSource

        return GyroSlot(index, cfg.gyro, Ros2ImuSource(cfg.gyro))
    from mousedom.sources.iio import GyroSource

    return GyroSlot(index, cfg.gyro, GyroSource(cfg.gyro, iio))


def gyro_device_info(slot: GyroSlot) -> CaptureDevice:
    """The gyro as opened: its IIO name and node, and how its samples were made."""
    from mousedom.capture.base import GYRO_KIND
    from mousedom.capture.base import DeviceInfo as CaptureDevice

    src = slot.source
    ros2 = slot.config.ros2
    if ros2 is not None:  # an IMU's topic: what it is, as the source read it
        return CaptureDevice(
            name=ros2.topic, kind=GYRO_KIND, rel_xy=False,
            extra={"source": "ros2", "topic": ros2.topic, "domain_id": src.health.extra.get(
                "domain_id"), "stamps": ros2.stamps, "axis": slot.config.axis,
                   "sign": slot.config.sign},
        )  # fmt: skip
    from mousedom.sources.iio import GyroSource

    assert isinstance(src, GyroSource)
    dev = src.device
    return CaptureDevice(
        name=dev.name if dev is not None else slot.node,
        kind=GYRO_KIND,
        rel_xy=False,
        extra={
            "node": slot.node,
            "sysfs": str(dev.sysdir) if dev is not None else None,
            "axis": slot.config.axis,
            "sign": slot.config.sign,
            "scale": src.scale,  # rad/s per LSB, as read at open
            "offset": src.offset,  # LSB
            "sample_hz": slot.config.sample_hz,
            "mode": src.mode.value if src.mode is not None else None,
        },
    )


def fileno_of(source: Source) -> int:
    """The fd to wait on, or -1 for ports without one (loop:// ...): those are polled."""
    try:
        fd = source.fileno()
    except Exception:  # pyserial URL handlers differ in what they raise here
        return -1
    return fd if isinstance(fd, int) and fd >= 0 else -1


def device_info(slot: Slot) -> CaptureDevice:
    from mousedom.capture.base import DeviceInfo as CaptureDevice

    m = slot.mouse
    if slot.serial:
        port = slot.port
        return CaptureDevice(
            name=port.port,
            kind="serial",
            mouse=m.name,
            extra={"port": port.port, "baud": port.baud, "k": port.k,
                   "sensor_cpi": port.sensor_cpi},
        )  # fmt: skip
    src, d = slot.evdev, slot.device
    return CaptureDevice(
        name=d.name,
        kind="evdev",
        bus=d.bustype or None,
        vendor=d.vendor or None,
        product=d.product or None,
        version=d.version or None,
        phys=d.phys or None,
        uniq=d.uniq or None,
        mouse=m.name,
        rel_xy=True,
        extra={
            "node": d.node,
            "by_id": list(d.by_id),
            "by_path": list(d.by_path),
            "mouse_dpi": d.mouse_dpi,
            "grabbed": src.grabbed,
        },
    )


def node_of(s: Slot) -> str:
    if s.serial:
        return s.port.port
    return s.device.node


def describe(s: Slot) -> str:
    return f"serial {node_of(s)}" if s.serial else node_of(s)
