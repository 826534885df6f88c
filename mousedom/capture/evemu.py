"""evemu-record captures (versions 1.0 to 1.3), streamed and parsed with numpy.

The format, as evemu writes it::

    # EVEMU 1.3                          (1.2 and later; older files have no version line)
    # comments ...
    N: <device name>
    I: <bus> <vendor> <product> <version>          (hex)
    P: <property bytes>                            (hex)
    B: <type> <8 bitmask bytes>                    (hex, several lines per type)
    A: <code> <min> <max> <fuzz> <flat> [<res>]     (code hex, the rest decimal)
    E: <sec>.<usec> <type> <code> <value>[\\t# comment]   (type, code hex; value decimal)

Times are absolute (CLOCK_REALTIME, old recordings) or relative to the first event.
Old recordings split the description (``.desc``) from the events (``.events``); given one
of the pair, the other is picked up from beside it.  Values may carry leading zeros
(``-013`` is minus thirteen).  Frames are grouped by SYN_REPORT, never by timestamp.

Speed: a block of event lines is checked and converted in a few C-level passes (bytes
split, numpy string-to-int), which is what makes 300 k reports/s possible; any block that
fails the quick checks is parsed again line by line to name the exact line at fault.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from mousedom.capture.base import (
    EPOCH_THRESHOLD,
    MAX_TIME_S,
    Batch,
    Capture,
    CaptureError,
    DeviceInfo,
    Feed,
    FrameBatcher,
    bounded_lines,
    check_line_length,
    check_lines,
    sec_usec,
)
from mousedom.capture.base import open_binary as _open
from mousedom.capture.evemu_lines import Events as _Events  # noqa: F401 (tests use it)
from mousedom.capture.evemu_lines import TornLine as _TornLine
from mousedom.capture.evemu_lines import _show, event_line
from mousedom.capture.evemu_lines import fast_events as _fast_events
from mousedom.capture.evemu_lines import slow_events as _slow_events
from mousedom.capture.plain import BOM
from mousedom.errors import located
from mousedom.sources.events import EV_REL, REL_X, REL_Y

KNOWN_VERSIONS = ("1.0", "1.1", "1.2", "1.3")
HEADER_TAGS = (b"N", b"I", b"P", b"B", b"A", b"L", b"S")
BLOCK_BYTES = 4 << 20

_VERSION = re.compile(rb"#\s*EVEMU\s+(\S+)")


# --------------------------------------------------------------------------- header


def _parse_header(path: str, lines: list[bytes], first_line: int, info: DeviceInfo) -> None:
    """Fill ``info`` from header lines; raise CaptureError naming the line at fault."""
    rel_bits = b""
    saw_bits = False
    for i, raw in enumerate(lines):
        lineno = first_line + i
        line = raw.rstrip(b"\r\n")
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith(b"#"):
            _read_comment(path, lineno, stripped, info)
            continue
        tag, sep, rest = line.partition(b":")
        if not sep or tag not in HEADER_TAGS:
            raise CaptureError(located(path, lineno, f"not an evemu header line: {_show(line)}"))
        try:
            field_bits = _read_field(tag, rest, info)
        except ValueError:
            raise CaptureError(
                located(path, lineno, f"malformed {tag.decode()}: line: {_show(line)}")
            ) from None
        if field_bits is not None:
            saw_bits = True
            rel_bits += field_bits
    if saw_bits:
        bits = int.from_bytes(rel_bits[:1] or b"\0", "little")
        info.rel_xy = bool(bits & (1 << REL_X)) and bool(bits & (1 << REL_Y))


def _read_comment(path: str, lineno: int, stripped: bytes, info: DeviceInfo) -> None:
    """A comment line: only ``# EVEMU <version>`` says something (a version this reader
    must know)."""
    m = _VERSION.match(stripped)
    if m:
        version = m.group(1).decode("ascii", "replace")
        if version not in KNOWN_VERSIONS:
            raise CaptureError(
                located(
                    path,
                    lineno,
                    f"unknown evemu version {version} (this reader knows "
                    f"{', '.join(KNOWN_VERSIONS)})",
                )
            )
        info.extra["evemu_version"] = version


def _read_field(tag: bytes, rest: bytes, info: DeviceInfo) -> bytes | None:
    """One header line's field into ``info`` (ValueError if malformed).  A ``B:`` line
    returns its EV_REL bit bytes (none for another event type); any other line None."""
    if tag == b"N":
        info.name = rest.strip().decode("utf-8", "replace")
    elif tag == b"I":
        bus, vendor, product, version = (int(x, 16) for x in rest.split())
        info.bus, info.vendor, info.product, info.version = bus, vendor, product, version
    elif tag == b"B":
        fields = [int(x, 16) for x in rest.split()]
        if not fields or any(not 0 <= f <= 255 for f in fields):
            raise ValueError
        return bytes(fields[1:]) if fields[0] == EV_REL else b""
    elif tag == b"P":
        [int(x, 16) for x in rest.split()]
    elif tag == b"A":
        # evemu writes "A: %02x %d %d %d %d %d": the axis code in hex, then
        # min, max, fuzz, flat (and resolution) in decimal.
        code, *limits = rest.split()
        int(code, 16)
        [int(x) for x in limits]
    return None


# --------------------------------------------------------------------------- the capture


def companion(path: str) -> tuple[str, str | None]:
    """(events file, description file or None) for a path naming either of a pair."""
    p = Path(path)
    if p.suffix == ".desc":
        ev = p.with_suffix(".events")
        if not ev.exists():
            raise CaptureError(f"{path}: a .desc file holds no events and {ev.name} is missing")
        return str(ev), str(p)
    if p.suffix == ".events":
        desc = p.with_suffix(".desc")
        if desc.exists():
            return str(p), str(desc)
    return str(p), None


class EvemuCapture(Capture):
    format = "evemu"

    def __init__(
        self, path: str, *, block_bytes: int = BLOCK_BYTES, data_path: str | None = None
    ) -> None:
        events_path, desc_path = companion(path)
        super().__init__(events_path, data_path)
        self.desc_path = desc_path
        self.block_bytes = block_bytes
        info = DeviceInfo(name=Path(events_path).stem)
        if desc_path:
            lines = _read_lines(desc_path)
            body_at = _firstevent_line(lines)
            if body_at < len(lines):
                raise CaptureError(located(desc_path, body_at + 1, "events in a .desc file"))
            _parse_header(desc_path, lines, 1, info)
        with _open(self.data_path) as f:
            head: list[bytes] = []
            self._body_offset = 0
            for raw in bounded_lines(f, self.path, 1):
                if raw.lstrip().startswith(b"E:"):
                    break
                head.append(raw)
                self._body_offset += len(raw)
                if self._body_offset > MAX_DESC_BYTES:  # (held whole: bounded as a .desc is)
                    raise CaptureError(located(self.path, len(head), f"more than "
                                       f"{MAX_DESC_BYTES} bytes before the first event: "
                                       "not an evemu recording"))  # fmt: skip
        self._body_line = len(head) + 1
        if not desc_path and not b"".join(head).strip() and self._body_offset == self.bytes_total:
            # Nothing at all, not even a header: a recording that never started, or the
            # wrong file; replaying it would print a CSV without a pose and exit 0.
            raise CaptureError(f"{self.path}: empty file (no evemu header and no events)")
        _parse_header(self.path, head, 1, info)
        self.devices = [info]
        self.reset_stats()
        t0 = self.first_time()
        self.time_base = "epoch" if t0 is not None and t0 > EPOCH_THRESHOLD else "relative"

    def first_time(self) -> float | None:
        with _open(self.data_path) as f:
            f.seek(self._body_offset)
            for i, raw in enumerate(bounded_lines(f, self.path, self._body_line)):
                line = raw.split(b"#", 1)[0].strip()
                if line:
                    if not raw.endswith(b"\n"):
                        return None  # the last line, cut off: skipped (_batches warns)
                    try:
                        return event_line(line)[0]
                    except ValueError as e:
                        raise CaptureError(
                            located(self.path, self._body_line + i, f"{e}: {_show(line)}")
                        ) from None
        return None

    def feeds(self) -> list[Feed]:
        self.reset_stats()
        return [Feed((0,), self._batches())]

    def _blocks(self) -> Iterator[tuple[bytes | memoryview, bool]]:
        """(block of whole lines, at end of file); the last may lack its newline.  A block
        is a view of what was read, not a copy (the vectorised parsers read it as is)."""
        with _open(self.data_path) as f:
            f.seek(self._body_offset)
            carry = b""
            line = self._body_line  # the carried line's number
            while True:
                buf = f.read(self.block_bytes)
                if not buf:
                    if carry:
                        yield carry, True
                    return
                buf = carry + buf
                cut = buf.rfind(b"\n") + 1
                carry = buf[cut:]
                if cut:
                    check_lines(self.path, buf, line, cut)
                    self.bytes_done += cut
                    line += buf.count(b"\n", 0, cut)
                    yield memoryview(buf)[:cut], False
                check_line_length(self.path, carry, line)

    def _batches(self) -> Iterator[Batch]:
        stats = self.stats[0]
        frames = FrameBatcher(0, stats)
        last_t = -np.inf
        first_line = self._body_line
        for block, at_eof in self._blocks():
            ev = None if at_eof else _fast_events(block, first_line)
            if ev is not None:
                lines = len(ev)  # the fast parsers take blocks of E: lines only
            else:
                block = bytes(block)
                lines = block.count(b"\n")
                try:
                    ev = _slow_events(self.path, block, first_line, at_eof=at_eof)
                except _TornLine as torn:
                    stats.torn_bytes += len(block)
                    self.warnings.append(
                        f"{self.path}:{torn.line}: last line cut off (truncated recording); skipped"
                    )
                    first_line += lines
                    continue
            first_line += lines
            if not len(ev):
                continue
            self._check_time(ev, last_t)
            last_t = float(ev.t[-1])
            yield frames.batch(ev.t, ev.typ, ev.code, ev.value)
        yield frames.last(self.warnings, self.path)

    def _check_time(self, ev: _Events, last_t: float) -> None:
        t = ev.t
        if t[-1] >= MAX_TIME_S and t[0] >= last_t and not (np.diff(t) < 0).any():
            k = int(np.argmax(t >= MAX_TIME_S))  # in order: the first one past the bound
            raise CaptureError(
                located(self.path, int(ev.line[k]), f"time {t[k]:.6f} s is past "
                        f"{MAX_TIME_S:g} s (year 2286): not a time any clock gives")
            )  # fmt: skip
        if t[0] >= last_t and (len(t) < 2 or not (np.diff(t) < 0).any()):
            return
        prev = np.concatenate([[last_t], t[:-1]])
        k = int(np.flatnonzero(t < prev)[0])
        line = int(ev.line[k])
        raise CaptureError(
            located(
                self.path,
                line,
                f"time goes backwards ({t[k]:.6f} after {prev[k]:.6f}); "
                "a recording must be in time order",
            )
        )


MAX_DESC_BYTES = 1 << 20  # a device description is a few kilobytes


def _read_lines(path: str) -> list[bytes]:
    """A .desc file's lines, its UTF-8 byte order mark dropped (as in every text capture)."""
    with _open(path) as f:
        data = f.read(MAX_DESC_BYTES + 1)
    if len(data) > MAX_DESC_BYTES:
        raise CaptureError(f"{path}: larger than {MAX_DESC_BYTES} bytes: not a device description")
    return data.removeprefix(BOM).splitlines(keepends=True)


def _firstevent_line(lines: list[bytes]) -> int:
    for i, raw in enumerate(lines):
        if raw.lstrip().startswith(b"E:"):
            return i
    return len(lines)


# --------------------------------------------------------------------------- writing


def format_evemu(
    t: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    *,
    name: str = "mousedom simulated mouse",
    version: str | None = "1.3",
    ids: tuple[int, int, int, int] = (0x03, 0x046D, 0xC077, 0x0111),
    comments: bool = False,
) -> str:
    """An evemu recording of motion reports (one frame per report), as evemu writes it.

    ``version=None`` writes an old-style body without header.  Used by tests, benches and
    the demo; times are written as given (relative or epoch).
    """
    lines = []
    if version is not None:
        lines += [
            f"# EVEMU {version}",
            f'# Input device name: "{name}"',
            f"N: {name}",
            "I: " + " ".join(f"{i:04x}" for i in ids),
            "P: 00 00 00 00 00 00 00 00",
            "B: 00 0b 00 00 00 00 00 00 00",
            "B: 01 00 00 00 00 00 00 00 00",
            "B: 01 00 00 07 00 00 00 00 00",
            "B: 02 03 01 00 00 00 00 00 00",
        ]
    sec, usec = sec_usec(t)
    cx = "\t# EV_REL / REL_X" if comments else ""
    cy = "\t# EV_REL / REL_Y" if comments else ""
    cs = "\t# ------------ SYN_REPORT (0) ----------" if comments else ""
    for s, u, x, y in zip(sec, usec, dx.tolist(), dy.tolist(), strict=True):
        stamp = f"E: {s}.{u:06d}"
        if x:
            lines.append(f"{stamp} 0002 0000 {int(x):04d}{cx}")
        if y:
            lines.append(f"{stamp} 0002 0001 {int(y):04d}{cy}")
        lines.append(f"{stamp} 0000 0000 0000{cs}")
    return "\n".join(lines) + "\n"
