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
import warnings
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

_COMMENT = re.compile(rb"[ \t]*#[^\n]*")
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


def _fast_events(block: bytes, first_line: int) -> _Events | None:
    """Parse a block of complete lines if every line is a well-formed E: line; else None."""
    text = _COMMENT.sub(b"", block) if b"#" in block else block
    n = text.count(b"\n")
    if n == 0 or (b"\n" + text).count(b"\nE:") != n:
        return None
    tok = text.replace(b".", b" ").split()
    if len(tok) != 6 * n or tok[0::6].count(b"E:") != n:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            sec = np.fromstring(b" ".join(tok[1::6]), dtype=np.int64, sep=" ")
            usec = np.fromstring(b" ".join(tok[2::6]), dtype=np.int64, sep=" ")
            value = np.fromstring(b" ".join(tok[5::6]), dtype=np.int64, sep=" ")
    except (ValueError, DeprecationWarning):
        return None
    if len(sec) != n or len(usec) != n or len(value) != n:
        return None
    usec_tok = tok[2::6]
    lengths = set(map(len, usec_tok))
    if lengths == {6}:
        frac = usec / 1_000_000
    else:
        if any(not x.isdigit() for x in usec_tok) or any(not x.isdigit() for x in tok[1::6]):
            return None
        frac = usec / np.power(10.0, np.fromiter(map(len, usec_tok), np.int64, n))
    if (sec < 0).any() or (usec < 0).any():
        return None
    keys = list(zip(tok[3::6], tok[4::6], strict=False))
    mapping = {}
    try:
        for k in set(keys):
            ty, co = int(k[0], 16), int(k[1], 16)
            if not (0 <= ty <= 0xFFFF and 0 <= co <= 0xFFFF) or b"_" in k[0] + k[1]:
                return None
            mapping[k] = ty << 16 | co
    except ValueError:
        return None
    packed = np.fromiter(map(mapping.__getitem__, keys), dtype=np.int64, count=n)
    if (value < -(2**31)).any() or (value >= 2**31).any():
        return None
    line = np.arange(first_line, first_line + n, dtype=np.int64)
    return _Events(sec + frac, packed >> 16, packed & 0xFFFF, value, line)


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
