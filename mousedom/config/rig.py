"""The rig's types: frozen dataclasses a parsed config is made of.

Each default is stated once, on its field; the parsers read it from there (``default``).
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, field, fields, replace
from typing import Any, TypeVar

from mousedom.config.outputs import FoxgloveConfig, MetricsConfig, Ros2Config, ServerConfig
from mousedom.errors import located

T = TypeVar("T")


def default(cls: type[Any], name: str, kind: type[T]) -> T:
    """The default of dataclass ``cls``'s field ``name``, checked to be a ``kind``."""
    for f in fields(cls):
        if f.name == name and f.default is not MISSING and isinstance(f.default, kind):
            return f.default
    raise TypeError(f"{cls.__name__}.{name} has no {kind.__name__} default")


@dataclass(frozen=True)
class Mount:
    """Sensor position in the body frame (metres) and yaw from body x to mouse forward."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0  # radians (the YAML says degrees)


@dataclass(frozen=True)
class EvdevMatch:
    """How a config entry finds its evdev device; any given field must match."""

    path: str | None = None  # a /dev/input/by-path/... or by-id/... link, or a node
    name: str | None = None
    phys: str | None = None
    vendor: int | None = None
    product: int | None = None
    uniq: str | None = None
    grab: bool = True


@dataclass(frozen=True)
class SerialSource:
    """An ADNS-3080 downsampler on a serial port (any pyserial URL)."""

    port: str
    baud: int = 115200
    k: int = 12  # sensor frames accumulated per packet
    sensor_cpi: int = 1600  # 1600 or 400, set in the sensor by the firmware


@dataclass(frozen=True)
class MouseConfig:
    name: str
    cpi_x: float
    cpi_y: float
    mount: Mount
    flip: bool = False  # mirrored sensor: REL_X points left instead of right
    sigma: float = 0.5  # measurement noise per axis per window, in counts (for weighting)
    report_hz: float = 125.0  # nominal report rate: bounds how far back a report reaches
    evdev: EvdevMatch | None = None
    serial: SerialSource | None = None
    replay: str | None = None  # capture file (absolute, or resolved against the config)
    replay_device: str | None = None  # device name inside a multi-device capture
    max_speed: float | None = None  # m/s the sensor tracks; faster reads are "saturated"
    min_squal: int | None = None  # ADNS-3080 SQUAL below this gates reports ("low quality")


# ADNS-3080 datasheet: tracking up to 40 inches per second; SQUAL (a quarter of the
# features seen, at most 169) is "nearly equal to zero if there is no surface below the
# sensor" and averages several tens on white paper at the nominal height, so a floor of 15
# tells a lifted or blinded sensor from a dull floor.
ADNS3080_MAX_SPEED = 40 * 0.0254
ADNS3080_MIN_SQUAL = 15


@dataclass(frozen=True)
class RobustConfig:
    """The fault-tolerant fusion's settings (docs/models.md, "Faults")."""

    enabled: bool = True
    false_alarm: float = 1e-4  # chance per window that a healthy rig fails the test
    relative_noise: float = 0.05  # reading error in proportion to motion (CPI, stamps)
    readmit_s: float = 0.25  # consistent motion an excluded mouse needs to be used again
    # how long a mouse whose shortfall is the motion of its last moments (its counts owed,
    # as after a USB host's stall) is held out as "late" before it is called excluded
    late_s: float = 0.05
    # each mouse's scale relative to the others is learnt online from the redundancy of
    # three or more mice and reported (fusion.scalelearn); applied where its CPI is within
    # +-scale_limit of the configured one (ScaleLearner.bounds), where learn_scale is true
    learn_scale: bool = True
    scale_limit: float = 0.10


@dataclass(frozen=True)
class WheelsConfig:
    """Wheel-encoder geometry for the McGill reference model."""

    radius_left: float
    radius_right: float
    track: float
    ticks_per_rev: float


# MPU-6000/MPU-6050 Product Specification (InvenSense PS-MPU-6000A-00 rev. 3.4), section
# 6.1: gyroscope rate noise spectral density 0.005 deg/s/sqrt(Hz) at 10 Hz, a typical MEMS
# figure; the default white-noise density of a gyro whose config says none.
MPU6050_NOISE = math.radians(0.005)


@dataclass(frozen=True)
class GyroRos2:
    """A gyro read from a ROS 2 ``sensor_msgs/Imu`` topic over DDS (``gyro: {ros2: ...}``):
    the angular velocity of an IMU whose driver publishes in ROS 2."""

    topic: str  # absolute, e.g. /imu/data
    # None: the ROS 2 output's (``output_domain``), else $ROS_DOMAIN_ID, else 0 (as ROS 2
    # does)
    domain_id: int | None = None
    # what the headers' stamps are on: system (ROS time, what drivers stamp with) or
    # monotonic (a driver stamping with the steady clock)
    stamps: str = "system"
    # From the ROS 2 output's section (config.load): its domain, the default for this
    # one, and its namespace, the reader's node's (one robot, one graph).  Not the gyro's
    # identity (``inherited``): the output keeps its own until a restart, and a reload
    # that edits only them must not reopen the gyro on another domain than the output's.
    output_domain: int | None = None
    namespace: str = ""

    def domain(self) -> int | None:
        """The domain to read on: the gyro's own, else the output's (None: as ROS 2 says)."""
        return self.domain_id if self.domain_id is not None else self.output_domain


@dataclass(frozen=True)
class GyroConfig:
    """The optional gyro (``gyro:``, docs/gyro.md): an IIO device and how it is mounted."""

    name: str | None = None  # the IIO device's `name` attribute, e.g. mpu6050
    path: str | None = None  # /sys/bus/iio/devices/iio:deviceN, /dev/iio:deviceN or a link
    axis: str = "z"  # the sensor axis along body z (up): x | y | z
    sign: int = 1  # -1 when that axis points down (a gyro mounted upside down)
    sample_hz: float | None = None  # written to sampling_frequency; None: the device's own
    noise: float = MPU6050_NOISE  # white-noise density of the rate, rad/s/sqrt(Hz)
    use: str = "both"  # heading from: both (gyro and mice) | gyro | mice
    replay: str | None = None  # a capture's gyro instead of a device (absolute path)
    replay_device: str | None = None  # its name or node, where the capture holds several
    ros2: GyroRos2 | None = None  # an IMU's sensor_msgs/Imu topic instead of a device

    def own(self) -> GyroConfig:
        """This gyro's section alone, without what it takes from the ROS 2 output's
        (GyroRos2.output_domain, namespace): what identifies it across a reload (the
        source reopened, the fusion's learning kept or begun again)."""
        if self.ros2 is None:
            return self
        return replace(self, ros2=replace(self.ros2, output_domain=None, namespace=""))


# Keyword-only: the top-level defaults (rate_hz, model, integrator) stand before the
# required mice, in the order the YAML lists them.
@dataclass(frozen=True, kw_only=True)
class Config:
    rate_hz: float = 100.0  # the output rate: one pose per window of 1/rate_hz seconds
    model: str = "lsq"
    integrator: str = "exact"
    mice: tuple[MouseConfig, ...]
    server: ServerConfig = field(default_factory=ServerConfig)
    wheels: WheelsConfig | None = None
    calibration: str | None = None  # absolute path of the calibration file, if any
    path: str | None = None  # where this config was read from
    robust: RobustConfig = field(default_factory=RobustConfig)
    # How late a report may come and still count where it was measured: a report within
    # this of the mouse's previous one covers all the time since (a USB catch-up report),
    # and windows wait this long for a silent mouse before closing without it.  0.15 s:
    # two chained USB gaps of 50-65 ms (a host that skips polls twice in a row) and the
    # slot between are still counted where measured; the wait adds nothing to the 99th
    # percentile of a window's delay (14 ms), 0.2 s would (38 ms; bench/latency.py).
    late_report_s: float = 0.15
    ros2: Ros2Config | None = None  # outputs.ros2: None means no DDS output
    foxglove: FoxgloveConfig | None = None  # outputs.foxglove: None means no live view
    metrics: MetricsConfig | None = None  # outputs.metrics: None means no Prometheus endpoint
    gyro: GyroConfig | None = None  # gyro: None means the heading comes from the mice alone
    # values that look like the wrong unit (mousedom.plausible): said, not refused
    warnings: tuple[str, ...] = ()
    # the line of each key path as written (YamlDoc.lines): where checks made after the
    # load (a capture file, a device in it) point the user; no part of what the config is
    lines: dict[tuple[str, ...], int] = field(default_factory=dict, compare=False, repr=False)

    def locate(self, keys: tuple[str, ...], message: str) -> str:
        """``path:line: a.b.c: message`` for a key path (its nearest written parent's
        line), as the load's errors name a key (``YamlDoc.error``)."""
        from mousedom.yamldoc import key_line  # (late: the config's types need no YAML)

        return located(self.path, key_line(self.lines, keys), message, ".".join(keys))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.mice)

    def mouse(self, name: str) -> MouseConfig:
        for m in self.mice:
            if m.name == name:
                return m
        raise KeyError(name)

    def index(self, name: str) -> int:
        return self.names.index(name)
