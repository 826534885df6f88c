"""A Python client of the daemon's socket: an iterator of poses, and the commands.

    from mousedom.client import Client

    with Client() as c:              # finds the socket like ``mousedom watch`` does
        c.rate(10)                   # ten poses a second for this client
        for pose in c:               # blocks; ends when the daemon goes away
            print(pose.x, pose.y, pose.theta, pose.updating)

Other messages (SOURCE, STATUS) are kept as they pass: ``c.sources`` holds the latest
SOURCE per sensor, as the dict the daemon sent (docs/protocol.md: its health, and since
protocol 1.2 its learnt ``scale``, ``scale_spread``, ``scale_applied``, ``scale_warning``).
Commands wait for their OK (or raise ``CommandError`` on ERROR); poses that arrive meanwhile
are kept for the iterator, none is lost.

Errors: ``DaemonNotRunning`` (no daemon at the socket), ``DaemonNotAnswering`` (the
socket is held, but nothing answers in time: a stopped or hung daemon), ``DaemonRefused``
(the daemon answered with ERROR instead of VERSION: too many clients), ``NotADaemon``
(something else there, or a line that is no protocol message or not of its class's shape:
``service.message_shapes``) and ``ConnectionLost`` (the daemon went away while a command
waited for its answer) are ``ConnectionError``s, so ``except OSError`` catches them;
``CommandError`` is a ``RuntimeError``; all are ``ClientError``s.  The iterator ends when
the daemon closes the connection, a last line cut off included.  A ``timeout`` (seconds,
None: wait for ever) bounds every wait for a line, and a command's wait for its answer as a
whole (``TimeoutError``); the connect and the VERSION banner take at most
``CONNECT_TIMEOUT_S`` without one.  Once a timeout runs out the connection is left in no
state to read again (its line may be half read): the client is to be closed.
"""

from __future__ import annotations

import errno
import itertools
import json
import math
import os
import socket
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from mousedom import invocation
from mousedom.angles import wrap_degrees
from mousedom.service import message_shapes
from mousedom.service.socketfile import SOCKET_NAME, default_socket_path

# Without a timeout, how long the connect and the VERSION banner may take.
CONNECT_TIMEOUT_S = 5.0


class ClientError(Exception):
    """Everything this client raises about the daemon (a base to catch them all)."""


class DaemonNotRunning(ClientError, ConnectionError):
    """No daemon answers at the socket (missing, refused, or no permission).  A
    ConnectionError, so ``except OSError`` catches it too; ``errno`` is the OS's."""

    def __str__(self) -> str:
        return self.strerror or super().__str__()  # the message, without "[Errno 2]"


class DaemonNotAnswering(ClientError, ConnectionError):
    """Something holds the socket (the connection waits in its backlog, or was taken) but
    says nothing in time: a daemon stopped (SIGSTOP), hung or overloaded.  ``errno`` is
    ETIMEDOUT."""

    def __str__(self) -> str:
        return self.strerror or super().__str__()


class NotADaemon(ClientError, ConnectionError):
    """Something answered at the socket, but not with mousedom's VERSION banner."""


class DaemonRefused(ClientError, ConnectionError):
    """The daemon answered the connection with ERROR (its message, e.g. "too many
    clients; try again later"), not with its VERSION banner."""


class ConnectionLost(ClientError, ConnectionError):
    """The daemon closed the connection (or it broke) while a command waited."""


class CommandError(ClientError, RuntimeError):
    """The daemon answered a command with ERROR (its message is the exception's)."""


@dataclass(frozen=True)
class Pose:
    t: float
    x: float
    y: float
    theta: float
    vx: float
    vy: float
    omega: float
    cov: tuple[tuple[float, ...], ...]
    used: int
    updating: bool
    missing: tuple[str, ...]
    excluded: tuple[str, ...] = ()  # left out by the fault-tolerant fusion (protocol 1.1)
    suspect: tuple[str, ...] = ()
    consistent: bool = True

    @property
    def heading_deg(self) -> float:
        """theta as a person reads it: degrees in (-180, 180], as ``mousedom watch`` and
        ``replay`` show it (theta itself is continuous: it counts whole turns)."""
        return wrap_degrees(self.theta)

    @classmethod
    def from_message(cls, m: dict[str, Any]) -> Pose:
        nan = float("nan")

        def num(v: Any) -> float:
            if v is None:
                return nan
            try:
                return float(v)
            except OverflowError:  # an integer beyond any float (JSON allows it)
                return math.inf if v > 0 else -math.inf

        return cls(
            t=num(m["t"]),
            x=num(m["x"]),
            y=num(m["y"]),
            theta=num(m["theta"]),
            vx=num(m["vx"]),
            vy=num(m["vy"]),
            omega=num(m["omega"]),
            cov=tuple(tuple(num(c) for c in row) for row in m["cov"]),
            used=int(m["used"]),
            updating=bool(m["updating"]),
            missing=tuple(m.get("missing", ())),
            excluded=tuple(m.get("excluded", ())),
            suspect=tuple(m.get("suspect", ())),
            consistent=bool(m.get("consistent", True)),
        )


def socket_candidates(environ: dict[str, str] | None = None) -> list[str]:
    """Where a daemon's socket may be, most likely first (see ``default_socket_path``)."""
    env = dict(os.environ) if environ is None else environ
    uid = os.getuid()
    out = [default_socket_path(env, uid), os.path.join("/run/mousedom", SOCKET_NAME)]
    if env.get("XDG_RUNTIME_DIR"):
        out.append(os.path.join(env["XDG_RUNTIME_DIR"], "mousedom", SOCKET_NAME))
    tmp = env.get("TMPDIR") or "/tmp"
    out.append(os.path.join(tmp, f"mousedom-{uid}", SOCKET_NAME))
    return list(dict.fromkeys(out))


def find_socket(environ: dict[str, str] | None = None) -> str:
    """The first candidate socket that exists, else the default one."""
    candidates = socket_candidates(environ)
    for path in candidates:
        if os.path.exists(path):
            return path
    return candidates[0]


def access_hint(path: str) -> str:
    """Why this user may not connect to the socket at ``path``, and what to do: the daemon
    runs, but the socket's mode and group (server.mode, server.group) keep this user out
    (connecting needs write permission on the socket, and search on its folders)."""
    import grp
    import pwd
    import stat

    try:
        st = os.stat(path)
    except OSError:
        return ("permission denied on the way to the socket: a folder above it is closed "
                "to this user")  # fmt: skip
    try:
        group = grp.getgrgid(st.st_gid).gr_name
    except KeyError:
        group = str(st.st_gid)
    try:
        owner = pwd.getpwuid(st.st_uid).pw_name
    except KeyError:
        owner = str(st.st_uid)
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o020:
        what = (f"join its group {group!r} (sudo usermod -aG {group} $USER, then log in "
                "again)")  # fmt: skip
    else:
        what = ("its mode lets no group in: set server.mode (e.g. \"0660\") and server.group "
                "in the daemon's config")  # fmt: skip
    return (f"permission denied: the socket is mode {mode:04o}, owner {owner}, group {group}; "
            f"to watch it as this user, {what}")  # fmt: skip


class Client:
    """One connection to the daemon; iterate it for poses."""

    def __init__(self, path: str | None = None, timeout: float | None = None) -> None:
        self.path = path or find_socket()
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        # The connect and the banner are bounded even without a timeout: a stopped daemon's
        # full backlog made connect() wait for ever (watch, doctor, a second `run`).
        wait = CONNECT_TIMEOUT_S if timeout is None else timeout
        self.sock.settimeout(wait)
        try:
            self._connect(time.monotonic() + wait)
        except TimeoutError:
            self.sock.close()
            raise DaemonNotAnswering(
                errno.ETIMEDOUT,
                f"{self.path}: the daemon takes no connection (waited {wait:g} s): it is "
                "stopped, hung or overloaded (`systemctl status mousedom`)",
            ) from None
        except PermissionError as e:
            self.sock.close()
            raise DaemonNotRunning(e.errno, f"{self.path}: {access_hint(self.path)}") from None
        except OSError as e:
            self.sock.close()
            raise DaemonNotRunning(
                e.errno,
                f"{self.path}: cannot connect: {e.strerror} (is the daemon running? start it "
                f"with `{invocation.command('run')}`, or give the socket's path)",
            ) from None
        self._file = self.sock.makefile("rb")
        self._pending: deque[dict[str, Any]] = deque()
        self._ids = itertools.count(1)
        self.sources: dict[str, dict[str, Any]] = {}
        self.version: dict[str, Any] = {}  # the latest VERSION (_read keeps it)
        try:
            first = self._read()
        except TimeoutError:
            self.close()
            raise DaemonNotAnswering(
                errno.ETIMEDOUT,
                f"{self.path}: the daemon took the connection but said nothing in {wait:g} s: "
                "it is stopped, hung or overloaded (`systemctl status mousedom`)",
            ) from None
        except (EOFError, OSError, ValueError) as e:
            self.close()
            raise NotADaemon(f"{self.path}: no VERSION banner ({e})") from None
        self.sock.settimeout(timeout)
        if first.get("class") == "ERROR" and isinstance(first.get("message"), str):
            self.close()  # the daemon's own word: too many clients
            raise DaemonRefused(f"{self.path}: the daemon refused: {first['message']}")
        if first.get("class") != "VERSION":
            self.close()
            raise NotADaemon(f"{self.path}: not a mousedom socket (no VERSION banner)")
        self._take(first)

    def _connect(self, deadline: float) -> None:
        """connect(), again while the listen backlog is full (a Unix socket with a timeout
        says EAGAIN at once rather than wait) until ``deadline``: TimeoutError then."""
        while True:
            try:
                self.sock.connect(self.path)
                return
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    raise TimeoutError from None
                time.sleep(0.05)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._file.close()
        self.sock.close()

    # ------------------------------------------------------------------ reading

    def _read(self) -> dict[str, Any]:
        line = self._file.readline()
        if not line.endswith(b"\n"):  # (a line cut off: the daemon went away within it)
            raise EOFError("the daemon closed the connection")
        try:
            obj: Any = json.loads(line)
        except ValueError:
            obj = None
        if not isinstance(obj, dict):
            raise NotADaemon(f"{self.path}: a line that is no protocol message: {line[:80]!r}")
        wrong = message_shapes.problem(obj)
        if wrong is not None:
            raise NotADaemon(f"{self.path}: a line that does not follow the protocol ({wrong}): "
                             f"{line[:80]!r}")  # fmt: skip
        return obj

    def _take(self, msg: dict[str, Any]) -> dict[str, Any]:
        """A message handed to the caller: ``version`` and ``sources`` as of it.  Kept at
        hand-over, not when read: a VERSION read while a command waited (a reload) was
        credited to the poses of the old config still queued before it."""
        cls = msg.get("class")
        if cls == "SOURCE":
            name: Any = msg.get("name")
            self.sources[name] = msg
        elif cls == "VERSION":
            # Again after a reload that changed what it says (docs/protocol.md): the
            # sensors' SOURCE lines follow it, and a sensor it no longer names is gone.
            self.version = msg
            self.sources.clear()
        return msg

    def messages(self) -> Iterator[dict[str, Any]]:
        """Every message as a dict, until the daemon closes the connection."""
        while True:
            if self._pending:
                yield self._take(self._pending.popleft())
                continue
            try:
                msg = self._read()
            except EOFError:
                return
            yield self._take(msg)

    def __iter__(self) -> Iterator[Pose]:
        for msg in self.messages():
            if msg.get("class") == "POSE":
                yield Pose.from_message(msg)

    # ------------------------------------------------------------------ commands

    def command(self, cmd: str, **args: float) -> dict[str, Any]:
        """Send one command and return its answer (OK or STATUS); ERROR raises."""
        ident = next(self._ids)
        line = json.dumps({"cmd": cmd, "id": ident, **args}) + "\n"
        # The timeout bounds the wait for the answer as a whole: each POSE that comes
        # meanwhile is in time, and a daemon that never answers kept it waiting for ever.
        timeout = self.sock.gettimeout()
        deadline = None if timeout is None else time.monotonic() + timeout
        try:
            self.sock.sendall(line.encode())
        except (BrokenPipeError, ConnectionResetError) as e:
            raise ConnectionLost(f"{self.path}: the daemon went away ({e.strerror})") from None
        while True:
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"{self.path}: no answer to {cmd} in {timeout:g} s")
            try:
                msg = self._read()
            except (EOFError, ConnectionResetError):  # (a reset: it closed with ours unread)
                raise ConnectionLost(
                    f"{self.path}: the daemon closed the connection before answering {cmd}"
                ) from None
            cls = msg.get("class")
            # Commands are answered in order; an ERROR without an id (a line the daemon
            # could not even read as an object) can only be ours.  (An id of true is no
            # 1: True == 1 in Python.)
            answer = type(msg.get("id")) is int and msg.get("id") == ident
            if (answer and cls in ("OK", "STATUS", "ERROR")) or (
                cls == "ERROR" and "id" not in msg
            ):
                if cls == "ERROR":
                    raise CommandError(msg.get("message", "error"))
                return msg
            self._pending.append(msg)

    def reset(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> dict[str, Any]:
        return self.command("reset", x=x, y=y, theta=theta)

    def fix(
        self, x: float | None = None, y: float | None = None, theta: float | None = None
    ) -> dict[str, Any]:
        given = {k: v for k, v in (("x", x), ("y", y), ("theta", theta)) if v is not None}
        return self.command("fix", **given)

    def rate(self, hz: float) -> dict[str, Any]:
        """POSE at most ``hz`` times a second from the answer on; the POSE lines that came
        before the answer (at the daemon's own rate) are dropped, so that iterating gives
        poses at the rate asked for from the first."""
        answer = self.command("rate", hz=hz)
        self._pending = deque(m for m in self._pending if m.get("class") != "POSE")
        return answer

    def status(self) -> dict[str, Any]:
        return self.command("status")


def poses(path: str | None = None, rate_hz: float | None = None) -> Iterator[Pose]:
    """Poses from the daemon at ``path`` until it goes away."""
    with Client(path) as c:
        if rate_hz is not None:
            c.rate(rate_hz)
        yield from c
