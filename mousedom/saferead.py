"""Every file the program reads by name goes through here: regular files only.

A config, a calibration file, a capture or a CSV named on the command line (or swapped in
before a SIGHUP) may be a FIFO, a character device or a socket.  ``open()`` of a FIFO blocks
until a writer appears, which froze a reloading daemon (no POSE, SIGTERM unanswered) and
hung ``check-config``; a device such as /dev/zero never ends.  So the file is opened
non-blocking (a FIFO's open returns at once), its type checked with ``fstat`` on the open
descriptor (no window between the check and the read), and only a regular file is handed
back, in blocking mode.  Anything else is refused with an ``OSError`` whose ``strerror``
names what it is, so the callers' existing "cannot read: {strerror}" messages say why.

Device nodes the program is meant to open (evdev, serial ports, FIFOs standing for them in
tests) do not come through here.
"""

from __future__ import annotations

import errno
import os
import stat
from typing import BinaryIO

# What a non-regular file is called in messages.
_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


class NotRegularFile(OSError):
    """The path names something other than a regular file."""


def kind_of(mode: int) -> str:
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"


def open_regular(path: str | os.PathLike[str]) -> BinaryIO:
    """``open(path, "rb")`` for regular files only (NotRegularFile, an OSError, else)."""
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | getattr(os, "O_NOCTTY", 0)
    fd = os.open(path, flags)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            err = errno.EISDIR if stat.S_ISDIR(mode) else errno.EINVAL
            raise NotRegularFile(err, f"is {kind_of(mode)}, not a regular file", str(path))
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    # Outside the try: once the file object holds the descriptor, an exception raised
    # there (a SIGTERM's Terminated, hangup.py, between two bytecodes) must not close it a
    # second time, when the orphan object is collected: by then the number may be another
    # file's, which then reads "Bad file descriptor" (a convert ended by SIGTERM said so
    # and exited 2, where it should have died by the signal).
    return os.fdopen(fd, "rb")


def read_bytes(path: str | os.PathLike[str], max_bytes: int | None = None) -> bytes:
    """The whole of a regular file (at most ``max_bytes + 1`` bytes are read, so a caller
    that passes a limit can tell a file that is larger)."""
    with open_regular(path) as f:
        return f.read() if max_bytes is None else f.read(max_bytes + 1)


def read_text(path: str | os.PathLike[str]) -> str:
    """A regular file as UTF-8 text (UnicodeDecodeError for other bytes)."""
    return read_bytes(path).decode("utf-8")
