"""``mousedom doctor``, the running daemon: a short read of its socket (``Live``), its
POSE rate against the config's, each mouse's state, and the Prometheus endpoint it serves."""

from __future__ import annotations

import errno
import importlib.util
import math
import os
import re
import stat
import time
import urllib.request
from dataclasses import dataclass, field
from typing import Any

from mousedom import invocation
from mousedom.commands._doctor_base import FAIL, WARN, Check, Lines
from mousedom.config import Config

RATE_TOLERANCE = 0.1  # a POSE rate within 10 % of rate_hz is the configured one


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
    closed: bool = False  # the daemon closed the connection within the read


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
    from mousedom.client import Client, ClientError, ConnectionLost, access_hint

    live = Live(path)
    command = invocation.command("run", "--config", config or "RIG.yaml")
    start = f"start it: `{command}` (or `systemctl start mousedom`)"
    if not os.path.exists(path):
        live.error = Check("daemon", WARN, f"no daemon: nothing at {path}",
                           f"{start}, or give --socket PATH")  # fmt: skip
        return live
    if not stat.S_ISSOCK(os.stat(path).st_mode):  # (a refused connect read "a socket, but")
        live.error = Check("daemon", FAIL, f"{path}: not a socket ({_kind(path)})",
                           "give the daemon's socket (--socket)")  # fmt: skip
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
        elif code == errno.ETIMEDOUT:  # (DaemonNotAnswering: a stopped or hung daemon)
            live.error = Check("daemon", FAIL, str(e), "`systemctl status mousedom` (a process "
                               "stopped by a signal shows state T: `kill -CONT PID`); "
                               "`journalctl -u mousedom` says what it did last")  # fmt: skip
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
        except (ConnectionLost, BrokenPipeError, ConnectionResetError):
            # (the command's send fails where the daemon closed before it: a race with
            # its close, so said as the close it is)
            live.closed = True
        except ClientError:
            live.status = {}
        end = t0 + timeout
        for msg in client.messages() if not live.closed else ():
            if msg.get("class") == "POSE":
                live.poses.append(msg)
            left = end - time.monotonic()
            if left <= 0:
                break
            client.sock.settimeout(left)
        else:
            live.closed = True  # (the messages ended: the daemon closed the connection)
    except (BrokenPipeError, ConnectionResetError):
        live.closed = True  # it went away while read
    except (OSError, ValueError):  # no next line in time (a stuck daemon)
        pass
    finally:
        live.seconds = time.monotonic() - t0
        live.sources = dict(client.sources)
        client.close()
    return live


def _kind(path: str) -> str:
    mode = os.stat(path).st_mode
    kinds = ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"),
             (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"))  # fmt: skip
    for test, name in kinds:
        if test(mode):
            return name
    return "not a socket"


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
    if live.closed:
        lines.fail(f"the daemon closed the connection after {live.seconds:.1f} s ({n} POSE)",
                   "it stopped or dropped this client: `journalctl -u mousedom` says "
                   "why")  # fmt: skip
    elif not n:
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
    "late": "its counts come late (a busy USB host): they are added back when they arrive; "
    "often, and the daemon's host is overloaded",
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
