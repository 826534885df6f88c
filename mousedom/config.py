"""Rig configuration: YAML in, frozen validated dataclasses out.

Every mistake becomes one ``ConfigError`` naming the file, the line and the key, e.g.
``rig.yaml:7: mice.left.cpi: must be a positive number, got -3``.  The YAML is parsed to
a node tree first so that each value keeps the line it came from.

A config may reference a calibration file (``calibration: rig.calib.yaml``, relative to
the config).  Values found there (per-mouse CPI and mount) override those of the config;
``mousedom calibrate ... --write`` writes that file, and the daemon rereads it on SIGHUP.
A referenced calibration file that does not exist yet is not an error: nothing has been
calibrated so far.
"""

from __future__ import annotations

import ipaddress
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

from mousedom import plausible, safeyaml
from mousedom.errors import located
from mousedom.yamldoc import ConfigError, Reader, YamlDoc, shown

T = TypeVar("T")

MODELS = ("lsq", "diff-drive", "bonarini")
INTEGRATORS = ("exact", "taylor", "euler", "midpoint")
DEFAULT_CONFIG_PATH = "/etc/mousedom/mousedom.yaml"


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
    # each mouse's scale relative to the others is learnt online from the redundancy of
    # three or more mice and reported (fusion.scalelearn); applied within +-scale_limit
    # where learn_scale is true
    learn_scale: bool = True
    scale_limit: float = 0.10


@dataclass(frozen=True)
class WheelsConfig:
    """Wheel-encoder geometry for the McGill reference model."""

    radius_left: float
    radius_right: float
    track: float
    ticks_per_rev: float


@dataclass(frozen=True)
class ServerConfig:
    socket: str | None = None  # None: /run/mousedom/mousedom.sock as root, else XDG dir
    mode: int = 0o660
    group: str | None = None
    control_uids: tuple[int, ...] = (0,)
    control_gids: tuple[int, ...] = ()
    max_clients: int = 32
    queue_lines: int = 256
    max_line: int = 4096
    idle_timeout_s: float = 10.0  # output waiting this long, nothing sent: the client goes


@dataclass(frozen=True)
class Ros2Config:
    """The optional ROS 2 output over DDS (docs/ros2.md); ``outputs: {ros2: {...}}``."""

    domain_id: int | None = None  # None: $ROS_DOMAIN_ID, else 0
    namespace: str = ""  # e.g. /robot1: topics become /robot1/odom, ...
    odom_topic: str = "/odom"
    tf_topic: str = "/tf"
    diagnostics_topic: str = "/diagnostics"
    odom_frame: str = "odom"
    base_frame: str = "base_link"
    map_frame: str = "map"
    publish_tf: bool = True  # odom -> base_link (off where robot_localization publishes it)
    publish_map_tf: bool = False  # map -> odom, the correction that fix and reset move
    diagnostics: bool = True
    counts: bool = False  # per-mouse counts of each window on <namespace>/mousedom/<mouse>/counts
    stamps: str = "system"  # system (ROS time, what tf and Nav2 compare with) | monotonic
    node_name: str = "mousedom"  # the node ROS 2 tools list (in the namespace, or /)
    optional: bool = False  # True: if DDS cannot start, log it and run without ROS 2
    initialpose: bool = False  # True: /initialpose (RViz's 2D Pose Estimate) fixes the pose


@dataclass(frozen=True)
class FoxgloveConfig:
    """The optional Foxglove live view (docs/ros2.md); ``outputs: {foxglove: {...}}``."""

    host: str = "127.0.0.1"  # localhost only unless said: the view has no access control
    port: int = 8765


@dataclass(frozen=True)
class MetricsConfig:
    """The optional Prometheus endpoint (docs/metrics.md); ``outputs: {metrics: {...}}``."""

    host: str = "127.0.0.1"  # localhost only unless said: the endpoint has no access control
    port: int = 9464  # 0: any free port (the log says which)


STAMPS = ("system", "monotonic")
# ROS 2's names, as rcl accepts them: a node name of letters, digits and _ not starting
# with a digit; a namespace of such names, each after a "/" (ros2graph announces these).
ROS_NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,254}")
ROS_NAMESPACE = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+/?")
ROS2_KEYS = tuple(f for f in Ros2Config.__dataclass_fields__)


@dataclass(frozen=True)
class Config:
    rate_hz: float
    model: str
    integrator: str
    mice: tuple[MouseConfig, ...]
    server: ServerConfig = field(default_factory=ServerConfig)
    wheels: WheelsConfig | None = None
    calibration: str | None = None  # absolute path of the calibration file, if any
    path: str | None = None  # where this config was read from
    robust: RobustConfig = field(default_factory=RobustConfig)
    # How late a report may come and still count where it was measured: a report within
    # this of the mouse's previous one covers all the time since (a USB catch-up report),
    # and windows wait this long for a silent mouse before closing without it.
    late_report_s: float = 0.1
    ros2: Ros2Config | None = None  # outputs.ros2: None means no DDS output
    foxglove: FoxgloveConfig | None = None  # outputs.foxglove: None means no live view
    metrics: MetricsConfig | None = None  # outputs.metrics: None means no Prometheus endpoint
    # values that look like the wrong unit (mousedom.plausible): said, not refused
    warnings: tuple[str, ...] = ()

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


TOP_KEYS = ("rate_hz", "model", "integrator", "mice", "server", "wheels", "calibration",
            "robust", "outputs", "late_report_s")  # fmt: skip
MOUSE_KEYS = ("cpi", "mount", "flip", "sigma", "report_hz", "evdev", "serial", "replay",
              "max_speed", "min_squal")  # fmt: skip
SERVER_KEYS = ("socket", "mode", "group", "control_uids", "control_gids", "max_clients",
               "queue_lines", "max_line", "idle_timeout_s")  # fmt: skip


# --------------------------------------------------------------------------- sections


def _cpi(r: Reader, key: str, default: tuple[float, float] | None) -> tuple[float, float]:
    v = r.raw(key)
    if v is None:
        if default is None:
            raise r.err(key, "is required (counts per inch, a number or {x: .., y: ..})")
        return default
    if isinstance(v, dict):
        sub = r.sub(key, ("x", "y"))
        cx = sub.number("x", positive=True)
        cy = sub.number("y", positive=True)
        sub.finish()
        return cx, cy
    c = r.number(key, positive=True)
    return c, c


def _mount(r: Reader, default: Mount | None) -> Mount:
    if not r.has("mount"):
        if default is None:
            raise r.err("mount", "is required ({x: metres, y: metres, yaw: degrees})")
        return default
    m = r.sub("mount", ("x", "y", "yaw"))
    base = default or Mount()
    x = m.number("x", base.x)
    y = m.number("y", base.y)
    yaw = math.radians(m.number("yaw", math.degrees(base.yaw)))
    m.finish()
    return Mount(x, y, yaw)


def _evdev(r: Reader) -> EvdevMatch:
    e = r.sub("evdev", ("path", "name", "phys", "vendor", "product", "uniq", "grab"))
    match = EvdevMatch(
        path=e.string("path"),
        name=e.string("name"),
        phys=e.string("phys"),
        vendor=e.integer("vendor") if e.has("vendor") else None,
        product=e.integer("product") if e.has("product") else None,
        uniq=e.string("uniq"),
        grab=e.boolean("grab", True),
    )
    e.finish()
    if not (match.path or match.name or match.phys or match.vendor is not None or match.uniq):
        raise r.err("evdev", "needs at least one of path, name, phys, vendor/product, uniq")
    return match


def _serial(r: Reader) -> SerialSource:
    s = r.sub("serial", ("port", "baud", "k", "sensor_cpi"))
    port = s.string("port")
    if not port:
        raise s.err("port", "is required (a device such as /dev/ttyUSB0 or a pyserial URL)")
    src = SerialSource(
        port=port,
        baud=s.integer("baud", 115200, minimum=1),
        k=s.integer("k", 12, minimum=1),
        sensor_cpi=s.integer("sensor_cpi", 1600),
    )
    if src.sensor_cpi not in (400, 1600):
        raise s.err("sensor_cpi", f"must be 400 or 1600, got {src.sensor_cpi}")
    if src.k > 255:
        raise s.err("k", f"must be at most 255, got {src.k}")
    s.finish()
    return src


def _mouse(doc: YamlDoc, name: str, value: Any, base_dir: Path) -> MouseConfig | None:
    """One mouse; None when it has problems (all kept in ``doc``, each part tried)."""
    r = Reader(doc, value, ("mice", name), MOUSE_KEYS)

    def required(key: str, read: Any) -> Any:
        # "mount: is required" is noise next to "mownt: unknown key (did you mean mount?)"
        if not r.has(key) and key in r.suggested:
            return None
        return doc.attempt(read)

    cpi = required("cpi", lambda: _cpi(r, "cpi", None))
    mount = required("mount", lambda: _mount(r, None if doc.need_mounts else Mount()))
    flip = doc.attempt(r.boolean, "flip", False)
    sigma = doc.attempt(r.number, "sigma", 0.5, positive=True)
    report_hz = doc.attempt(r.number, "report_hz", 125.0, within=(1.0, 100000.0))
    max_speed = doc.attempt(r.number, "max_speed", 0.0, positive=True) if r.has(
        "max_speed") else None  # fmt: skip
    min_squal = doc.attempt(r.integer, "min_squal", 0, minimum=0) if r.has(
        "min_squal") else None  # fmt: skip
    sources = [k for k in ("evdev", "serial", "replay") if r.has(k)]
    if len(sources) > 1:
        doc.keep(r.err(sources[1], f"a mouse has one source; {sources[0]} is given already"))
    source: dict[str, Any] = {}
    if r.has("evdev"):
        source["evdev"] = doc.attempt(_evdev, r)
    elif r.has("serial"):
        source["serial"] = doc.attempt(_serial, r)
    elif r.has("replay"):
        source["replay"] = doc.attempt(_replay, r, base_dir)
    parts = [cpi, mount, flip, sigma, report_hz, *source.values()]
    if any(p is None for p in parts):
        return None
    mouse = MouseConfig(
        name=name, cpi_x=cpi[0], cpi_y=cpi[1], mount=mount, flip=flip, sigma=sigma,
        report_hz=report_hz, max_speed=max_speed, min_squal=min_squal,
    )  # fmt: skip
    if "evdev" in source:
        mouse = replace(mouse, evdev=source["evdev"])
    elif "serial" in source:
        mouse = replace(mouse, serial=source["serial"])
        # The sensor's own limits are known; a USB mouse's are not (none unless set).
        if max_speed is None:
            mouse = replace(mouse, max_speed=ADNS3080_MAX_SPEED)
        if min_squal is None:
            mouse = replace(mouse, min_squal=ADNS3080_MIN_SQUAL)
        if not r.has("report_hz"):
            # The downsampler sends one packet per K sensor polls of 1250 us (firmware/).
            mouse = replace(mouse, report_hz=1e6 / (source["serial"].k * 1250.0))
    elif "replay" in source:
        file, device = source["replay"]
        mouse = replace(mouse, replay=str(base_dir / file), replay_device=device)
    return mouse


def _replay(r: Reader, base_dir: Path) -> tuple[str, str | None]:
    v = r.raw("replay")
    if isinstance(v, dict):
        rr = r.sub("replay", ("file", "device"))
        file = rr.string("file")
        device = rr.string("device")
    else:
        file, device = r.string("replay"), None
    if not file:
        raise r.err("replay", "needs a capture file")
    return file, device


def _server(r: Reader) -> ServerConfig:
    s = r.sub("server", SERVER_KEYS)
    mode = s.raw("mode", 0o660)
    if isinstance(mode, str):
        try:
            mode = int(mode, 8)
        except ValueError:
            raise s.err(
                "mode", f"must be an octal file mode such as '0660', got {mode!r}"
            ) from None
    if isinstance(mode, bool) or not isinstance(mode, int) or not 0 <= mode <= 0o777:
        raise s.err("mode", f"must be a file mode between 0 and 0777, got {shown(mode)}")

    def ids(key: str, default: tuple[int, ...]) -> tuple[int, ...]:
        v = s.raw(key, list(default))
        if not isinstance(v, list) or not all(isinstance(i, int) and i >= 0 for i in v):
            raise s.err(key, f"must be a list of numeric ids, got {shown(v)}")
        return tuple(v)

    server = ServerConfig(
        socket=s.string("socket"),
        mode=mode,
        group=s.string("group"),
        control_uids=ids("control_uids", (0,)),
        control_gids=ids("control_gids", ()),
        max_clients=s.integer("max_clients", 32, minimum=1),
        queue_lines=s.integer("queue_lines", 256, minimum=1),
        max_line=s.integer("max_line", 4096, minimum=64),
        idle_timeout_s=s.number("idle_timeout_s", 10.0, within=(0.5, 86400.0)),
    )
    s.finish()
    return server


def _robust(r: Reader) -> RobustConfig:
    v = r.raw("robust")
    if isinstance(v, bool):  # `robust: false` turns it off (for comparison)
        return RobustConfig(enabled=v)
    s = r.sub("robust", ("enabled", "false_alarm", "relative_noise", "readmit_s",
                         "learn_scale", "scale_limit"))  # fmt: skip
    robust = RobustConfig(
        enabled=s.boolean("enabled", True),
        false_alarm=s.number("false_alarm", 1e-4, within=(1e-12, 0.5)),
        relative_noise=s.number("relative_noise", 0.05, within=(0.0, 1.0)),
        readmit_s=s.number("readmit_s", 0.25, within=(0.0, 3600.0)),
        learn_scale=s.boolean("learn_scale", True),
        scale_limit=s.number("scale_limit", 0.10, within=(0.0, 0.5)),
    )
    s.finish()
    return robust


def _outputs(
    r: Reader,
) -> tuple[Ros2Config | None, FoxgloveConfig | None, MetricsConfig | None]:
    o = r.sub("outputs", ("ros2", "foxglove", "metrics"))
    ros2 = _switched(o, "ros2", Ros2Config, _ros2)
    fox = _switched(o, "foxglove", FoxgloveConfig, _foxglove)
    metrics = _switched(o, "metrics", MetricsConfig, _metrics)
    o.finish()
    return ros2, fox, metrics


def _switched(
    o: Reader, key: str, default: Callable[[], T], parse: Callable[[Reader], T | None]
) -> T | None:
    """An output under ``outputs``: absent, false or null is off; true is on with its
    defaults; a mapping is parsed (whose ``enabled: false`` is off too)."""
    if not o.has(key):
        return None
    v = o.raw(key)
    if v is False or v is None:
        return None
    if v is True:
        return default()
    return parse(o)


def _tcp_port(s: Reader, default: int, zero: str = "") -> int:
    """``port``: a TCP port to listen on (0 to 65535; ``zero`` says what 0 does)."""
    port = s.integer("port", default, minimum=0)
    if port > 65535:
        raise s.err("port", f"must be a TCP port (0 to 65535{zero}), got {port}")
    return port


def _foxglove(r: Reader) -> FoxgloveConfig | None:
    s = r.sub("foxglove", ("enabled", "host", "port"))
    d = FoxgloveConfig()
    cfg = FoxgloveConfig(host=s.string("host") or d.host, port=_tcp_port(s, d.port))
    enabled = s.boolean("enabled", True)
    s.finish()
    return cfg if enabled else None


def _metrics(r: Reader) -> MetricsConfig | None:
    s = r.sub("metrics", ("enabled", "host", "port"))
    d = MetricsConfig()
    port = _tcp_port(s, d.port, "; 0: any free one")
    host = s.string("host") or d.host
    # An address, not a name: a name would be looked up (DNS) at every start, and could
    # resolve to an interface nobody meant to expose.
    try:
        ipaddress.ip_address(host)
    except ValueError:
        if host != "localhost":
            raise s.err("host", "must be an IP address to listen on (127.0.0.1 or ::1 for "
                        "this machine only, 0.0.0.0 or :: for every interface), got "
                        f"{shown(host)}") from None  # fmt: skip
    enabled = s.boolean("enabled", True)
    s.finish()
    return MetricsConfig(host=host, port=port) if enabled else None


def _ros2(r: Reader) -> Ros2Config:
    s = r.sub("ros2", ("enabled", *ROS2_KEYS))
    d = Ros2Config()

    def name(key: str, default: str, topic: bool) -> str:
        v = s.string(key) if s.has(key) else default
        ok = all(c.isalnum() or c in "_/~" for c in v) if topic else all(
            c.isalnum() or c in "_/" for c in v)  # fmt: skip
        if not v or not ok or "//" in v:
            what = "a ROS topic name" if topic else "a frame id"
            raise s.err(key, f"must be {what} (letters, digits, _ and /), got {shown(v)}")
        return v

    namespace = s.string("namespace") if s.has("namespace") else ""
    if namespace and not ROS_NAMESPACE.fullmatch(namespace):
        raise s.err(
            "namespace",
            "must be /name or /a/b, each name of letters, digits and _ not starting with a "
            f"digit (e.g. /robot1), got {shown(namespace)}",
        )
    domain = s.integer("domain_id", minimum=0) if s.has("domain_id") else None
    if domain is not None and domain > 232:
        raise s.err("domain_id", f"must be between 0 and 232 (ROS 2's range), got {domain}")
    cfg = Ros2Config(
        domain_id=domain,
        namespace=namespace.rstrip("/"),
        odom_topic=name("odom_topic", d.odom_topic, True),
        tf_topic=name("tf_topic", d.tf_topic, True),
        diagnostics_topic=name("diagnostics_topic", d.diagnostics_topic, True),
        odom_frame=name("odom_frame", d.odom_frame, False),
        base_frame=name("base_frame", d.base_frame, False),
        map_frame=name("map_frame", d.map_frame, False),
        publish_tf=s.boolean("publish_tf", d.publish_tf),
        publish_map_tf=s.boolean("publish_map_tf", d.publish_map_tf),
        diagnostics=s.boolean("diagnostics", d.diagnostics),
        counts=s.boolean("counts", d.counts),
        stamps=s.choice("stamps", STAMPS, d.stamps),
        node_name=s.string("node_name") if s.has("node_name") else d.node_name,
        optional=s.boolean("optional", d.optional),
        initialpose=s.boolean("initialpose", d.initialpose),
    )
    if not ROS_NODE_NAME.fullmatch(cfg.node_name):
        raise s.err("node_name", "must be a ROS 2 node name (letters, digits and _, not "
                    f"starting with a digit), got {shown(cfg.node_name)}")  # fmt: skip
    enabled = s.boolean("enabled", True)
    s.finish()
    return cfg if enabled else None


def _wheels(r: Reader) -> WheelsConfig:
    w = r.sub("wheels", ("radius", "radius_left", "radius_right", "track", "ticks_per_rev"))
    radius = w.number("radius", 0.0) if w.has("radius") else None
    wheels = WheelsConfig(
        radius_left=w.number("radius_left", radius, positive=True),
        radius_right=w.number("radius_right", radius, positive=True),
        track=w.number("track", positive=True),
        ticks_per_rev=w.number("ticks_per_rev", positive=True),
    )
    w.finish()
    return wheels


# --------------------------------------------------------------------------- calibration


def _apply_calibration(mice: tuple[MouseConfig, ...], path: Path) -> tuple[MouseConfig, ...]:
    try:
        text = safeyaml.read_text(path)
    except FileNotFoundError:
        return mice
    except OSError as e:
        raise ConfigError(
            located(str(path), None, f"cannot read calibration: {e.strerror}")
        ) from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: byte offset {e.start}: not UTF-8 text") from None
    doc = YamlDoc(str(path), text)
    top = Reader(doc, doc.data, ())
    section = top.sub("mice")
    by_name = {m.name: m for m in mice}
    for name in section.value:
        if name not in by_name:
            raise section.err(str(name), "calibration for a mouse the config does not have")
        r = section.sub(str(name), ("cpi", "mount", "scale"))
        m = by_name[name]
        cpi_x, cpi_y = _cpi(r, "cpi", (m.cpi_x, m.cpi_y))
        by_name[name] = replace(m, cpi_x=cpi_x, cpi_y=cpi_y, mount=_mount(r, m.mount))
        r.raw("scale")  # informational, written by `calibrate mounts`
        r.finish()
    section.finish()
    for key in top.value:  # other sections (distance, notes) are informational
        top.used.add(key)
    doc.raise_problems()
    return tuple(by_name[m.name] for m in mice)


# --------------------------------------------------------------------------- entry points


def parse_config(
    text: str,
    path: str | None = None,
    *,
    need_sources: bool = True,
    need_model: bool = True,
    need_mounts: bool = True,
) -> Config:
    """Parse and validate a config given as text.

    ``need_sources=False`` lets mice leave out where they come from (replay and
    calibration supply captures on the command line instead).  A tool that does not fuse
    validates only what it uses: ``need_model=False`` skips the check that the model can
    be solved from the mice (one mouse on a calibration jig is a fine rig for
    ``calibrate cpi``), ``need_mounts=False`` lets mice leave out their mount (taken as
    the body origin).
    """
    doc = YamlDoc(path, text)
    doc.need_mounts = need_mounts
    base_dir = Path(path).resolve().parent if path else Path.cwd()
    if doc.data is None:
        raise doc.error((), "the file is empty: a rig config needs at least `mice:`")
    top = Reader(doc, doc.data, (), TOP_KEYS)
    # Each section is read even when another failed, so that one run names every mistake.
    rate_hz = doc.attempt(top.number, "rate_hz", 100.0, within=(0.1, 10000.0)) or 100.0
    model = doc.attempt(top.choice, "model", MODELS, "lsq") or "lsq"
    integrator = doc.attempt(top.choice, "integrator", INTEGRATORS, "exact") or "exact"
    late = doc.attempt(top.number, "late_report_s", 0.1, within=(0.0, 1.0))
    mice_raw = top.raw("mice")
    if not isinstance(mice_raw, dict) or not mice_raw:
        doc.keep(doc.error(("mice",), "needs at least one mouse (a mapping of name: settings)"))
        mice_raw = {}
    read = [
        doc.attempt(_mouse, doc, str(name), value, base_dir) for name, value in mice_raw.items()
    ]
    server = (doc.attempt(_server, top) if top.has("server") else None) or ServerConfig()
    wheels = doc.attempt(_wheels, top) if top.has("wheels") else None
    robust = (doc.attempt(_robust, top) if top.has("robust") else None) or RobustConfig()
    outputs = doc.attempt(_outputs, top) if top.has("outputs") else None
    ros2, foxglove, metrics = outputs or (None, None, None)
    calibration = doc.attempt(top.string, "calibration")
    calibration_path = str(base_dir / calibration) if calibration else None
    doc.raise_problems()
    mice = tuple(m for m in read if m is not None)

    found = plausible.suspects([(m.name, m.cpi_x, m.cpi_y, m.mount.x, m.mount.y,
                                 math.degrees(m.mount.yaw)) for m in mice])  # fmt: skip
    warnings = tuple(
        str(doc.error(s.keys, s.message))
        for s in found  # file:line: key: message
    )
    if calibration_path:
        mice = _apply_calibration(mice, Path(calibration_path))

    if need_sources:
        for m in mice:
            if not (m.evdev or m.serial or m.replay):
                doc.keep(doc.error(
                    ("mice", m.name),
                    "says nowhere where the mouse comes from (evdev, serial or replay)",
                ))  # fmt: skip
        doc.raise_problems()

    from mousedom.fusion.geometry import rank_problem  # late import: geometry is numeric

    problem = rank_problem(model, [(m.mount.x, m.mount.y) for m in mice], [m.name for m in mice])
    if problem and need_model:
        raise doc.error(("mice",), f"model {model}: {problem}")
    return Config(
        rate_hz=rate_hz,
        model=model,
        integrator=integrator,
        mice=mice,
        server=server,
        wheels=wheels,
        calibration=calibration_path,
        path=path,
        robust=robust,
        late_report_s=0.1 if late is None else late,
        ros2=ros2,
        foxglove=foxglove,
        metrics=metrics,
        warnings=warnings,
    )


def load_config(
    path: str | os.PathLike[str],
    *,
    need_sources: bool = True,
    need_model: bool = True,
    need_mounts: bool = True,
) -> Config:
    """Read a config file; every problem is a ConfigError naming file, line and key."""
    p = str(path)
    try:
        text = safeyaml.read_text(p)  # bounded: a reload must not swallow a 10 GB file
    except FileNotFoundError:
        raise ConfigError(f"{p}: config file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: is a directory, not a config file") from None
    except OSError as e:
        raise ConfigError(f"{p}: cannot read config: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{p}: byte offset {e.start}: not UTF-8 text") from None
    return parse_config(
        text, p, need_sources=need_sources, need_model=need_model, need_mounts=need_mounts
    )
