"""evemu event lines -> event columns: two vectorised parsers and a careful one.

``fast_events`` parses a whole block of ``E:`` lines on its bytes as one numpy array:
first as evemu writes them (``regular_events``, ``evemu_regular``: fixed offsets from
the decimal point, one optional tab comment), else with any blanks and widths (``general_events``);
``slow_events`` goes line by line and names the first bad line.  Where the compiled core
is built, ``general_events`` runs compiled (csrc/evemu.c) in place of both vectorised
parsers, which stay as the Python core's path and its specification.  The reader tries the
fast one first and falls back to the slow one for any block it refuses, so the fast
paths only have to be right, never clever about errors; the tests check that all agree.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mousedom import core
from mousedom.capture.base import CaptureError, decimal_field
from mousedom.capture.evemu_regular import line_bounds, regular_columns
from mousedom.errors import located


class Events:
    """Parsed event columns of one block (times, types, codes, values, line numbers)."""

    __slots__ = ("t", "typ", "code", "value", "line")

    def __init__(self, t, typ, code, value, line) -> None:
        self.t, self.typ, self.code, self.value, self.line = t, typ, code, value, line

    def __len__(self) -> int:
        return len(self.t)


def _show(line: bytes) -> str:
    text = line.decode("utf-8", "replace")
    return repr(text if len(text) <= 50 else text[:47] + "...")


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


def fast_events(block: bytes | memoryview, first_line: int) -> Events | None:
    """Parse a block of whole lines when every one is a plain E: line; else None.  In the
    compiled core where it is built (csrc/evemu.c: ``general_events`` in one pass)."""
    native = core.native
    if native is not None:
        return native_events(native, block, first_line)
    ev = regular_events(block, first_line)
    return ev if ev is not None else general_events(block, first_line)


def native_events(native: Any, block: bytes | memoryview, first_line: int) -> Events | None:
    """``general_events`` by the compiled core: the same lines taken, the same refused."""
    cap = len(block) // 12  # a line takes at least 12 bytes ("E: 0.0 0 0 0" and newline)
    t = np.empty(cap)
    typ, code, value = (np.empty(cap, dtype=np.int64) for _ in range(3))
    n = native.evemu_events(block, t, typ, code, value)
    if n is None:
        return None
    line = np.arange(first_line, first_line + n, dtype=np.int64)
    return Events(t[:n], typ[:n], code[:n], value[:n], line)


def regular_events(block: bytes | memoryview, first_line: int) -> Events | None:
    """The lines as evemu writes them, parsed at fixed offsets (``evemu_regular``);
    None for anything else (``general_events`` then decides)."""
    columns = regular_columns(block)
    if columns is None:
        return None
    sec, usec, typ, code, value = columns
    line = np.arange(first_line, first_line + len(sec), dtype=np.int64)
    # the same operations as general_events (and the line parser) for six-digit fractions
    return Events(sec + usec / 1_000_000, typ, code, value, line)


def general_events(block: bytes | memoryview, first_line: int) -> Events | None:
    """Parse a block of whole lines when every one is a plain E: line; else None.

    Everything happens on the block's bytes as one numpy array: line starts, the three
    separators of each line (found with searchsorted on the whitespace positions), then
    each field's digits gathered into a (lines x width) matrix.  Anything unusual (a
    comment line, doubled blanks, odd widths) returns None and the careful line-by-line
    parser takes over, so this path only has to be right, never clever about errors.
    """
    b = np.frombuffer(block, dtype=np.uint8)
    lines = line_bounds(b)
    if lines is None:
        return None
    starts, nl = lines
    n = len(nl)
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
    return Events(sec + frac, typ, code, value, line)


def slow_events(path: str, block: bytes, first_line: int, *, at_eof: bool) -> Events:
    """Parse line by line, naming the first bad line; a torn last line at EOF is skipped.

    evemu ends every line with a newline, so at the end of the file (``at_eof``) a last
    line without one was cut off mid-write (crash, full disk, a truncated .gz): TornLine,
    whatever it holds.  It may still read as an event (``E: 0.008 0002 0000 12`` cut from
    ``... 1234``), with a wrong count: it is never kept."""
    ts, types, codes, values, lines = [], [], [], [], []
    parts = block.split(b"\n")
    torn = at_eof and not block.endswith(b"\n")
    for i, raw in enumerate(parts):
        lineno = first_line + i
        line = raw.split(b"#", 1)[0].strip()
        if torn and i == len(parts) - 1 and raw.strip():
            # A recording cut off mid-line: the line is lost (a comment cut off too).
            raise TornLine(lineno)
        if not line:
            continue
        try:
            t, ty, co, va = event_line(line)
        except ValueError as e:
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
    return Events(
        np.array(ts, np.float64),
        np.array(types, np.int64),
        np.array(codes, np.int64),
        np.array(values, np.int64),
        np.array(lines, np.int64),
    )


class TornLine(Exception):
    def __init__(self, line: int) -> None:
        self.line = line


def event_line(line: bytes) -> tuple[float, int, int, int]:
    fields = line.split()
    if fields[0] != b"E:":
        raise ValueError("expected an event line 'E: sec.usec type code value'")
    if len(fields) != 5:
        raise ValueError(f"an event line has 4 fields after E:, this has {len(fields) - 1}")
    sec, dot, usec = fields[1].partition(b".")
    if not sec.isdigit() or (dot and not usec.isdigit()):
        raise ValueError("bad time (want seconds.microseconds)")
    if len(sec.lstrip(b"0")) > 12 or len(usec) > 9:
        # Beyond any clock (12 digits: 31,000 years) and beyond float64's exactness; what
        # the fast path refuses too, so both paths agree.
        raise ValueError("time out of range (at most 12 digits of seconds, 9 of fraction)")
    t = int(sec) + (int(usec) / 10 ** len(usec) if usec else 0.0)
    if len(usec) == 6:
        t = int(sec) + int(usec) / 1_000_000
    try:
        ty, co = int(fields[2], 16), int(fields[3], 16)
    except ValueError:
        raise ValueError("type and code must be hexadecimal") from None
    if not (0 <= ty <= 0xFFFF and 0 <= co <= 0xFFFF) or b"_" in fields[2] + fields[3]:
        raise ValueError("type or code out of range")
    value = fields[4]
    if not decimal_field(value):
        raise ValueError("value must be a decimal integer")
    # Its significant digits counted before int(): past 4300 digits (leading zeros too)
    # int() refuses with Python's own advice (sys.set_int_max_str_digits), no help to
    # whoever holds the file; and more than 10 of them are past 2**31 anyway.
    digits = (value[1:] if value[:1] in (b"-", b"+") else value).lstrip(b"0") or b"0"
    va = (-1 if value[:1] == b"-" else 1) * int(digits) if len(digits) <= 10 else None
    if va is None or not -(2**31) <= va < 2**31:
        raise ValueError("value beyond the signed 32 bits of an input_event value")
    return t, ty, co, va
