"""The systemd notify protocol: one datagram of ``KEY=VALUE`` lines to ``$NOTIFY_SOCKET``.

A ``Type=notify`` unit is started only when the daemon says ``READY=1``; with ``WatchdogSec``
systemd kills it unless ``WATCHDOG=1`` arrives often enough; ``STATUS=...`` is the line that
``systemctl status`` shows.  The protocol is a single ``sendto`` on an AF_UNIX datagram socket;
a socket name starting with ``@`` is in the abstract namespace.  Outside systemd
(``NOTIFY_SOCKET`` unset) every call does nothing, so the daemon calls it unconditionally.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


def _address(name: str) -> str | bytes:
    # "@foo" is the abstract socket "\0foo" (systemd documents both spellings).
    if name.startswith("@"):
        return b"\0" + name[1:].encode()
    return name


def watchdog_interval(environ: dict[str, str] | None = None) -> float | None:
    """Seconds between WATCHDOG=1 pings (half of WatchdogSec), or None when not asked.

    systemd sets WATCHDOG_USEC, and WATCHDOG_PID to the process it means; a child that
    inherited the variables must not ping for its parent.
    """
    env = os.environ if environ is None else environ
    usec = env.get("WATCHDOG_USEC")
    if not usec:
        return None
    pid = env.get("WATCHDOG_PID")
    if pid and pid.strip() != str(os.getpid()):
        return None
    try:
        value = int(usec)
    except ValueError:
        log.warning("ignoring WATCHDOG_USEC=%r: not an integer", usec)
        return None
    if value <= 0:
        return None
    return value / 2e6


# systemd ignores a notify datagram longer than this (NOTIFY_BUFFER_MAX, PIPE_BUF): a
# READY=1 sent with a STATUS naming 200 bad keys was lost, and the reload never ended.
MAX_DATAGRAM = 4096


def datagram(fields: dict[str, object]) -> bytes:
    """``KEY=VALUE`` lines, one field a line, within MAX_DATAGRAM bytes: a STATUS too long
    for it is cut (at a character, ending in "..."); the other fields are short."""
    lines = {key: str(value).replace("\n", " ") for key, value in fields.items()}
    data = "\n".join(f"{k}={v}" for k, v in lines.items()).encode()
    if len(data) <= MAX_DATAGRAM or "STATUS" not in lines:
        return data
    over = len(data) - MAX_DATAGRAM + len(b"...")
    status = lines["STATUS"].encode()
    lines["STATUS"] = status[: max(0, len(status) - over)].decode(errors="ignore") + "..."
    return "\n".join(f"{k}={v}" for k, v in lines.items()).encode()


class Notifier:
    """Sends notify datagrams; a no-op when ``NOTIFY_SOCKET`` is not set."""

    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        name = env.get("NOTIFY_SOCKET") or None
        self.address = _address(name) if name else None
        self._sock: socket.socket | None = None
        self.sent = 0
        if self.address is not None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, **fields: object) -> bool:
        """Send ``KEY=VALUE`` lines (e.g. ``notify(READY=1, STATUS="ok")``); True if sent.

        Failures are logged, never raised: losing a status line must not stop the fusion.
        """
        if self._sock is None or self.address is None or not fields:
            return False
        try:
            # Never block the fusion on the notify socket: a receiver whose queue is full
            # (it holds only a few datagrams) costs us one status line, not a stall.
            self._sock.sendto(datagram(fields), socket.MSG_DONTWAIT, self.address)
        except BlockingIOError:
            log.debug("sd_notify to %r: receiver busy, line dropped", self.address)
            return False
        except OSError as e:
            log.warning("sd_notify to %r failed: %s", self.address, e)
            return False
        self.sent += 1
        return True

    def ready(self, status: str | None = None) -> bool:
        fields: dict[str, object] = {"READY": 1}
        if status:
            fields["STATUS"] = status
        return self.notify(**fields)

    def reloading(self) -> bool:
        return self.notify(RELOADING=1)

    def watchdog(self) -> bool:
        return self.notify(WATCHDOG=1)

    def status(self, text: str) -> bool:
        return self.notify(STATUS=text)

    def stopping(self) -> bool:
        return self.notify(STOPPING=1)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
