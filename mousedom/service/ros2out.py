"""The daemon's ROS 2 output: nav_msgs/Odometry, TF and diagnostics over DDS, no ROS needed.

ROS 2's middleware is DDS; ``cyclonedds`` (the ``ros2`` extra) speaks it.  ROS 2's
conventions on the wire (what rmw_cyclonedds does): a topic ``/odom`` is the DDS topic
``rt/odom``, the type ``nav_msgs/msg/Odometry`` is ``nav_msgs::msg::dds_::Odometry_`` in
XCDR1, each writer's USER_DATA carries the type's REP-2011 hash as ROS 2 since Iron does,
the domain is ``$ROS_DOMAIN_ID`` (0 if unset) unless the config names one.  QoS as
rclcpp's defaults for these topics: reliable, volatile, keep last 10 (/odom, /diagnostics)
and keep last 100 (/tf, as tf2's TransformBroadcaster).

What is published is ``ros2conv``'s: odom -> base_link that never jumps (REP-105), the
map -> odom correction that the socket's reset and fix move, one DiagnosticStatus per
sensor from the fault-tolerant fusion's health.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from typing import Any
from xml.sax.saxutils import quoteattr

from mousedom.config import MouseConfig, Ros2Config
from mousedom.errors import UserError
from mousedom.fusion.posebatch import PoseRow
from mousedom.service import ros2cdr as cdr
from mousedom.service import ros2conv as conv
from mousedom.service import ros2msgs as msgs
from mousedom.service.output import Output, PerMouse
from mousedom.service.rostime import system_lead

log = logging.getLogger(__name__)

# ROS 2's default middleware, Fast DDS (RTPS vendor id 1.15), builds the XTypes TypeObjects
# of ROS messages with collection element flags 0 (no try-construct bit) where cyclonedds
# sets TRY_CONSTRUCT1: every type holding an array or a sequence (Odometry's covariance[36],
# DiagnosticArray's status[], TFMessage's transforms[]) gets another TypeIdentifier on each
# side; Cyclone then asks Fast DDS for its types over type lookup, rejects them as invalid
# (element flags 0) or cannot resolve them, and never matches the ROS 2 reader.  Fast DDS
# ignores other vendors' type information and matches on the type name: this makes Cyclone
# do the same with Fast DDS's (a user's $CYCLONEDDS_URI, read after it, may say otherwise).
DDS_COMPAT = (
    '<CycloneDDS><Domain id="any"><Compatibility>'
    "<IgnoreTypeInformation>1.15</IgnoreTypeInformation>"
    "</Compatibility></Domain></CycloneDDS>"
)


def dds_config(environ: dict[str, str] | None = None) -> str:
    """The Cyclone DDS configuration of our domain: what ROS 2's discovery variables ask
    (as rmw_cyclonedds_cpp reads them), DDS_COMPAT, then the user's $CYCLONEDDS_URI (a list
    of files and XML fragments, the later overriding the earlier)."""
    env = os.environ if environ is None else environ
    scope = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper()
    if not scope and env.get("ROS_LOCALHOST_ONLY", "").strip() == "1":
        scope = "LOCALHOST"  # the older variable, as rmw reads it when the range is unset
    peers = [p.strip() for p in env.get("ROS_STATIC_PEERS", "").split(";") if p.strip()]
    parts = []
    if scope in ("LOCALHOST", "OFF") or peers:
        # ROS nodes limited to this host find their peers by unicast on the well-known
        # ports (7410 + 2 * index in domain 0): take one, and announce to theirs.  OFF:
        # no automatic discovery at all, only the static peers.
        localhost = scope == "LOCALHOST"
        unicast = scope in ("LOCALHOST", "OFF")
        xml = ""
        if unicast:
            # LOCALHOST: the loopback interface only, so that the locators we announce are
            # 127.0.0.1, where peers limited to this host (Fast DDS's well-known unicast
            # ports) look for us; on a host with a network Cyclone would otherwise pick it.
            lo = '<Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
            xml = (f"<General>{lo if localhost else ''}"
                   "<AllowMulticast>false</AllowMulticast></General>")  # fmt: skip
        xml += ("<Discovery><ParticipantIndex>auto</ParticipantIndex>"
                "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex><Peers>")  # fmt: skip
        for peer in (["localhost"] if localhost else []) + peers:
            xml += f"<Peer address={quoteattr(peer)}/>"
        xml += "</Peers></Discovery>"
        parts.append(f'<CycloneDDS><Domain id="any">{xml}</Domain></CycloneDDS>')
    parts.append(DDS_COMPAT)
    user = env.get("CYCLONEDDS_URI", "").strip()
    if user:
        parts.append(user)
    return ",".join(parts)


INSTALL_HINT = (
    "the ROS 2 output needs cyclonedds, which is not installed: "
    "pip install 'mousedom[ros2]' (or: pip install cyclonedds mcap mcap-ros2-support)"
)


def require() -> None:
    try:
        import cyclonedds.domain  # noqa: F401
    except ImportError:
        raise UserError(INSTALL_HINT) from None


def domain_id(cfg: Ros2Config, environ: dict[str, str] | None = None) -> int:
    """The config's domain, else $ROS_DOMAIN_ID, else 0 (as ROS 2 does)."""
    if cfg.domain_id is not None:
        return cfg.domain_id
    raw = (os.environ if environ is None else environ).get("ROS_DOMAIN_ID", "").strip()
    if not raw:
        return 0
    if not raw.isdigit() or int(raw) > 232:
        raise UserError(f"ROS_DOMAIN_ID={raw!r}: must be a number from 0 to 232")
    return int(raw)


class Ros2Unavailable(UserError):
    """No DDS participant could be made: the ROS 2 output cannot start (the message says
    why and where docs/ros2.md says what to do)."""


DOCS = 'docs/ros2.md, "When the ROS 2 output cannot start"'


@contextlib.contextmanager
def _dds_stderr() -> Iterator[Callable[[], str]]:
    """Catch what Cyclone DDS writes to file descriptor 2 (its own C code says why it
    failed: a config error, no interface) while the participant is made; yields a function
    giving that text.  What it wrote is passed on to stderr afterwards, as it would be,
    unless the block failed: then the one error line that names the cause carries it.
    Called where a participant is made (the daemon's start, a ROS 2 gyro joined again):
    fd 2 is the process's, so what another thread writes meanwhile is passed on after."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        yield lambda: ""
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        failed = True
        try:
            yield lambda: _read_back(tmp)
            failed = False
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            text = _read_back(tmp)
            if failed:  # the error message carries Cyclone's lines; the rest go on
                text = "".join(ln for ln in text.splitlines(keepends=True)
                               if not _CYCLONE_LINE.match(ln))  # fmt: skip
            if text:
                sys.stderr.write(text)


def _read_back(tmp: Any) -> str:
    tmp.seek(0)
    text = tmp.read(1 << 20).decode("utf-8", "replace")
    return text + ("\n(... cut at 1 MiB)" if tmp.read(1) else "")


# Cyclone's lines: "<time> [<domain>] <thread>: <message>"; anything else on fd 2 meanwhile
# is another thread's (the daemon's log), not a reason
_CYCLONE_LINE = re.compile(r"\s*\d+\.\d+ \[-?\d+\]\s+[^:]*: ")


def _why_no_participant(domain: int, said: str, what: str = "ROS 2 output") -> str:
    lines = [ln.split(": ", 1)[-1].strip() for ln in said.splitlines() if _CYCLONE_LINE.match(ln)]
    cause = "; ".join(dict.fromkeys(lines)) or "Cyclone DDS gave no reason"
    hint = ""
    if "interfaces" in cause:
        hint = (" (no usable network interface: under systemd, the unit's network "
                "restrictions need the ros2 drop-in)")  # fmt: skip
    elif "config" in cause:
        hint = " (check CYCLONEDDS_URI)"
    return f"{what}: no DDS participant on domain {domain}: {cause}{hint}; see {DOCS}"


# The Domain objects this process configured, by domain id, kept while it lives: Cyclone
# reads a domain's configuration when its first entity is made, and deleting the Domain
# object would delete every participant in it (the output's and the gyro's share one).
_DOMAINS: dict[int, Any] = {}


def withdraw(graph: Any) -> None:
    """Take a closing node off ROS 2's graph (``NodeAnnouncer.withdraw``); a DDS error then
    is logged, not raised: the node is going anyway, and its lease ends it."""
    from cyclonedds.core import DDSException

    try:
        graph.withdraw()
    except DDSException as e:
        log.warning("could not take node %s off the ROS 2 graph: %s", graph.name, e)


def participant(domain: int, what: str = "ROS 2 output") -> Any:
    """A DDS participant on ``domain``, the domain configured as ``dds_config`` says the
    first time; Ros2Unavailable saying why (``what`` wanted it) where none can be made."""
    require()
    from cyclonedds.core import DDSException
    from cyclonedds.domain import Domain, DomainParticipant

    made = None
    with _dds_stderr() as said:
        if domain not in _DOMAINS:
            try:
                made = Domain(domain, dds_config())
            except DDSException:  # a bad configuration, no interface, or made elsewhere
                refused = [ln for ln in said().splitlines() if _CYCLONE_LINE.match(ln)]
                if any("config:" in ln for ln in refused):  # Cyclone refused our config
                    raise Ros2Unavailable(_why_no_participant(domain, said(), what)) from None
        try:
            part = DomainParticipant(domain)
        except DDSException:
            raise Ros2Unavailable(_why_no_participant(domain, said(), what)) from None
    if domain not in _DOMAINS:
        _DOMAINS[domain] = made
        if made is None:  # the participant joined a domain another part of us made
            log.warning(
                "DDS domain %d existed already in this process: its configuration "
                "stands (ROS 2 nodes on Fast DDS may not match our topics)",
                domain,
            )
    return part


class _RawWriter:
    """A DataWriter fed CDR bytes: cyclonedds' ``write`` wants an object of the topic's
    type and calls its ``serialize``; this hands it one whose ``serialize`` is the bytes."""

    def __init__(self, writer: Any, cls: type) -> None:
        self.writer = writer

        class Serialized(cls):
            def serialize(self, *args: Any, **kwargs: Any) -> bytes:  # noqa: ARG002
                return self.cdr

        self._cls = Serialized

    def write(self, data: bytes) -> None:
        sample = object.__new__(self._cls)
        sample.cdr = data
        self.writer.write(sample)


class Ros2Output(PerMouse, Output):
    """One DDS participant and its writers; ``publish`` per window (see the module)."""

    def __init__(
        self,
        cfg: Ros2Config,
        sensors: tuple[str, ...],
        rate_hz: float,
        mice: tuple[MouseConfig, ...] = (),
    ) -> None:
        """``mice``: their mounts go on /tf_static (base frame -> <mouse>_mouse)."""
        require()
        from cyclonedds.pub import DataWriter
        from cyclonedds.qos import Policy, Qos
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        self.cfg, self.sensors, self.rate = cfg, sensors, rate_hz
        self.domain = domain_id(cfg)
        self.rep = conv.Rep105()
        types = msgs.idl_types()
        self.participant: Any = participant(self.domain)

        def writer(topic: str, name: str, depth: int):
            qos = Qos(
                Policy.Reliability.Reliable(duration(milliseconds=100)),
                Policy.Durability.Volatile,
                Policy.History.KeepLast(depth),
            )
            t = Topic(self.participant, "rt" + conv.topic(cfg, topic), types[name], qos=qos)
            hashed = Qos(*qos, Policy.Userdata(f"typehash={msgs.TYPE_HASHES[name]};".encode()))
            return _RawWriter(DataWriter(self.participant, t, hashed), types[name])

        self.odom = writer(cfg.odom_topic, msgs.ODOMETRY, 10)
        self.tf = (
            writer(cfg.tf_topic, msgs.TF, 100) if cfg.publish_tf or cfg.publish_map_tf else None
        )
        self.diag = writer(cfg.diagnostics_topic, msgs.DIAGNOSTICS, 10) if cfg.diagnostics else None
        self.counts = []
        if cfg.counts:
            self.counts = [writer(conv.counts_topic(s), msgs.COUNTS, 10) for s in sensors]
        # Each mouse's mount, once, kept for late joiners (as tf2's static broadcaster):
        # RViz draws the mice where the config puts them.
        self.tf_static = None
        if mice:
            static = Qos(
                Policy.Reliability.Reliable(duration(milliseconds=100)),
                Policy.Durability.TransientLocal,
                Policy.History.KeepLast(1),
            )
            topic = Topic(self.participant, "rt" + conv.topic(cfg, "/tf_static"), types[msgs.TF],
                          qos=static)  # fmt: skip
            hashed = Qos(
                *static, Policy.Userdata(f"typehash={msgs.TYPE_HASHES[msgs.TF]};".encode())
            )
            self.tf_static = DataWriter(self.participant, topic, hashed)
            st = conv.stamp(time.monotonic(), self._offset())
            mounts = [conv.mount_transform(cfg.base_frame, m.name, m.mount.x, m.mount.y,
                                           m.mount.yaw, m.flip, st) for m in mice]  # fmt: skip
            self.tf_static.write(msgs.build(msgs.TF, {"transforms": mounts}))
        # RViz's "2D Pose Estimate": an absolute pose in the map frame (allowed by config)
        self.initialpose = None
        if cfg.initialpose:
            from cyclonedds.sub import DataReader

            rq = Qos(
                Policy.Reliability.Reliable(duration(milliseconds=100)),
                Policy.Durability.Volatile,
                Policy.History.KeepLast(10),
            )
            topic = Topic(self.participant, "rt" + conv.topic(cfg, "/initialpose"),
                          types[msgs.INITIALPOSE], qos=rq)  # fmt: skip
            self.initialpose = DataReader(self.participant, topic, rq)
        # The node in the ROS 2 graph (ros2 node list): its writers are ours.
        from mousedom.service.ros2graph import NodeAnnouncer

        graph = NodeAnnouncer(self.participant, cfg.node_name, cfg.namespace or "/")
        self.graph: NodeAnnouncer | None = graph  # (None once closed)
        mine = [w.writer for w in (self.odom, self.tf, self.diag, *self.counts) if w is not None]
        if self.tf_static is not None:
            mine.append(self.tf_static)
        graph.announce([self.initialpose] if self.initialpose is not None else [], mine)
        self.sent = 0
        # CDR packed per window (ros2cdr: byte for byte what cyclonedds would serialise)
        self.odom_cdr = cdr.OdometryCdr(cfg.odom_frame, cfg.base_frame)
        pairs = []
        if cfg.publish_tf:
            pairs.append((cfg.odom_frame, cfg.base_frame))
        if cfg.publish_map_tf:
            pairs.append((cfg.map_frame, cfg.odom_frame))
        self.tf_cdr = cdr.TfCdr(pairs)
        self.counts_cdr = [
            cdr.Vector3StampedCdr(conv.mouse_frame(s, cfg.base_frame)) for s in sensors
        ]
        log.info("ROS 2 output on domain %d: %s (%s -> %s)", self.domain,
                 conv.topic(cfg, cfg.odom_topic), cfg.odom_frame, cfg.base_frame)  # fmt: skip

    def _offset(self) -> float:
        # The system clock's lead over the monotonic one, read per message: NTP may step it.
        return system_lead() if self.cfg.stamps == "system" else 0.0

    def publish(self, row: PoseRow) -> None:
        """One window (a PoseRow): Odometry, and TF where enabled."""
        cfg = self.cfg
        st = conv.stamp(row.t, self._offset())
        odom = self.rep.odom_pose((row.x, row.y, row.theta))
        msg = conv.odometry(cfg, st, odom, self.rep.odom_cov(row.cov, odom), row, self.rate)
        self.odom.write(self.odom_cdr.encode(st, msg))
        if self.tf is not None:
            tfs = []
            if cfg.publish_tf:
                tfs.append(conv.transform(cfg.odom_frame, cfg.base_frame, st, odom))
            if cfg.publish_map_tf:
                tfs.append(conv.transform(cfg.map_frame, cfg.odom_frame, st, self.rep.map_odom))
            self.tf.write(self.tf_cdr.encode(st, tfs))
        if not self.per_mouse:  # (the mice changed: output.PerMouse)
            self.sent += 1
            return
        for w, enc, name, (cx, cy) in zip(self.counts, self.counts_cdr, self.sensors,
                                          row.counts, strict=False):  # fmt: skip
            w.write(enc.encode(st, conv.counts(st, name, cx, cy, cfg.base_frame)))
        self.sent += 1

    def fixes(self) -> list[conv.Pose2]:
        """The poses /initialpose asked for since the last call (map frame: x, y, yaw);
        one in another frame, or not finite, or beyond what a pose may be, is logged and
        left out."""
        if self.initialpose is None:
            return []
        out = []
        for m in self.initialpose.take(N=16):
            frame = m.header.frame_id
            p, q = m.pose.pose.position, m.pose.pose.orientation
            yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
            pose = (float(p.x), float(p.y), yaw)
            if frame not in ("", self.cfg.map_frame):
                log.warning("/initialpose in frame %r ignored: it must be %r", frame,
                            self.cfg.map_frame)  # fmt: skip
            elif not all(math.isfinite(v) and abs(v) <= 1e7 for v in pose):
                log.warning("/initialpose %r ignored: not a finite pose", pose)
            else:
                out.append(pose)
        return out

    def moved(self, before: conv.Pose2, after: conv.Pose2) -> None:
        """The socket's reset or fix moved the pose: map -> odom takes the jump."""
        self.rep.moved(before, after)

    def sources(self, messages: list[dict[str, Any]], t: float) -> None:
        """The SOURCE messages (once a second) as /diagnostics."""
        if self.diag is not None:
            st = conv.stamp(t, self._offset())
            self.diag.write(cdr.diagnostics(st, conv.diagnostics(st, messages)))

    def close(self) -> None:
        if self.graph is not None:
            withdraw(self.graph)
        self.graph = self.tf_static = self.initialpose = None
        self.odom = self.tf = self.diag = None
        self.counts = []
        self.participant = None
