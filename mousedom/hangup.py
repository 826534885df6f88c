"""The command line's hangups and terminations: what SIGHUP and SIGTERM do before, and
outside, the commands that handle them themselves.

For `run`: Python's default for SIGHUP ends the process, so a reload asked in the first
half second of `mousedom run` (its imports, the config, the sensors) killed the daemon
with no word.  ``hold`` is called first thing for `run` (cli.main); the daemon, once its
handlers are in, asks ``pending`` and reloads if one came (the config may have changed
after it was read).

For the commands that write a file and have no handlers of their own (convert, replay,
calibrate, umbmark...): the default ends the process where it stands, and ``replace_file``
left its full-size temporary file beside the output (`timeout`, systemd, a closed
terminal).  ``stopping`` turns the two signals into ``Terminated``, which unwinds as
Ctrl-C's KeyboardInterrupt does: every ``finally`` and cleanup runs, and the CLI says so
in one line and then dies by the signal (``die``: what a supervisor asked for).  A
signal the process was started with ignored (``nohup``) stays ignored.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator

_seen: list[int] = []
STOPS = (signal.SIGTERM, signal.SIGHUP)


class Terminated(BaseException):  # noqa: N818  (as KeyboardInterrupt: not an error)
    """A SIGTERM or SIGHUP, raised where the command stood (``stopping``)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


def hold() -> None:
    """From now on a SIGHUP is remembered, until the daemon's handler replaces this one."""
    signal.signal(signal.SIGHUP, lambda signum, frame: _seen.append(signum))


def pending() -> bool:
    """Whether a SIGHUP came while held."""
    return bool(_seen)


def _raise(signum: int, frame: object) -> None:
    raise Terminated(signum)


@contextlib.contextmanager
def stopping() -> Iterator[None]:
    """Within: SIGTERM and SIGHUP raise Terminated (those not ignored); after, the
    handlers before.  Only on the main thread (where Python runs handlers); elsewhere
    (a test calling the CLI from a thread) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # (None: a handler set from C, which Python cannot put back: left as it is)
    before = {
        sig: handler
        for sig in STOPS
        if (handler := signal.getsignal(sig)) is not None and handler is not signal.SIG_IGN
    }
    try:
        for sig in before:
            signal.signal(sig, _raise)
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)


def die(signum: int) -> None:
    """End the process by ``signum`` itself, its cleanup done: a supervisor (systemd, a
    shell's `wait`) then sees a death by that signal, as it asked for, and not an exit
    status it would count as a failure.  Returns only where the signal does not kill."""
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)
