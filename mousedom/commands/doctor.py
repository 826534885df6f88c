"""``mousedom doctor``: does it work, and if not, what to do.

One line per finding, in the order a rig is brought up: the config (found, parses, its
warnings and notes), the devices (the input directory, which device each mouse's rule
matches, permissions and the group to join), the calibration file, the daemon's socket
(connect, then a short read: POSE rate against the config's, each mouse's state, learnt
scale warnings), the ROS 2 output (can a DDS participant start; with a live daemon, does
its odometry arrive), the Prometheus endpoint where the config asks for one (the extra
installed, and the running daemon serving it), and the core in use.  Each line is OK,
WARN or FAIL, and a WARN or FAIL says what to do.  Exit 1 on any FAIL; warnings alone exit 0.

Nothing here re-implements a rule: it asks the parts that own them (``load_config`` and
its plausibility warnings, ``observability.blind_spots``, ``sources.discovery`` and
``list``'s matching, the ``Client`` and its ``access_hint``, ``service.ros2out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import grp
import importlib
import importlib.machinery
import importlib.util
import json
import math
import os
import re
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mousedom import invocation, safeyaml
from mousedom.commands import _options as options
from mousedom.config import DEFAULT_CONFIG_PATH, Config, ConfigError, MouseConfig, load_config
from mousedom.errors import UserError

OK, WARN, FAIL = "OK", "WARN", "FAIL"
RATE_TOLERANCE = 0.1  # a POSE rate within 10 % of rate_hz is the configured one
PARTICIPANT_TIMEOUT_S = 5.0  # a DDS participant starts in ~0.2 s; more means it is stuck
PACKAGE = Path(__file__).resolve().parents[1]  # this mousedom, wherever it was imported


@dataclass
class Check:
    """One line of the report: which check, its verdict, what was found, what to do."""

    check: str  # config, devices, calibration, daemon, ros2, metrics, core
    status: str  # OK, WARN or FAIL
    message: str
    hint: str | None = None
    data: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        if not d["data"]:
            del d["data"]
        return d


class Lines(list):
    """The lines of one check, added by verdict."""

    def __init__(self, check: str) -> None:
        super().__init__()
        self.check = check

    def ok(self, message: str, **data: Any) -> None:
        self.append(Check(self.check, OK, message, None, data))

    def warn(self, message: str, hint: str | None, **data: Any) -> None:
        self.append(Check(self.check, WARN, message, hint, data))

    def fail(self, message: str, hint: str | None, **data: Any) -> None:
        self.append(Check(self.check, FAIL, message, hint, data))


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "doctor",
        help="check that it all works (config, devices, daemon, ROS 2) and say what to do",
        description="Check, in order: the rig config; the input devices and which one each "
        "mouse's rule matches (and the group to join when one is closed to this user); the "
        "calibration file; the running daemon (its POSE rate, each mouse's state); the ROS 2 "
        "output; the core in use. Each line says OK, WARN or FAIL and what to do. Exit 1 if "
        "anything FAILs.",
    )
    p.add_argument(
        "-c",
        "--config",
        metavar="RIG.yaml",
        help=f"the rig config (default {DEFAULT_CONFIG_PATH}, as for run; if that does not "
        "exist, the one the running daemon reports)",
    )
    p.add_argument("--socket", metavar="PATH", help="daemon socket (default: found as run does)")
    p.add_argument(
        "--timeout",
        type=float,
        default=1.5,
        metavar="S",
        help="how long to read the running daemon, and to listen for its ROS 2 odometry "
        "(default 1.5)",
    )
    p.add_argument("--json", action="store_true", help="the checks as a JSON document")
    options.add_root(p)
    p.set_defaults(func=run)


# --------------------------------------------------------------------------- 1. config


@dataclass
class Found:
    """The config doctor checks, how it was found, and what loading it gave."""

    path: str | None
    how: str = ""  # "--config", "the daemon's default", "the running daemon's"
    config: Config | None = None
    calibration_error: str | None = None  # the config is fine, its calibration file is not


def check_config(found: Found) -> list[Check]:
    """Found, parses (each mouse with a source), and what check-config warns of and notes."""
    from mousedom.observability import blind_spots

    lines = Lines("config")
    demo = invocation.command("run", "--demo")
    if found.path is None:
        lines.fail(
            f"no config: {DEFAULT_CONFIG_PATH} (the daemon's default) does not exist, and no "
            "daemon answers to say which one it runs",
            f"give --config RIG.yaml (config/examples/ has rigs to start from), or try the "
            f"demo: {demo}",
        )
        return lines
    where = f"{found.path} ({found.how})"
    try:
        cfg = load_config(found.path)
    except ConfigError as e:
        text = str(e)
        if "config file not found" in text:
            lines.fail(text, f"give --config RIG.yaml, or try the demo: {demo}")
        elif not text.startswith(found.path) and _loads_without_calibration(found.path):
            lines.ok(f"{where}: parses; its calibration file does not (below)")
            found.calibration_error = text
        elif _loads_without_sources(found.path):
            lines.fail(text, "the daemon needs a source for each mouse (evdev, serial or "
                       "replay): this rig is for captures and calibration only")  # fmt: skip
        else:
            lines.fail(text, "fix what the message names (`mousedom check-config` says the same)")
        return lines
    found.config = cfg
    n = len(cfg.mice)
    lines.ok(
        f"{where}: {cfg.model} model, {cfg.rate_hz:g} Hz, {n} {'mouse' if n == 1 else 'mice'} "
        f"({', '.join(cfg.names)})",
        path=cfg.path,
        rate_hz=cfg.rate_hz,
    )
    for w in cfg.warnings:  # values that look like the wrong unit (mousedom.plausible)
        lines.warn(w, "correct it if it is not what you meant (if it is, nothing to do)")
    if cfg.robust.enabled:  # what the layout hides from the fault test, as check-config notes
        mounts = [(m.name, m.mount.x, m.mount.y) for m in cfg.mice]
        r = cfg.robust
        for note in blind_spots(cfg.model, mounts, r.relative_noise, r.false_alarm):
            lines.ok(f"note: {note}")
    return lines


def _loads_without_sources(path: str) -> bool:
    try:
        load_config(path, need_sources=False)
    except UserError:
        return False
    return True


def _loads_without_calibration(path: str) -> bool:
    """Whether the error came from the calibration file: the config's text, its
    ``calibration:`` line left out, loads."""
    try:
        lines = safeyaml.read_text(path).splitlines(keepends=True)
        text = "".join(ln for ln in lines if not ln.startswith("calibration:"))
        from mousedom.config import parse_config

        parse_config(text, path)
    except (UserError, OSError, UnicodeDecodeError):
        return False
    return True


# --------------------------------------------------------------------------- 2. devices


def _group_of(path: str) -> str:
    try:
        gid = os.stat(path).st_gid
    except OSError:
        return "?"
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def _join(group: str) -> str:
    return f"join group '{group}' (sudo usermod -aG {group} $USER, then log in again)"


def check_devices(cfg: Config | None, root: str | None) -> list[Check]:
    """The input directory, then each mouse: the device it is, or why there is none."""
    from mousedom.commands.list import config_matches
    from mousedom.sources.discovery import is_stream, join_group_hint, paths_for_root, scan

    lines = Lines("devices")
    paths = paths_for_root(root)
    result = scan(paths)
    where = paths.dev_input
    mice = cfg.mice if cfg else ()
    streams = {m.name for m in mice if m.evdev and m.evdev.path and is_stream(m.evdev.path)}
    evdev = [m.name for m in mice if m.evdev and m.name not in streams]
    if not result.present:
        container = (
            "is this a container? pass the devices through (docker/podman run --device "
            "/dev/input/eventN), or replay captures (`mousedom replay`, "
            f"`{invocation.command('run', '--demo')}`)"
        )
        if evdev:
            lines.fail(f"no {where}: this machine has no input devices, so the evdev mice "
                       f"({', '.join(evdev)}) cannot be found", container)  # fmt: skip
        elif cfg is None:
            lines.warn(f"no {where} on this machine", container)
        else:
            lines.ok(f"no {where} on this machine (not needed: no mouse of this config is an "
                     "evdev device)")  # fmt: skip
    else:
        locked = [d for d in result.devices if not d.readable]
        n = len(result.devices)
        s = "s" if result.nodes != 1 else ""
        msg = f"{where}: {result.nodes} input node{s}, {n} with REL_X and REL_Y"
        if locked:
            groups = sorted({d.group or "input" for d in locked})
            msg += f"; {len(locked)} closed to this user (group {', '.join(groups)})"
            if cfg is not None:  # each evdev mouse's line says whether it is one of those
                lines.ok(msg)
            else:
                lines.warn(msg, f"{_join(groups[0])}, or install udev/99-mousedom.rules")
        elif n == 0 and (cfg is None or evdev):
            lines.warn(msg + ": no mouse plugged in", "plug the mice in (`mousedom list`)")
        else:
            lines.ok(msg)
    if cfg is None:
        return lines
    by_node = {d.node: d for d in result.devices}
    matches = config_matches(cfg.path, result) if result.present and evdev else {}
    ports: dict[str, str] = {}
    for m in mice:
        if m.name in streams:
            lines.ok(f"{m.name} -> {m.evdev.path} (a FIFO: a stream of input events)")
        elif m.evdev:
            if not result.present:
                continue  # said once above
            r = matches.get(m.name, {})
            node = r.get("node")
            dev = by_node.get(node) if node else None
            label = f"{node} {dev.name!r}" if dev and dev.name else str(node)
            if r.get("error"):
                lines.fail(f"{m.name}: {r['error']}", "plug it in, or change its rule: `mousedom "
                           "list` shows each device and a rule that names it")  # fmt: skip
            elif dev is not None and not dev.readable:
                lines.fail(f"{m.name} -> {label}: closed to this user", join_group_hint(dev),
                           mouse=m.name, node=node, group=dev.group)  # fmt: skip
            else:
                lines.ok(f"{m.name} -> {label}", mouse=m.name, node=node)
        elif m.serial:
            _check_serial(lines, m, ports)
        elif m.replay:
            if os.path.isfile(m.replay):
                lines.ok(f"{m.name} -> replay {m.replay}")
            else:
                lines.fail(f"{m.name}: replay {m.replay}: capture file not found",
                           "record one (`mousedom record`) or fix the path (relative to the "
                           "config)")  # fmt: skip
    return lines


def _check_serial(lines: Lines, m: MouseConfig, ports: dict[str, str]) -> None:
    """An ADNS-3080 board's serial port: there, and open to this user.  Not opened here:
    opening toggles DTR, which resets many boards."""
    port = m.serial.port
    if "://" in port:  # a pyserial URL (socket://, loop://): nothing to look at here
        lines.ok(f"{m.name} -> serial {port} (a pyserial URL)")
        return
    real = os.path.realpath(port)
    if real in ports:
        lines.fail(f"{m.name}: serial {port} is {ports[real]}'s port too",
                   "one board per port: give each mouse its own")  # fmt: skip
        return
    ports[real] = m.name
    if not os.path.exists(port):
        lines.fail(f"{m.name}: serial port {port} does not exist",
                   "plug the ADNS-3080 board in (`ls /dev/serial/by-id/` names it); in a "
                   "container, pass it through (--device)")  # fmt: skip
    elif not os.access(port, os.R_OK | os.W_OK):
        group = _group_of(port)
        lines.fail(f"{m.name}: serial port {port}: permission denied", _join(group),
                   mouse=m.name, port=port, group=group)  # fmt: skip
    else:
        lines.ok(f"{m.name} -> serial {port}")


# --------------------------------------------------------------------------- 3. calibration


def check_calibration(found: Found) -> list[Check]:
    lines = Lines("calibration")
    cfg = found.config
    if found.calibration_error:
        lines.fail(found.calibration_error, "fix the file, or write it again (`mousedom "
                   "calibrate ... --write`): the daemon does not start with it")  # fmt: skip
    if cfg is None:
        return lines
    if not cfg.calibration:
        lines.ok("none named (the config's CPI and mounts are used as written)")
        return lines
    path = cfg.calibration
    if not os.path.exists(path):
        lines.warn(f"{path}: named, not written yet: the config's own CPI and mounts are used",
                   "calibrate the rig (docs/calibration.md); `mousedom calibrate cpi ... "
                   "--write` writes this file")  # fmt: skip
        return lines
    # load_config has read and applied it (it refuses the config otherwise): say what it holds.
    try:
        doc = safeyaml.load(safeyaml.read_text(path)) or {}
        covered = {str(k): sorted(v or {}) for k, v in (doc.get("mice") or {}).items()}
    except (OSError, ValueError, AttributeError, UnicodeDecodeError):
        covered = {}
    held = ", ".join(f"{n} ({'/'.join(keys) or 'nothing'})" for n, keys in covered.items())
    lines.ok(f"{path}: read and applied: {held or 'no mouse in it'}", path=path)
    left = [n for n in cfg.names if n not in covered]
    if left and covered:
        lines.warn(f"{', '.join(left)}: not in the calibration file (the config's values stand)",
                   "calibrate them too, if the rig has changed")  # fmt: skip
    return lines


# --------------------------------------------------------------------------- 4. the daemon


@dataclass
class Live:
    """What a short read of the daemon gave."""

    path: str
    connected: bool = False
    error: Check | None = None  # why there is nothing to read
    version: dict[str, Any] = field(default_factory=dict)
    status: dict[str, Any] = field(default_factory=dict)
    sources: dict[str, dict[str, Any]] = field(default_factory=dict)  # the latest of each
    poses: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0


def socket_path(cfg: Config | None, given: str | None) -> str:
    """The socket the daemon of this config listens on, found as ``run`` and ``watch`` do."""
    from mousedom.client import find_socket

    if given:
        return given
    if cfg is not None and cfg.server.socket:
        return cfg.server.socket
    return find_socket()


def read_live(path: str, timeout: float, config: str | None = None) -> Live:
    """Connect, ask for the STATUS, and read POSE and SOURCE lines for ``timeout`` s."""
    from mousedom.client import Client, ClientError, access_hint

    live = Live(path)
    command = invocation.command("run", "--config", config or "RIG.yaml")
    start = f"start it: `{command}` (or `systemctl start mousedom`)"
    if not os.path.exists(path):
        live.error = Check("daemon", WARN, f"no daemon: nothing at {path}",
                           f"{start}, or give --socket PATH")  # fmt: skip
        return live
    try:
        client = Client(path, timeout=timeout + 1.0)
    except ClientError as e:
        code = getattr(e, "errno", None)
        if code in (errno.EACCES, errno.EPERM):
            # "permission denied: the socket is mode ..., owner ..., group ...; to watch ..."
            what, _, todo = access_hint(path).partition("; ")
            live.error = Check("daemon", FAIL, f"{path}: the daemon runs, but {what}",
                               todo or None, {"socket": path})  # fmt: skip
        elif code == errno.ECONNREFUSED:
            live.error = Check("daemon", FAIL, f"{path}: a socket, but no daemon listens (it "
                               "stopped without removing it?)", f"{start}; `journalctl -u "
                               "mousedom` says why it stopped")  # fmt: skip
        else:
            live.error = Check("daemon", FAIL, str(e), "give the daemon's socket (--socket)")
        return live
    live.connected = True
    live.version = client.version
    t0 = time.monotonic()
    try:
        try:
            live.status = client.command("status")
        except ClientError:
            live.status = {}
        end = t0 + timeout
        for msg in client.messages():
            if msg.get("class") == "POSE":
                live.poses.append(msg)
            left = end - time.monotonic()
            if left <= 0:
                break
            client.sock.settimeout(left)
    except (OSError, ValueError):  # no next line in time (a stuck daemon), or it went away
        pass
    finally:
        live.seconds = time.monotonic() - t0
        live.sources = dict(client.sources)
        client.close()
    return live


def pose_rate(poses: list[dict[str, Any]]) -> float | None:
    """POSEs per second, from their own stamps (not from when they arrived)."""
    ts = [p["t"] for p in poses if isinstance(p.get("t"), (int, float))]
    if len(ts) < 3 or ts[-1] <= ts[0]:
        return None
    return (len(ts) - 1) / (ts[-1] - ts[0])


def check_daemon(live: Live, cfg: Config | None, timeout: float) -> list[Check]:
    lines = Lines("daemon")
    if live.error is not None:
        lines.append(live.error)
        return lines
    v, st = live.version, live.status
    sensors = [str(s) for s in v.get("sensors") or []]
    up = f", up {st['uptime']:.0f} s" if isinstance(st.get("uptime"), (int, float)) else ""
    lines.ok(f"mousedom {v.get('release')} at {live.path}: {v.get('model')} model, "
             f"{v.get('rate_hz')} Hz, sensors {', '.join(sensors)}{up}",
             socket=live.path, version=v, config=st.get("config"))  # fmt: skip
    expected = v.get("rate_hz")
    if cfg is not None:
        differs = []
        if sensors != list(cfg.names):
            differs.append(f"sensors {', '.join(sensors)} (the config: {', '.join(cfg.names)})")
        if v.get("model") != cfg.model:
            differs.append(f"model {v.get('model')} (the config: {cfg.model})")
        if v.get("rate_hz") != cfg.rate_hz:
            differs.append(f"{v.get('rate_hz')} Hz (the config: {cfg.rate_hz:g} Hz)")
        if differs:
            runs = f" ({st['config']})" if st.get("config") else ""
            lines.warn(f"the daemon runs another config{runs}: {'; '.join(differs)}",
                       "check the daemon's config (--config), or reload the daemon with this "
                       "one (`systemctl reload mousedom`, SIGHUP)")  # fmt: skip
        else:
            expected = cfg.rate_hz
    rate = pose_rate(live.poses)
    n = len(live.poses)
    if not n:
        lines.fail(f"connected, but no POSE in {live.seconds:.1f} s", "the daemon is stuck or "
                   "overloaded: `journalctl -u mousedom`, or run it in the foreground "
                   "with -v")  # fmt: skip
    elif rate is None:
        lines.warn(f"{n} POSE in {live.seconds:.1f} s: too few to measure the rate",
                   f"read longer: --timeout {max(2 * timeout, 5.0):g}")  # fmt: skip
    else:
        text = f"POSE {rate:.1f} Hz (rate_hz {expected:g}), {n} in {live.seconds:.1f} s"
        d = {"pose_rate_hz": round(rate, 2), "rate_hz": expected, "poses": n}
        if isinstance(expected, (int, float)) and abs(rate - expected) > RATE_TOLERANCE * expected:
            lines.warn(text + ": not the configured rate", "the machine may be too busy "
                       "(docs/performance.md): lower rate_hz, or see what else runs",
                       **d)  # fmt: skip
        else:
            lines.ok(text, **d)
        held = sum(1 for p in live.poses if p.get("updating") is False)
        if held:
            lines.warn(f"{held} of {n} poses held (updating false): the sensors still live "
                       "cannot determine the motion", "see the mice below")  # fmt: skip
    _check_mice(lines, live, sensors)
    return lines


_STATE_HINT = {
    "suspect": "its readings are in doubt: watch it (`mousedom watch`)",
    "excluded": "the fusion goes on without it: is it on the floor, its lens clean, its "
    'mount and CPI right? (docs/models.md, "Faults")',
}


def _check_mice(lines: Lines, live: Live, sensors: list[str]) -> None:
    """Each sensor's state from its latest SOURCE line (and the last POSE's ``missing``)."""
    last = live.poses[-1] if live.poses else {}
    for name in sensors:
        s = live.sources.get(name)
        if s is None:
            lines.fail(f"{name}: missing: no SOURCE line in {live.seconds:.1f} s",
                       "`mousedom watch` shows the sensors; the daemon's log says why",
                       mouse=name, state="missing")  # fmt: skip
            continue
        state = s.get("state") or ("tracking" if s.get("live") else "gone")
        if not s.get("connected") or state == "gone" or name in (last.get("missing") or ()):
            state = "missing"
        reason = s.get("reason") or s.get("error")
        facts = [str(s.get("kind"))]
        rate, residual = s.get("rate_hz"), s.get("residual")
        if isinstance(rate, (int, float)):
            facts.append(f"{rate:.0f} reports/s" if rate else "still (no reports)")
        if isinstance(residual, (int, float)) and math.isfinite(residual):
            facts.append(f"residual {residual * 1e6:.0f} um")
        text = f"{name}: {state}{f' ({reason})' if reason else ''}, {', '.join(facts)}"
        d = {"mouse": name, "state": state, "reason": reason}
        if state == "tracking":
            lines.ok(text, **d)
        elif state == "missing":
            lines.fail(text, "plug it in (the daemon reopens it by itself); the devices lines "
                       "above say whether this machine sees it", **d)  # fmt: skip
        else:
            lines.warn(text, _STATE_HINT.get(state), **d)
        if s.get("scale_warning"):
            lines.warn(f"{name}: {s['scale_warning']}", "correct its cpi in the config, or "
                       "measure it: `mousedom calibrate scales` on a recorded drive "
                       "(docs/calibration.md)", mouse=name, scale=s.get("scale"))  # fmt: skip


# --------------------------------------------------------------------------- 5. ROS 2

# Run in a child process, so that a DDS stack that hangs cannot hang doctor: start a
# participant as the daemon does (its domain, its DDS configuration, Cyclone's own words
# when it fails), then, if asked, count the odometry messages that arrive for a while.
_PARTICIPANT = r"""
import json, sys, time
args = json.loads(sys.argv[1])
def done(**kw):
    print(json.dumps(kw), flush=True)
    sys.exit(0)
try:
    from cyclonedds.core import DDSException
    from cyclonedds.domain import Domain, DomainParticipant
except ImportError as e:
    done(ok=False, missing=True, error=str(e))
from mousedom.service import ros2msgs, ros2out
domain = args["domain"]
error = None
with ros2out._dds_stderr() as said:
    try:
        dds_domain = Domain(domain, ros2out.dds_config())
    except DDSException:
        if "config:" in said():
            error = ros2out._why_no_participant(domain, said())
    if error is None:
        try:
            dp = DomainParticipant(domain)
        except DDSException:
            error = ros2out._why_no_participant(domain, said())
if error is not None:
    done(ok=False, error=error)
received = None
if args["listen"] > 0:
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    topic = Topic(dp, args["topic"], ros2msgs.idl_types()[ros2msgs.ODOMETRY])
    reader = DataReader(dp, topic)
    received = 0
    end = time.monotonic() + args["listen"]
    while time.monotonic() < end:
        received += len(reader.take(N=256))
        time.sleep(0.05)
done(ok=True, received=received)
"""


class Ros2Probe:
    """The ROS 2 check: started before the daemon is read, so that its listening for the
    odometry and the read of the socket take the same second; ``finish`` gives its lines."""

    def __init__(self, cfg: Config | None, listen: float) -> None:
        self.lines = Lines("ros2")
        self.proc: subprocess.Popen[str] | None = None
        if cfg is None:
            return
        if cfg.ros2 is None:
            self.lines.ok("ROS 2 output not configured (outputs.ros2 in the config, or "
                          "`run --ros2`)")  # fmt: skip
            return
        from mousedom.service import ros2conv, ros2out

        o = cfg.ros2
        # optional: the daemon runs on without it, so a problem is a warning
        self.bad = self.lines.warn if o.optional else self.lines.fail
        self.see = f"see {ros2out.DOCS}"
        self.install_hint = ros2out.INSTALL_HINT.split(": ", 1)[-1]
        try:
            self.domain = ros2out.domain_id(o)
        except UserError as e:
            self.bad(str(e), "set ROS_DOMAIN_ID to a number from 0 to 232, or "
                     "outputs.ros2.domain_id")  # fmt: skip
            return
        self.odom, self.listen = ros2conv.topic(o, o.odom_topic), listen
        args = {"domain": self.domain, "topic": "rt" + self.odom, "listen": listen}
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PACKAGE.parent),
                                                          env.get("PYTHONPATH")]))  # fmt: skip
        self.deadline = time.monotonic() + PARTICIPANT_TIMEOUT_S + listen
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _PARTICIPANT, json.dumps(args)],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, env=env,
        )  # fmt: skip

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()

    def finish(self, live: Live | None) -> list[Check]:
        if self.proc is None:
            return self.lines
        try:
            out, err = self.proc.communicate(timeout=max(0.0, self.deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            self.close()
            self.bad(f"no DDS participant on domain {self.domain} within "
                     f"{PARTICIPANT_TIMEOUT_S + self.listen:g} s",
                     f"DDS is stuck (network interfaces? CYCLONEDDS_URI?): {self.see}")  # fmt: skip
            return self.lines
        try:
            result = json.loads(out.strip().splitlines()[-1])
        except (IndexError, ValueError):
            tail = (err.strip().splitlines() or ["no output"])[-1]
            self.bad(f"the DDS check failed: {tail}", self.see)
            return self.lines
        if result.get("missing"):
            self.bad("the ROS 2 output is configured, but cyclonedds is not installed",
                     self.install_hint)  # fmt: skip
            return self.lines
        if not result.get("ok"):
            self.bad(str(result.get("error") or "no DDS participant"), "fix what Cyclone DDS "
                     "names; or let the daemon run without ROS 2: outputs.ros2.optional: "
                     "true")  # fmt: skip
            return self.lines
        self.lines.ok(f"a DDS participant starts on domain {self.domain}", domain=self.domain)
        received, odom = result.get("received"), self.odom
        if received is None or live is None or not live.connected:
            return self.lines  # no daemon to listen to
        if received:
            self.lines.ok(f"{odom}: {received} messages in {self.listen:.1f} s", topic=odom,
                          received=received)  # fmt: skip
        else:
            self.lines.warn(f"{odom}: no message in {self.listen:.1f} s", "does the daemon run "
                            "the ROS 2 output (its log says so at start)? the same "
                            "ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE as this shell?",
                            topic=odom, received=0)  # fmt: skip
        return self.lines


# --------------------------------------------------------------------------- 6. metrics


def check_metrics(cfg: Config | None, live: Live, timeout: float) -> list[Check]:
    """The Prometheus endpoint (docs/metrics.md), where the config asks for one: the extra
    installed, and a running daemon serving it where the config says."""
    lines = Lines("metrics")
    m = cfg.metrics if cfg is not None else None
    if m is None:
        lines.ok("Prometheus metrics not configured (outputs.metrics; docs/metrics.md)")
        return lines
    if importlib.util.find_spec("prometheus_client") is None:
        lines.fail("outputs.metrics is set but prometheus-client is not installed",
                   "pip install 'mousedom[metrics]'")  # fmt: skip
        return lines
    if m.port == 0:
        lines.warn("not checked: port 0 takes any free port (the daemon's log names it)",
                   "set outputs.metrics.port to have it checked here")  # fmt: skip
        return lines
    if not live.connected:
        lines.warn(f"not checked: no daemon answers on {live.path}", "start the daemon")
        return lines
    # where a client on this machine reaches it (an "every interface" address included)
    host = {"0.0.0.0": "127.0.0.1", "::": "::1", "localhost": "127.0.0.1"}.get(m.host, m.host)
    url = f"http://{f'[{host}]' if ':' in host else host}:{m.port}/metrics"
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            text = r.read(1 << 20).decode("utf-8", "replace")
    except (OSError, ValueError) as e:
        lines.fail(f"nothing serves {url} ({getattr(e, 'reason', e)})",
                   "the daemon reads outputs.metrics when it starts: restart it after a "
                   "change (or another program holds the port)")  # fmt: skip
        return lines
    found = re.search(r"^mousedom_windows_total (\S+)$", text, re.MULTILINE)
    if found is None:
        lines.fail(
            f"{url} answers but is not mousedom's (no mousedom_windows_total)",
            "another program holds the port: choose another outputs.metrics.port",
        )
        return lines
    windows = float(found.group(1))
    lines.ok(f"serving {url}: {windows:.0f} windows published", url=url, windows=windows)
    return lines


# --------------------------------------------------------------------------- 7. the core


def compiled_modules() -> list[str]:
    """The compiled extension modules inside the mousedom package, as module names."""
    suffixes = sorted(importlib.machinery.EXTENSION_SUFFIXES, key=len, reverse=True)
    out = []
    for p in sorted(PACKAGE.rglob("*")):
        suffix = next((s for s in suffixes if p.name.endswith(s)), None)
        if suffix:
            rel = p.relative_to(PACKAGE.parent).as_posix()[: -len(suffix)]
            out.append(rel.replace("/", "."))
    return out


def check_core(live: Live | None) -> list[Check]:
    lines = Lines("core")
    said = live.version.get("core") if live is not None else None
    tail = f"; the running daemon says: {said}" if said else ""
    modules = compiled_modules()
    if not modules:
        lines.ok(f"python (no compiled core built){tail}")
    elif os.environ.get("MOUSEDOM_CORE", "").strip() == "python":
        lines.ok(f"python (MOUSEDOM_CORE=python; built: {', '.join(modules)}){tail}")
    else:
        for module in modules:
            try:
                importlib.import_module(module)
            except ImportError as e:
                lines.warn(f"python: the compiled {module} does not load ({e})",
                           "rebuild it: pip install --force-reinstall mousedom (with gcc and "
                           "the Python headers, docs/install.md)")  # fmt: skip
                return lines
        lines.ok(f"compiled ({', '.join(modules)}){tail}")
    return lines


# --------------------------------------------------------------------------- the report


def find_config(given: str | None, socket_given: str | None) -> Found:
    """--config; else the daemon's default; else the config the running daemon reports."""
    if given:
        return Found(given, "--config")
    if os.path.exists(DEFAULT_CONFIG_PATH):
        return Found(DEFAULT_CONFIG_PATH, "the daemon's default")
    path = socket_path(None, socket_given)
    if os.path.exists(path):
        runs = read_live(path, 0.1).status.get("config")
        if isinstance(runs, str) and runs:
            return Found(runs, "the running daemon's")
    return Found(None)


def diagnose(
    config: str | None = None,
    socket: str | None = None,
    timeout: float = 1.5,
    root: str | None = None,
) -> list[Check]:
    """Every check, in order: config, devices, calibration, daemon, ROS 2, metrics, core."""
    found = find_config(config, socket)
    checks = check_config(found)
    cfg = found.config
    if found.path is not None and cfg is None and not found.calibration_error:
        checks.append(Check("devices", WARN, "not checked: the config did not load",
                            "fix the config first"))  # fmt: skip
    else:
        checks += check_devices(cfg, root)
    checks += check_calibration(found)
    path = socket_path(cfg, socket)
    ros2 = Ros2Probe(cfg, listen=timeout if os.path.exists(path) else 0.0)
    try:
        live = read_live(path, timeout, cfg.path if cfg else None)
        checks += check_daemon(live, cfg, timeout)
        checks += ros2.finish(live)
    finally:
        ros2.close()
    checks += check_metrics(cfg, live, timeout)
    checks += check_core(live)
    return checks


def render(checks: list[Check]) -> str:
    """The report as text: one line per check, what to do under each WARN and FAIL."""
    lines = []
    for c in checks:
        lines.append(f"{c.status:<4}  {c.check}: {c.message}")
        if c.hint and c.status != OK:
            lines.append(f"      -> {c.hint}")
    count = {s: sum(1 for c in checks if c.status == s) for s in (FAIL, WARN, OK)}
    verdict = "it works" if not count[FAIL] else "it does not work yet"
    lines.append(f"doctor: {verdict} ({count[FAIL]} FAIL, {count[WARN]} WARN, {count[OK]} OK)")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise UserError(f"--timeout must be a positive number of seconds, got {args.timeout}")
    checks = diagnose(args.config, args.socket, args.timeout, args.root)
    failed = any(c.status == FAIL for c in checks)
    if args.json:
        doc = {"ok": not failed, "checks": [c.as_dict() for c in checks]}
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
    else:
        sys.stdout.write(render(checks))
    return 1 if failed else 0
