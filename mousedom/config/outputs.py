"""Where the poses go: the socket server's settings and the optional outputs (ROS 2,
Foxglove, Prometheus), their types and their YAML sections (``server:``, ``outputs:``)."""

from __future__ import annotations

import ipaddress
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from mousedom.yamldoc import Reader, shown

T = TypeVar("T")

MAX_SOCKET_PATH = 107  # sizeof(sockaddr_un.sun_path) on Linux, less its terminating NUL
MAX_ID = 2**32 - 2  # uid_t and gid_t; (uid_t) -1 means "no change" to chown, no user


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
# ROS 2's names, as rcl accepts them (rmw's validate_node_name, validate_namespace and
# validate_full_topic_name): ASCII letters, digits and _, no name starting with a digit; a
# node name one such name; a namespace and a topic such names, each after a "/" (a topic
# name relative to the namespace: the first without).  No "~" or "{}": rcl expands them
# (private names, substitutions) where this daemon, speaking DDS itself, would send them
# as they are, names no ROS 2 node can subscribe to.
_ROS_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
ROS_NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,254}")
ROS_NAMESPACE = re.compile(rf"(/{_ROS_TOKEN})+/?")
ROS_TOPIC = re.compile(rf"/?{_ROS_TOKEN}(/{_ROS_TOKEN})*")
# A full topic name (namespace and all) is at most 247 characters (RMW_TOPIC_MAX_NAME_LENGTH:
# 255 less 8 kept for DDS's prefixes), a namespace 2 fewer (RMW_NAMESPACE_MAX_LENGTH).
ROS_TOPIC_MAX = 247
ROS_NAMESPACE_MAX = ROS_TOPIC_MAX - 2
# Topics the output puts under the namespace whatever the config names (ros2out)
FIXED_TOPICS = ("/tf_static", "/initialpose")
# A tf2 frame id: no leading "/" (tf2 refuses such ids at every lookup); the rest as this
# daemon has always written them, letters, digits and _ between single "/".
ROS_FRAME = re.compile(r"[A-Za-z0-9_]+(/[A-Za-z0-9_]+)*")
ROS2_KEYS = tuple(f for f in Ros2Config.__dataclass_fields__)
SERVER_KEYS = ("socket", "mode", "group", "control_uids", "control_gids", "max_clients",
               "queue_lines", "max_line", "idle_timeout_s")  # fmt: skip


def read_server(r: Reader) -> ServerConfig:
    s = r.sub("server", SERVER_KEYS)
    d = ServerConfig()
    mode = s.raw("mode", d.mode)
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
        # (a YAML true is an int to Python: 1 in (True,) gave uid 1 control)
        v = s.raw(key, list(default))
        if not isinstance(v, list) or not all(
            isinstance(i, int) and not isinstance(i, bool) and 0 <= i <= MAX_ID for i in v
        ):
            raise s.err(key, f"must be a list of numeric ids (0 to {MAX_ID}), got {shown(v)}")
        return tuple(v)

    socket = s.string("socket")
    if socket is not None and not socket.strip():  # ("" fell back to the default path)
        raise s.err("socket", "is empty: a path, or leave the key out for the default")
    if socket is not None and len(os.fsencode(socket)) > MAX_SOCKET_PATH:
        raise s.err("socket", f"is {len(os.fsencode(socket))} bytes, longer than the "
                    f"{MAX_SOCKET_PATH} a Unix socket's address holds")  # fmt: skip
    server = ServerConfig(
        socket=socket,
        mode=mode,
        group=s.string("group"),
        control_uids=ids("control_uids", d.control_uids),
        control_gids=ids("control_gids", d.control_gids),
        max_clients=s.integer("max_clients", d.max_clients, minimum=1),
        queue_lines=s.integer("queue_lines", d.queue_lines, minimum=1),
        max_line=s.integer("max_line", d.max_line, minimum=64),
        idle_timeout_s=s.number("idle_timeout_s", d.idle_timeout_s, within=(0.5, 86400.0)),
    )
    s.finish()
    return server


def read_outputs(
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


def _text(s: Reader, key: str, default: str) -> str:
    """A string with a default: absent is the default, null is no string."""
    v = s.string(key, default)
    if v is None:
        raise s.err(key, f"must be a string, got {shown(v)}")
    return v


def _ros2(r: Reader) -> Ros2Config | None:
    s = r.sub("ros2", ("enabled", *ROS2_KEYS))
    d = Ros2Config()

    namespace = _text(s, "namespace", d.namespace)
    if namespace and not ROS_NAMESPACE.fullmatch(namespace):
        raise s.err(
            "namespace",
            "must be /name or /a/b, each name of ASCII letters, digits and _ not starting "
            f"with a digit (e.g. /robot1), got {shown(namespace)}",
        )
    if len(namespace.rstrip("/")) > ROS_NAMESPACE_MAX:
        raise s.err("namespace", f"must be at most {ROS_NAMESPACE_MAX} characters (ROS 2's "
                                 f"limit), got {len(namespace.rstrip('/'))}")  # fmt: skip
    for fixed in FIXED_TOPICS:  # the topics put under it that the config does not name
        if len(namespace.rstrip("/") + fixed) > ROS_TOPIC_MAX:
            raise s.err("namespace", f"{fixed} under it would be over ROS 2's {ROS_TOPIC_MAX} "
                                     "characters: a shorter namespace")  # fmt: skip

    def topic(key: str, default: str) -> str:
        v = _text(s, key, default)
        if not ROS_TOPIC.fullmatch(v):
            raise s.err(key, "must be a ROS 2 topic name: names of ASCII letters, digits "
                             "and _ not starting with a digit, joined by single / (no "
                             f"trailing /, ~ or {{}}), got {shown(v)}")  # fmt: skip
        full = namespace.rstrip("/") + "/" + v.lstrip("/")  # (ros2conv.topic; one / at most)
        if len(full) > ROS_TOPIC_MAX:
            raise s.err(key, f"its full name {shown(full[:40] + '...')} is {len(full)} "
                             f"characters, over ROS 2's {ROS_TOPIC_MAX}")  # fmt: skip
        return v

    def frame(key: str, default: str) -> str:
        v = _text(s, key, default)
        if not ROS_FRAME.fullmatch(v):
            lead = " (tf2 refuses a leading /)" if v.startswith("/") else ""
            raise s.err(key, "must be a frame id of ASCII letters, digits and _, parts "
                             f"joined by single /{lead}, got {shown(v)}")  # fmt: skip
        return v

    domain = s.integer("domain_id", minimum=0) if s.has("domain_id") else d.domain_id
    if domain is not None and domain > 232:
        raise s.err("domain_id", f"must be between 0 and 232 (ROS 2's range), got {domain}")
    cfg = Ros2Config(
        domain_id=domain,
        namespace=namespace.rstrip("/"),
        odom_topic=topic("odom_topic", d.odom_topic),
        tf_topic=topic("tf_topic", d.tf_topic),
        diagnostics_topic=topic("diagnostics_topic", d.diagnostics_topic),
        odom_frame=frame("odom_frame", d.odom_frame),
        base_frame=frame("base_frame", d.base_frame),
        map_frame=frame("map_frame", d.map_frame),
        publish_tf=s.boolean("publish_tf", d.publish_tf),
        publish_map_tf=s.boolean("publish_map_tf", d.publish_map_tf),
        diagnostics=s.boolean("diagnostics", d.diagnostics),
        counts=s.boolean("counts", d.counts),
        stamps=s.choice("stamps", STAMPS, d.stamps),
        node_name=_text(s, "node_name", d.node_name),
        optional=s.boolean("optional", d.optional),
        initialpose=s.boolean("initialpose", d.initialpose),
    )
    if not ROS_NODE_NAME.fullmatch(cfg.node_name):
        raise s.err("node_name", "must be a ROS 2 node name (letters, digits and _, not "
                    f"starting with a digit), got {shown(cfg.node_name)}")  # fmt: skip
    enabled = s.boolean("enabled", True)
    s.finish()
    return cfg if enabled else None
