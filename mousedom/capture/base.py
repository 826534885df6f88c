"""What every capture reader gives the replay engine.

A ``Capture`` describes its devices up front and then streams *feeds*: iterators of
``Batch`` objects, each holding motion reports (and, for the native format, raw serial
bytes) plus a watermark ``complete``: every report of the feed's devices stamped at or
before it has been yielded.  A single-device text file is one feed; a libinput record
file is one feed per device (its devices sit one after another in the file); a native
file is one feed for all its sources.  The engine advances whichever feed lags, so memory
stays bounded however long the capture is.

Times stay on the capture's own base (``time_base``): ``epoch`` (CLOCK_REALTIME seconds,
old evemu), ``relative`` (seconds from the first event) or ``monotonic`` (host
CLOCK_MONOTONIC, native recordings).  Rebasing epoch times is the engine's job because it
needs every file given together.
"""

from __future__ import annotations

import os
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from mousedom.errors import UserError, located
from mousedom.saferead import NotRegularFile, open_regular
from mousedom.sources.events import AssemblerStats, FrameAssembler


class CaptureError(UserError):
    """A capture file is malformed; the message names file and line (or byte offset)."""


def open_binary(path: str):
    """Open a capture for reading; a missing or unreadable file is a CaptureError."""
    try:
        return open_regular(path)
    except FileNotFoundError:
        raise CaptureError(f"{path}: capture file not found") from None
    except IsADirectoryError:
        raise CaptureError(f"{path}: is a directory, not a capture") from None
    except NotRegularFile as e:
        raise CaptureError(f"{path}: {e.strerror}; a capture is read from a file") from None
    except OSError as e:
        raise CaptureError(f"{path}: cannot read: {e.strerror}") from None


# The longest line a text capture (evemu, libinput record) may hold: theirs are tens of
# bytes (a comment, a device name, a few hundred). The readers carry a partial line from
# one block to the next; one line of hundreds of megabytes was copied again with each
# block read (a 400 MB line: 22-40 s and up to 1.7 GB), so a longer one is refused.
MAX_LINE_BYTES = 1 << 20


def check_line_length(path: str, carry: bytes | memoryview, line: int) -> None:
    """Refuse a partial line carried past MAX_LINE_BYTES (``line``: its number)."""
    if len(carry) > MAX_LINE_BYTES:
        raise CaptureError(
            located(path, line, f"a line longer than {MAX_LINE_BYTES} bytes: not a capture's line")
        )


def check_lines(path: str, block: bytes, first_line: int, end: int | None = None) -> None:
    """Refuse a block of whole lines (``first_line``: the first one's number) holding a
    line longer than MAX_LINE_BYTES, wherever it falls: the same file is taken or
    refused whatever the reader's block size.  From each line start, the last newline
    within the next MAX_LINE_BYTES + 1 bytes is the next start; none there is such a
    line.  Each step is one search in C and passes a whole window but its last line:
    a handful of steps a block.  ``end``: where the lines end (default: the block's)."""
    start, end = 0, len(block) if end is None else end
    while end - start > MAX_LINE_BYTES:
        nl = block.rfind(b"\n", start, start + MAX_LINE_BYTES + 1)
        if nl < 0:
            check_line_length(path, block[start:end], first_line + block.count(b"\n", 0, start))
        start = nl + 1


def bounded_lines(f: Any, path: str, first_line: int) -> Iterator[bytes]:
    """The lines of the binary file ``f`` from where it stands (``first_line``: the first
    one's number), none held past MAX_LINE_BYTES: a longer one is refused."""
    line = first_line
    while raw := f.readline(MAX_LINE_BYTES + 1):
        if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):  # (its newline not counted)
            check_line_length(path, raw, line)
        yield raw
        line += 1


TIME_BASES = ("epoch", "relative", "monotonic")
# No capture time may reach this (in seconds, any base): 317 years of uptime or of a
# recording, past 2286 on the wall clock.  Beyond it float64 seconds lose the microsecond,
# and window grids their meaning.
MAX_TIME_S = 1e10
# evemu writes CLOCK_REALTIME in old recordings: anything past 1973-03-03 is taken as an
# epoch time; kernels up that long are not a concern.
EPOCH_THRESHOLD = 1e8


# What a capture's device is: a mouse read through evdev (its decoded motion reports), a
# serial sensor (its raw bytes), or a gyro read through Linux IIO (its yaw-rate samples).
DEVICE_KINDS = ("evdev", "serial", "iio")
GYRO_KIND = "iio"


@dataclass
class DeviceInfo:
    """One input device of a capture: enough to map it onto a mouse of the config."""

    name: str
    kind: str = "evdev"  # DEVICE_KINDS: "evdev", "serial" or "iio" (a gyro)
    bus: int | None = None
    vendor: int | None = None
    product: int | None = None
    version: int | None = None
    phys: str | None = None
    uniq: str | None = None
    mouse: str | None = None  # the config mouse it was recorded as (native captures)
    rel_xy: bool | None = None  # declares REL_X and REL_Y; None when the capture does not say
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DeviceInfo:
        """A device as a native header holds it; ValueError naming the first field of the
        wrong type (a header is input like any other: ``"extra": 5`` must not reach code
        that takes it for a mapping)."""
        if not isinstance(d, dict):
            raise ValueError(f"a device is {type(d).__name__}, not an object")
        known = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        for key, v in known.items():
            want = _DEVICE_FIELD_TYPES[key]
            if isinstance(v, bool) and bool not in want or not isinstance(v, want):
                names = " or ".join("null" if t is type(None) else t.__name__ for t in want)
                raise ValueError(f"device field {key!r} is {v!r}, not {names}")
        if not known.get("name"):
            raise ValueError("a device has no name")
        if known.get("kind", "evdev") not in DEVICE_KINDS:
            kinds = ", ".join(map(repr, DEVICE_KINDS))
            raise ValueError(f"device kind {known['kind']!r} is not one of {kinds}")
        return cls(**known)


_NONE = type(None)
_DEVICE_FIELD_TYPES: dict[str, tuple[type, ...]] = {
    "name": (str,), "kind": (str,), "bus": (int, _NONE), "vendor": (int, _NONE),
    "product": (int, _NONE), "version": (int, _NONE), "phys": (str, _NONE),
    "uniq": (str, _NONE), "mouse": (str, _NONE), "rel_xy": (bool, _NONE), "extra": (dict,),
}  # fmt: skip


def sec_usec(t: np.ndarray) -> tuple[list[int], list[int]]:
    """Seconds to the (sec, usec) pairs the text formats write, rounded to the microsecond."""
    us = np.round(np.asarray(t, dtype=np.float64) * 1e6).astype(np.int64)
    sec, usec = np.divmod(us, 1_000_000)
    return sec.tolist(), usec.tolist()


# The counters a converted source carries along (native NOTE chunks) and that add up.
SOURCE_COUNTERS = (
    "events",
    "frames",
    "skipped",
    "dropped_frames",
    "dropped_events",
    "lost_x",
    "lost_y",
    "unterminated",
)


@dataclass
class DeviceStats:
    """What a reader saw of one device; filled in while the capture streams."""

    events: int = 0
    frames: int = 0
    reports: int = 0
    skipped: int = 0  # non-motion events: buttons, wheels, MSC_SCAN ...
    dropped_frames: int = 0  # frames discarded because of SYN_DROPPED
    dropped_events: int = 0  # non-SYN events in those frames
    lost_x: int = 0  # counts inside dropped frames
    lost_y: int = 0
    unterminated: int = 0  # events after the last SYN_REPORT at the end (kept: they happened)
    torn_bytes: int = 0  # unreadable tail of a crashed recording
    net_x: int = 0
    net_y: int = 0
    path_x: int = 0
    path_y: int = 0
    first_t: float | None = None
    last_t: float | None = None
    serial_bytes: int = 0
    saturated: int = 0  # a gyro's samples read at its converter's limit

    def add_motion(self, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
        n = len(t)
        if not n:
            return
        self.reports += n
        self.net_x += int(dx.sum())
        self.net_y += int(dy.sum())
        self.path_x += int(np.abs(dx).sum())
        self.path_y += int(np.abs(dy).sum())
        if self.first_t is None:
            self.first_t = float(t[0])
        self.last_t = float(t[-1])

    def take_assembler(self, st: AssemblerStats) -> None:
        """Copy the frame assembler's counters (they are running totals)."""
        self.events = st.events
        self.frames = st.frames
        self.skipped = st.skipped
        self.dropped_frames = st.dropped_frames
        self.dropped_events = st.dropped_events
        self.lost_x = st.dropped_dx
        self.lost_y = st.dropped_dy
        self.unterminated = st.incomplete_events

    def add_rates(self, t: np.ndarray, saturated: np.ndarray | None = None) -> None:
        """A gyro's samples (its ``reports``; motion counts stay 0)."""
        if not len(t):
            return
        self.reports += len(t)
        if saturated is not None:
            self.saturated += int(saturated.sum())
        if self.first_t is None:
            self.first_t = float(t[0])
        self.last_t = float(t[-1])

    def merge(self, other: DeviceStats) -> None:
        """Add counters recorded elsewhere (e.g. a native file's notes of its source)."""
        for name in SOURCE_COUNTERS:
            setattr(self, name, getattr(self, name) + getattr(other, name))

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Motion:
    """Motion reports of one device (index into ``Capture.devices``), evdev convention."""

    device: int
    t: np.ndarray  # float64 seconds, non-decreasing
    dx: np.ndarray  # int64 REL_X sums
    dy: np.ndarray  # int64 REL_Y sums


@dataclass
class Serial:
    """Raw bytes read from a serial source, each piece with its host time of arrival."""

    device: int
    t: np.ndarray  # float64, one per piece
    data: list[bytes]


@dataclass
class Rates:
    """A gyro's samples (native captures): stamps and yaw rates, exactly as recorded."""

    device: int
    t: np.ndarray  # float64 seconds, non-decreasing
    rate: np.ndarray  # float64 rad/s about body z, counter-clockwise positive
    # bool per sample: read at the converter's limit (a bound, not the rate); None: none
    saturated: np.ndarray | None = None


@dataclass
class Batch:
    motion: list[Motion]
    serial: list[Serial]
    complete: float  # all reports of the feed's devices stamped <= this have been yielded
    gyro: list[Rates] = field(default_factory=list)  # a gyro's samples (native captures)


class FrameBatcher:
    """One device's events -> motion Batches, keeping its DeviceStats up to date.

    The text readers (evemu, libinput record) parse events in blocks; this is the part they
    share: grouping into frames (events.FrameAssembler), counting, and the end of input.
    """

    def __init__(self, device: int, stats: DeviceStats) -> None:
        self.device, self.stats = device, stats
        self.asm = FrameAssembler()

    def _motion(self, frames) -> Motion:
        self.stats.add_motion(frames.t, frames.dx, frames.dy)
        self.stats.take_assembler(self.asm.stats)
        return Motion(self.device, frames.t, frames.dx, frames.dy)

    def batch(self, t: np.ndarray, typ: np.ndarray, code: np.ndarray, value: np.ndarray) -> Batch:
        """A block of events (non-decreasing times): everything stamped before its last
        time is complete (a frame may still be open at that time)."""
        motion = self._motion(self.asm.feed(t, typ, code, value))
        return Batch([motion], [], float(np.nextafter(float(t[-1]), -np.inf)))

    def last(self, warnings: list[str], what: str) -> Batch:
        """End of input; a last frame without SYN_REPORT is kept and warned about."""
        motion = self._motion(self.asm.flush())
        if self.stats.unterminated:
            warnings.append(
                f"{what}: the last frame has no SYN_REPORT (truncated recording); "
                "its counts are kept"
            )
        return Batch([motion], [], np.inf)


@dataclass
class Feed:
    devices: tuple[int, ...]
    batches: Iterator[Batch]


def lagging_first(states: list) -> Iterator[tuple[Any, Batch | None]]:
    """Merge feeds by time: yield ``(state, batch)`` always from the state whose
    ``watermark`` lags most among those not ``done``.  A state whose feed has ended is
    marked done and yielded once with ``None``.  The caller moves ``state.watermark``
    (``state.feed`` is a ``Feed``); so memory holds about one batch per feed."""
    while True:
        live = [s for s in states if not s.done]
        if not live:
            return
        st = min(live, key=lambda s: s.watermark)
        batch = next(st.feed.batches, None)
        if batch is None:
            st.done = True
        yield st, batch


class Capture(ABC):
    """A capture file opened for streaming; see the module docstring."""

    format = "capture"

    def __init__(self, path: str, data_path: str | None = None) -> None:
        self.path = path  # what messages name: the user's file
        # What is read: the file itself, or its plain copy (capture.plain: decompressed,
        # line endings repaired), which has the same lines.
        self.data_path = data_path or path
        self.open_warnings: list[str] = []  # said once per feeds(), e.g. a cut-off .gz
        self.devices: list[DeviceInfo] = []
        self.stats: list[DeviceStats] = []
        self.time_base = "relative"
        self.header: dict[str, Any] = {}  # format specific (the native config snapshot)
        self.warnings: list[str] = []
        try:
            self.bytes_total = os.path.getsize(self.data_path)
        except OSError:
            self.bytes_total = 0
        self.bytes_done = 0  # how far the feeds have read (for progress bars)

    @abstractmethod
    def first_time(self) -> float | None:
        """Time of the earliest event (None for a capture without events)."""

    def grid_start(self) -> float | None:
        """Where the recorder's window grid began, for a capture that says (a daemon's
        ``run --record``): replay anchors its windows there, so that they are the
        daemon's; None: anchored at the first event (``first_time``)."""
        return None

    @abstractmethod
    def feeds(self) -> list[Feed]:
        """Fresh iterators over the whole capture (stats are reset)."""

    def reset_stats(self) -> None:
        self.stats = [DeviceStats() for _ in self.devices]
        self.warnings = list(self.open_warnings)
        self.bytes_done = 0


def decimal_field(text: bytes) -> bool:
    """A text capture's integer field as the fast scanners take it: an optional sign and
    ASCII digits.  int() also reads "1_000" (a digit separator no recorder writes) as 1000,
    and Unicode digits in str."""
    return (text[1:] if text[:1] in (b"-", b"+") else text).isdigit()
