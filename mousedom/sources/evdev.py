"""A live mouse over evdev: raw input_event bytes from the node, decoded in the source.

``open()`` finds the device the config rule names (``mousedom.sources.discovery``), opens it with
python-evdev, grabs it (EVIOCGRAB, unless ``grab: false``) so that the robot's mice do not
move a cursor, and switches its timestamps to CLOCK_MONOTONIC (EVIOCSCLOCKID, which
python-evdev does not wrap).  The hot path is ``os.read`` of up to ``READ_EVENTS`` records
at a time, then, for the few frames of a live read (up to ``SMALL_READ``), one Python loop
over ``struct.iter_unpack`` (``FrameAssembler.feed_bytes``) whose lists go to the tracker
as they are; bigger reads are decoded in bulk (one ``np.frombuffer``, no Python object per
event).  Both give the same results (tests/test_evdev_readpath.py; docs/readpath.md).

Unplugging shows at once: the kernel wakes the reader and ``read`` fails with ENODEV
(or returns EOF); the source closes the frame it was assembling (its counts are kept,
see ``FrameAssembler.flush``) and raises ``SourceGone``.  ``open()`` later rescans and
reattaches to whichever device matches the same rule.

Test hook: when the configured ``path`` is a FIFO or pipe rather than a character device,
it is read as a raw input_event stream and the ioctls are skipped (logged at debug).  The
writer closing its end is the unplug; reopening the FIFO is the reattach.  Times are then
whatever the writer put in the records.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import select
import struct
from collections.abc import Callable
from typing import Any

import numpy as np

from mousedom.config import EvdevMatch, MouseConfig
from mousedom.sources.base import (
    Reports,
    Source,
    SourceGone,
    SourceUnavailable,
    forward_list,
)
from mousedom.sources.discovery import (
    AmbiguousDevice,
    DeviceInfo,
    NoDevice,
    SystemPaths,
    is_stream,
    join_group_hint,
    locate,
    scan,
)
from mousedom.sources.events import EVENT_SIZE, FrameAssembler, MotionFrames, decode_input_events

log = logging.getLogger(__name__)

# _IOW('E', 0xa0, int): set the clock of the event timestamps (linux/input.h).
EVIOCSCLOCKID = (1 << 30) | (4 << 16) | (ord("E") << 8) | 0xA0
CLOCK_MONOTONIC = 1
READ_EVENTS = 1024  # records per os.read: 24 KiB, ~1 s of an 8 kHz mouse's frames
READ_BYTES = READ_EVENTS * EVENT_SIZE
MAX_READS = 16  # per read() call, so that one busy source cannot starve the others
# Reads up to this size (what a live mouse delivers per wake-up) take the assembler's
# pure-Python path; past ~300 records numpy's fixed cost per call pays off
# (bench/readpath.py prints both).
SMALL_READ = 256 * EVENT_SIZE


class EvdevSource(Source):
    """One configured mouse read from its evdev node (or from a FIFO, for tests)."""

    kind = "evdev"
    bounds_own_stamps = True  # before the forward clamp, in _read and _small

    def __init__(
        self,
        mouse: MouseConfig,
        paths: SystemPaths | None = None,
        *,
        device_opener: Callable[[str], Any] | None = None,
        ioctl: Callable[[int, int, bytes], Any] | None = None,
    ) -> None:
        """``device_opener`` (default ``evdev.InputDevice``) and ``ioctl`` (default
        ``fcntl.ioctl``) are the two doors to the kernel's evdev interface; tests pass
        fakes because this machine has no /dev/input nor /dev/uinput."""
        if mouse.evdev is None:
            raise ValueError(f"mouse {mouse.name} has no evdev section")
        super().__init__(mouse.name)
        self.rule: EvdevMatch = mouse.evdev
        self.paths = paths or SystemPaths()
        self.assembler = FrameAssembler()
        self.device: DeviceInfo | None = None
        self._dev = None  # python-evdev InputDevice while a real node is open
        self._fd = -1
        self._stream = False  # reading a FIFO/pipe: no ioctls, poll for hang-up
        self._rest = b""  # bytes of an incomplete record, completed by the next read
        self._gone: str | None = None  # the device went away; raise after handing over data
        self.truncated_bytes = 0  # bytes of incomplete records lost at unplug
        self.grabbed = False
        self.small_read = SMALL_READ  # tests set 0 to force the bulk path
        self._health_key: tuple | None = None
        self._device_opener = device_opener or _input_device
        self._ioctl = ioctl or fcntl.ioctl

    # ----------------------------------------------------------------- open / close

    def _open(self) -> None:
        self.close()
        self._gone, self._rest = None, b""
        if self.rule.path and is_stream(self.rule.path):
            self._open_stream(DeviceInfo(node=self.rule.path, name="(input_event stream)"))
        else:
            info = self._find()
            if is_stream(info.node):  # a test machine described as a directory tree
                self._open_stream(info)
            else:
                self._open_device(info)
        self._update_health()

    def _open_stream(self, info: DeviceInfo) -> None:
        try:
            self._fd = os.open(info.node, os.O_RDONLY | os.O_NONBLOCK)
        except OSError as e:
            raise SourceUnavailable(f"{self.name}: {info.node}: {e.strerror}") from None
        self._stream, self.grabbed, self.device = True, False, info
        log.debug(
            "%s: %s is a FIFO/pipe: reading raw input_event records, no grab, no clock ioctl",
            self.name,
            info.node,
        )

    def _find(self) -> DeviceInfo:
        try:
            return locate(self.rule, scan(self.paths).devices, self.paths, who=self.name)
        except AmbiguousDevice as e:
            # Several devices fit the rule (twin mice, or a look-alike plugged in later).
            # Sources speak base.py's terms only: "not available now, retry later", with
            # every candidate in the message.  The daemon keeps running and attaches once
            # the look-alike is unplugged; `record` and `list --config` stop with this
            # message (exit 1), which tells the user what to add to the rule.
            raise SourceUnavailable(str(e)) from None
        except NoDevice as e:
            if (
                self.rule.path
                and os.path.exists(self.rule.path)
                and not os.access(self.rule.path, os.R_OK)
            ):
                group = _group_of(self.rule.path)
                raise SourceUnavailable(
                    join_group_hint(DeviceInfo(node=self.rule.path, group=group))
                ) from None
            raise SourceUnavailable(str(e)) from None

    def _open_device(self, info: DeviceInfo) -> None:
        try:
            dev = self._device_opener(info.node)
        except PermissionError:
            raise SourceUnavailable(join_group_hint(info)) from None
        except OSError as e:
            why = "not an evdev device" if e.errno == errno.ENOTTY else e.strerror
            raise SourceUnavailable(f"{self.name}: {info.node}: {why}") from None
        try:
            if self.rule.grab:
                try:
                    dev.grab()
                except OSError as e:
                    if e.errno == errno.EBUSY:
                        raise SourceUnavailable(
                            f"{self.name}: {info.node} is grabbed by another process "
                            "(another mousedom? set grab: false to share it)"
                        ) from None
                    raise
            self._ioctl(dev.fd, EVIOCSCLOCKID, struct.pack("i", CLOCK_MONOTONIC))
            os.set_blocking(dev.fd, False)  # python-evdev opens O_NONBLOCK; make sure
        except SourceUnavailable:
            dev.close()
            raise
        except OSError as e:
            dev.close()
            raise SourceUnavailable(f"{self.name}: {info.node}: {e.strerror}") from None
        self._dev, self._fd, self._stream = dev, dev.fd, False
        self.grabbed = self.rule.grab
        self.device = info
        log.info("%s: attached to %s (%s)", self.name, info.node, info.name)

    def fileno(self) -> int:
        return self._fd

    def identity(self) -> str | None:
        if self._fd < 0 or self.device is None:
            return None
        return os.path.realpath(self.device.node)

    def close(self) -> None:
        if self._dev is not None:
            try:
                self._dev.close()  # closing the fd releases the grab too
            except OSError:
                pass
            self._dev = None
        elif self._fd >= 0:
            try:
                os.close(self._fd)
            except OSError:
                pass
        self._fd = -1
        self.grabbed = False

    # ----------------------------------------------------------------- data plane

    def _read(self, now: float) -> list[Reports]:
        if self._gone is not None:
            raise SourceGone(self._gone)
        fd = self._fd
        if fd < 0:
            raise SourceGone(f"{self.name}: not open")
        chunks = [self._rest] if self._rest else []
        gone = None
        for _ in range(MAX_READS):
            try:
                data = os.read(fd, READ_BYTES)
            except BlockingIOError:
                break
            except OSError as e:
                # ENODEV is the unplug; anything else (EIO from a dying USB port...) leaves
                # the descriptor unusable too: treat it the same and let open() retry.
                gone = f"{self.name}: device gone ({e.strerror or e})"
                break
            if not data:
                if self._stream and not chunks and not _ready(fd):
                    # A FIFO whose writer has not connected yet reads as EOF too; only
                    # POLLHUP (a writer came and went) is the unplug.  Checked here, on
                    # EOF, rather than before every read: the poll is a syscall per read.
                    return []
                gone = f"{self.name}: device gone (end of stream)"
                break
            chunks.append(data)
            if len(data) < READ_BYTES:
                break
        buf = b"".join(chunks)  # one chunk (the usual case): that same object, no copy
        if gone is None and len(buf) <= self.small_read:
            return self._small(buf, now)
        events, self._rest = decode_input_events(buf)
        frames = self.assembler.feed_events(events)
        if gone is not None:
            # The frame being assembled will never get its SYN_REPORT: keep its counts.
            frames = MotionFrames.concat([frames, self.assembler.flush()])
            self.truncated_bytes += len(self._rest)
            self._rest = b""
        self._update_health()
        if gone is not None and not len(frames):
            raise SourceGone(gone)
        self._gone = gone  # raised by the next call, after these frames are delivered
        if not len(frames):
            return []
        before = self.time_backwards
        t = self._forward(frames.t, now)
        if self.time_backwards != before:
            self._update_health()
        return [Reports(self.name, t, frames.dx.astype(np.float64), frames.dy)]

    def end_frame(self, now: float) -> list[Reports]:
        """At the end of a recording (``record`` stopped): the frame being assembled
        will get no SYN_REPORT here; its counts happened, so they are handed over as one
        report, as at an unplug (``FrameAssembler.flush``: counted incomplete)."""
        frames = self.assembler.flush()
        self._update_health()
        if not len(frames):
            return []
        t = self._forward(frames.t, now)
        return [Reports(self.name, t, frames.dx.astype(np.float64), frames.dy)]

    def _small(self, buf: bytes, now: float) -> list[Reports]:
        """A live read of a few frames: the same results as the bulk path below (the
        property tests compare them), on Python lists without a numpy call; the lists go
        to the tracker as they are (``Reports.from_lists``)."""
        t, dx, dy, self._rest = self.assembler.feed_bytes(buf)
        if not t:
            self._update_health()
            return []
        far, worst, back = forward_list(t, now, self._last_t)
        self._far_stamps(far, worst)
        if back:
            self.time_backwards += back
        self._update_health()
        self._last_t = t[-1]
        return [Reports.from_lists(self.name, t, dx, dy)]

    def _update_health(self) -> None:
        s = self.assembler.stats
        # Called on every read: rebuild the status only when something in it changed.
        key = (
            s.dropped_frames, s.skipped, s.syn_dropped, s.dropped_dx, s.dropped_dy,
            s.incomplete_frames, self.truncated_bytes, self.time_backwards, self.device,
            self.grabbed, self._stream,
        )  # fmt: skip
        if key == self._health_key:
            return
        self._health_key = key
        self.health.dropped = s.dropped_frames
        self.health.skipped = s.skipped
        self.health.extra.update(
            node=self.device.node if self.device else None,
            device=self.device.name if self.device else None,
            grabbed=self.grabbed,
            clock="as-written (stream)" if self._stream else "monotonic",
            syn_dropped=s.syn_dropped,
            dropped_counts=[s.dropped_dx, s.dropped_dy],
            incomplete_frames=s.incomplete_frames,
            truncated_bytes=self.truncated_bytes,
            time_backwards=self.time_backwards,
        )


def _input_device(node: str) -> Any:
    import evdev  # the C extension: only for real nodes (open, identity, grab)

    return evdev.InputDevice(node)


def _ready(fd: int) -> bool:
    """A FIFO whose writer never connected reads as EOF; only read when poll says so.

    Linux reports POLLHUP on a FIFO's read end only after a writer has come and gone,
    so "nothing yet" (no event) and "unplugged" (POLLHUP) are told apart here.
    """
    p = select.poll()
    p.register(fd, select.POLLIN)
    return bool(p.poll(0))


def _group_of(path: str) -> str | None:
    import grp

    try:
        return grp.getgrgid(os.stat(path).st_gid).gr_name
    except (OSError, KeyError):
        return None
