"""evemu-record captures (versions 1.0 to 1.3), streamed and parsed with numpy.

The format, as evemu writes it::

    # EVEMU 1.3                          (1.2 and later; older files have no version line)
    # comments ...
    N: <device name>
    I: <bus> <vendor> <product> <version>          (hex)
    P: <property bytes>                            (hex)
    B: <type> <8 bitmask bytes>                    (hex, several lines per type)
    A: <code> <min> <max> <fuzz> <flat> [<res>]     (decimal)
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
    Batch,
    Capture,
    DeviceInfo,
    Feed,
    Motion,
)
from mousedom.errors import UserError, located
from mousedom.events import EV_REL, REL_X, REL_Y, FrameAssembler

KNOWN_VERSIONS = ("1.0", "1.1", "1.2", "1.3")
HEADER_TAGS = (b"N", b"I", b"P", b"B", b"A", b"L", b"S")
BLOCK_BYTES = 4 << 20

_VERSION = re.compile(rb"#\s*EVEMU\s+(\S+)")


class CaptureError(UserError):
    """A capture file is malformed; the message names file and line (or byte offset)."""


class _Events:
    """Parsed event columns of one block (times, types, codes, values, line numbers)."""

    __slots__ = ("t", "typ", "code", "value", "line")

    def __init__(self, t, typ, code, value, line) -> None:
        self.t, self.typ, self.code, self.value, self.line = t, typ, code, value, line

    def __len__(self) -> int:
        return len(self.t)


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
            continue
        tag, sep, rest = line.partition(b":")
        if not sep or tag not in HEADER_TAGS:
            raise CaptureError(located(path, lineno, f"not an evemu header line: {_show(line)}"))
        try:
            if tag == b"N":
                info.name = rest.strip().decode("utf-8", "replace")
            elif tag == b"I":
                bus, vendor, product, version = (int(x, 16) for x in rest.split())
                info.bus, info.vendor, info.product, info.version = bus, vendor, product, version
            elif tag == b"B":
                fields = [int(x, 16) for x in rest.split()]
                if not fields or any(not 0 <= f <= 255 for f in fields):
                    raise ValueError
                saw_bits = True
                if fields[0] == EV_REL:
                    rel_bits += bytes(fields[1:])
            elif tag == b"P":
                [int(x, 16) for x in rest.split()]
            elif tag == b"A":
                [int(x) for x in rest.split()]
        except ValueError:
            raise CaptureError(
                located(path, lineno, f"malformed {tag.decode()}: line: {_show(line)}")
            ) from None
    if saw_bits:
        bits = int.from_bytes(rel_bits[:1] or b"\0", "little")
        info.rel_xy = bool(bits & (1 << REL_X)) and bool(bits & (1 << REL_Y))


def _show(line: bytes) -> str:
    text = line.decode("utf-8", "replace")
    return repr(text if len(text) <= 50 else text[:47] + "...")


# --------------------------------------------------------------------------- event lines


_WS = np.zeros(256, dtype=bool)
_WS[[ord(" "), ord("\t"), ord("\r")]] = True
_HEX = np.full(256, -1, dtype=np.int64)
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"ABCDEF"):
    _HEX[_c] = 10 + _i
_DEC = np.full(256, -1, dtype=np.int64)
for _i, _c in enumerate(b"0123456789"):
    _DEC[_c] = _i


def _digits(b: np.ndarray, begin: np.ndarray, end: np.ndarray, base: int, width: int):
    """Vectorised integer fields b[begin:end] (one per line); None if any is malformed.

    Horner's rule one column at a time: at most ``width`` passes over n-long arrays.
    """
    w = end - begin
    if len(w) and (w.min() < 1 or w.max() > width):
        return None
    lut = _HEX if base == 16 else _DEC
    value = np.zeros(len(begin), dtype=np.int64)
    last = len(b) - 1
    for j in range(int(w.max()) if len(w) else 0):
        digit = lut[b[np.minimum(begin + j, last)]]
        used = j < w
        if ((digit < 0) & used).any():
            return None
        value = np.where(used, value * base + digit, value)
    return value


def _fast_events(block: bytes, first_line: int) -> _Events | None:
    """Parse a block of whole lines when every one is a plain E: line; else None.

    Everything happens on the block's bytes as one numpy array: line starts, the three
    separators of each line (found with searchsorted on the whitespace positions), then
    each field's digits gathered into a (lines x width) matrix.  Anything unusual (a
    comment line, doubled blanks, odd widths) returns None and the careful line-by-line
    parser takes over, so this path only has to be right, never clever about errors.
    """
    b = np.frombuffer(block, dtype=np.uint8)
    nl = np.flatnonzero(b == 10)
    n = len(nl)
    if n == 0 or nl[-1] != len(b) - 1:
        return None
    starts = np.empty(n, dtype=np.int64)
    starts[0] = 0
    starts[1:] = nl[:-1] + 1
    if ((nl - starts) < 11).any():  # "E: 0.0 0 0 0" is the shortest event line
        return None
    if not ((b[starts] == 69) & (b[starts + 1] == 58) & (b[starts + 2] == 32)).all():
        return None
    ws = np.flatnonzero(_WS[b])
    k = np.searchsorted(ws, starts + 3)
    if k.max() + 2 >= len(ws):
        return None
    s1, s2, s3 = ws[k], ws[k + 1], ws[k + 2]
    if not ((s3 < nl) & (b[s1] == 32) & (b[s2] == 32) & (b[s3] == 32)).all():
        return None
    # Value ends at the next blank or the newline; after it only blanks and a comment.
    k4 = k + 3
    s4 = np.where(k4 < len(ws), ws[np.minimum(k4, len(ws) - 1)], len(b))
    vend = np.minimum(s4, nl)
    # After the value: nothing, blanks, or blanks and a comment.
    rest_ok = np.searchsorted(ws, nl) - np.searchsorted(ws, vend) == nl - vend
    if not rest_ok.all():
        ve = vend[~rest_ok]
        hashes = np.flatnonzero(b == 35)
        hi = np.searchsorted(hashes, ve)
        if hi.max() >= len(hashes):
            return None
        h = hashes[hi]
        if not (h < nl[~rest_ok]).all():
            return None
        if not (np.searchsorted(ws, h) - np.searchsorted(ws, ve) == h - ve).all():
            return None
    dots = np.flatnonzero(b == 46)
    di = np.searchsorted(dots, starts + 3)
    if di.max() >= len(dots):
        return None
    dot = dots[di]
    if not (dot < s1).all():
        return None
    sec = _digits(b, starts + 3, dot, 10, 12)
    usec = _digits(b, dot + 1, s1, 10, 9)
    typ = _digits(b, s1 + 1, s2, 16, 4)
    code = _digits(b, s2 + 1, s3, 16, 4)
    neg = b[s3 + 1] == 45
    pos = b[s3 + 1] == 43
    value = _digits(b, s3 + 1 + (neg | pos), vend, 10, 10)
    if sec is None or usec is None or typ is None or code is None or value is None:
        return None
    value = np.where(neg, -value, value)
    if (value < -(2**31)).any() or (value >= 2**31).any():
        return None
    w_usec = s1 - dot - 1
    frac = usec / 1_000_000 if (w_usec == 6).all() else usec / np.power(10.0, w_usec)
    line = np.arange(first_line, first_line + n, dtype=np.int64)
    return _Events(sec + frac, typ, code, value, line)


def _slow_events(path: str, block: bytes, first_line: int, *, at_eof: bool) -> _Events:
    """Parse line by line, naming the first bad line; a torn last line at EOF is skipped."""
    ts, types, codes, values, lines = [], [], [], [], []
    parts = block.split(b"\n")
    for i, raw in enumerate(parts):
        lineno = first_line + i
        line = raw.split(b"#", 1)[0].strip()
        if not line:
            continue
        last = i == len(parts) - 1
        try:
            t, ty, co, va = _event_line(line)
        except ValueError as e:
            if at_eof and last and not block.endswith(b"\n"):
                # A recording cut off mid-line (crash, full disk): the line is lost.
                raise _TornLine(lineno) from None
            if line[:1].isalpha() and line[1:2] == b":" and line[:1] != b"E":
                msg = f"header line {_show(line)} among the events"
            else:
                msg = f"{e}: {_show(line)}"
            raise CaptureError(located(path, lineno, msg)) from None
        ts.append(t)
        types.append(ty)
        codes.append(co)
        values.append(va)
        lines.append(lineno)
    return _Events(
        np.array(ts, np.float64),
        np.array(types, np.int64),
        np.array(codes, np.int64),
        np.array(values, np.int64),
        np.array(lines, np.int64),
    )


class _TornLine(Exception):
    def __init__(self, line: int) -> None:
        self.line = line


def _event_line(line: bytes) -> tuple[float, int, int, int]:
    fields = line.split()
    if fields[0] != b"E:":
        raise ValueError("expected an event line 'E: sec.usec type code value'")
    if len(fields) != 5:
        raise ValueError(f"an event line has 4 fields after E:, this has {len(fields) - 1}")
    sec, dot, usec = fields[1].partition(b".")
    if not sec.isdigit() or (dot and not usec.isdigit()):
        raise ValueError("bad time (want seconds.microseconds)")
    t = int(sec) + (int(usec) / 10 ** len(usec) if usec else 0.0)
    if len(usec) == 6:
        t = int(sec) + int(usec) / 1_000_000
    try:
        ty, co = int(fields[2], 16), int(fields[3], 16)
    except ValueError:
        raise ValueError("type and code must be hexadecimal") from None
    if not (0 <= ty <= 0xFFFF and 0 <= co <= 0xFFFF) or b"_" in fields[2] + fields[3]:
        raise ValueError("type or code out of range")
    try:
        va = int(fields[4], 10)
    except ValueError:
        raise ValueError("value must be a decimal integer") from None
    if not -(2**31) <= va < 2**31:
        raise ValueError("value out of range")
    return t, ty, co, va


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

    def __init__(self, path: str, *, block_bytes: int = BLOCK_BYTES) -> None:
        events_path, desc_path = companion(path)
        super().__init__(events_path)
        self.desc_path = desc_path
        self.block_bytes = block_bytes
        info = DeviceInfo(name=Path(events_path).stem)
        if desc_path:
            lines = _read_lines(desc_path)
            body_at = _first_event_line(lines)
            if body_at < len(lines):
                raise CaptureError(located(desc_path, body_at + 1, "events in a .desc file"))
            _parse_header(desc_path, lines, 1, info)
        with _open(self.path) as f:
            head: list[bytes] = []
            self._body_offset = 0
            for raw in f:
                if raw.lstrip().startswith(b"E:"):
                    break
                head.append(raw)
                self._body_offset += len(raw)
        self._body_line = len(head) + 1
        _parse_header(self.path, head, 1, info)
        self.devices = [info]
        self.reset_stats()
        t0 = self.first_time()
        self.time_base = "epoch" if t0 is not None and t0 > EPOCH_THRESHOLD else "relative"

    def first_time(self) -> float | None:
        with _open(self.path) as f:
            f.seek(self._body_offset)
            for i, raw in enumerate(f):
                line = raw.split(b"#", 1)[0].strip()
                if line:
                    try:
                        return _event_line(line)[0]
                    except ValueError as e:
                        if not raw.endswith(b"\n"):
                            return None
                        raise CaptureError(
                            located(self.path, self._body_line + i, f"{e}: {_show(line)}")
                        ) from None
        return None

    def feeds(self) -> list[Feed]:
        self.reset_stats()
        return [Feed((0,), self._batches())]

    def _blocks(self) -> Iterator[tuple[bytes, int, bool]]:
        """(block of whole lines, number of its first line, at end of file)."""
        with _open(self.path) as f:
            f.seek(self._body_offset)
            line = self._body_line
            carry = b""
            while True:
                buf = f.read(self.block_bytes)
                if not buf:
                    if carry:
                        yield carry, line, True
                    return
                buf = carry + buf
                cut = buf.rfind(b"\n") + 1
                carry = buf[cut:]
                if cut:
                    block = buf[:cut]
                    self.bytes_done += len(block)
                    yield block, line, False
                    line += block.count(b"\n")

    def _batches(self) -> Iterator[Batch]:
        stats = self.stats[0]
        asm = FrameAssembler()
        last_t = -np.inf
        for block, first_line, at_eof in self._blocks():
            ev = None if at_eof else _fast_events(block, first_line)
            if ev is None:
                try:
                    ev = _slow_events(self.path, block, first_line, at_eof=at_eof)
                except _TornLine as torn:
                    stats.torn_bytes += len(block)
                    self.warnings.append(
                        f"{self.path}:{torn.line}: last line cut off (truncated recording); skipped"
                    )
                    continue
            if not len(ev):
                continue
            self._check_time(ev, last_t)
            last_t = float(ev.t[-1])
            fr = asm.feed(ev.t, ev.typ, ev.code, ev.value)
            stats.add_motion(fr.t, fr.dx, fr.dy)
            stats.take_assembler(asm.stats)
            yield Batch([Motion(0, fr.t, fr.dx, fr.dy)], [], float(np.nextafter(last_t, -np.inf)))
        fr = asm.flush()
        stats.add_motion(fr.t, fr.dx, fr.dy)
        stats.take_assembler(asm.stats)
        if stats.unterminated:
            self.warnings.append(
                f"{self.path}: the last frame has no SYN_REPORT (truncated recording); "
                "its counts are kept"
            )
        yield Batch([Motion(0, fr.t, fr.dx, fr.dy)], [], np.inf)

    def _check_time(self, ev: _Events, last_t: float) -> None:
        t = ev.t
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


def _open(path: str):
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise CaptureError(f"{path}: capture file not found") from None
    except IsADirectoryError:
        raise CaptureError(f"{path}: is a directory, not a capture") from None
    except OSError as e:
        raise CaptureError(f"{path}: cannot read: {e.strerror}") from None


def _read_lines(path: str) -> list[bytes]:
    with _open(path) as f:
        return f.read().splitlines(keepends=True)


def _first_event_line(lines: list[bytes]) -> int:
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
    us = np.round(np.asarray(t, dtype=np.float64) * 1e6).astype(np.int64)
    sec, usec = np.divmod(us, 1_000_000)
    cx = "\t# EV_REL / REL_X" if comments else ""
    cy = "\t# EV_REL / REL_Y" if comments else ""
    cs = "\t# ------------ SYN_REPORT (0) ----------" if comments else ""
    for s, u, x, y in zip(sec.tolist(), usec.tolist(), dx.tolist(), dy.tolist(), strict=True):
        stamp = f"E: {s}.{u:06d}"
        if x:
            lines.append(f"{stamp} 0002 0000 {int(x):04d}{cx}")
        if y:
            lines.append(f"{stamp} 0002 0001 {int(y):04d}{cy}")
        lines.append(f"{stamp} 0000 0000 0000{cs}")
    return "\n".join(lines) + "\n"
