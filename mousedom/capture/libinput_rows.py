"""The event rows of a ``libinput record`` file: a block of whole lines of an event list
read into arrays, and, when the quick checks fail, the line at fault named.

A row is ``- [sec, usec, type, code, value]``, one per line as the recorder writes them,
or several in a flow list (``- evdev: [[...], [...]]``) as other writers do; comments and
the lines of hid and libinput entries are skipped.
"""

from __future__ import annotations

import re
import warnings
from typing import NoReturn

import numpy as np

from mousedom.capture.base import CaptureError, DeviceStats, decimal_field
from mousedom.errors import escaped, located

# Seconds since the start of a recording: a century is far past any real one, and keeps
# every time exact in float64 and the window arithmetic bounded.
MAX_SECONDS = 3_155_760_000

_COMMENT = re.compile(rb"[ \t]*#[^\n]*")
_ROW = re.compile(rb"(?m)^[ \t]*- \[([^\]\n]*)\][ \t]*$")
_ROW_C = re.compile(rb"(?m)^[ \t]*- \[([^\]\n]*)\][ \t]*(?:#[^\n]*)?$")  # with a comment
# Lines allowed in an event list besides rows: "- evdev:", "- hid:", keys of hid and
# libinput entries, blanks (comments are stripped first).
# An ``evdev:`` key with anything after it is not "other": it holds events (flow style).
# ``- {time: ..., type: POINTER_MOTION, ...}``: an entry of a ``- libinput:`` list
# (``libinput record --with-libinput``), never an evdev event.
_OTHER = re.compile(
    rb"(?m)^(?:[ \t]*- \[[^\]\n]*\][ \t]*"
    rb"|[ \t]*(?:- )?(?!evdev:[ \t]*[^ \t\n])[A-Za-z_][\w-]*:.*"
    rb"|[ \t]*- \{.*\}[ \t]*|[ \t]*)$"
)
# Flow style, as YAML allows and other writers produce: ``- evdev: [[0, 10, 2, 0, 1], ...]``.

_FLOW_HINT = re.compile(rb"evdev:[ \t]*\[")
_FLOW = re.compile(rb"(?m)^[ \t]*- evdev:[ \t]*\[(.*)\][ \t]*$")
_FLOW_ROW = re.compile(rb"\[([^\[\]\n]*)\]")


# A row's five fields, each at most 32 characters (``_row_ok``), with separators and
# spaces: a longer one is refused before the array checks.
MAX_ROW_BYTES = 256


def parse_rows(
    path: str, block: bytes, line: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, type, code, value) arrays of the evdev rows of a block of whole lines."""
    rows = _ROW_C.findall(block)
    flow = _FLOW_HINT.search(block) is not None
    # Quick check: every line is a row or "- evdev:"; else look at each line closely.
    if flow or len(rows) + block.count(b"- evdev:") != block.count(b"\n"):
        text = _COMMENT.sub(b"", block) if b"#" in block else block
        if flow:
            text = _FLOW.sub(_flow_rows, text)
        if len(_OTHER.sub(b"", text).strip()) != 0:
            complain(path, block, line)
        rows = _ROW.findall(text)
    n = len(rows)
    if n == 0:
        e = np.empty(0, np.int64)
        return np.empty(0, np.float64), e, e, e
    if max(map(len, rows)) > MAX_ROW_BYTES:
        # (no valid row is this long: _row_ok names it; the vectorised checks below cost
        # about 21 times a row's size, 2.6 GB for one 120 MB field)
        complain(path, block, line)
    joined = b",".join(rows)
    try:
        if not _every_field_has_a_digit(joined):
            # numpy reads a blank field, or a lone "+" or "-", as 0: "[1, , 0, 0, 5]"
            raise ValueError
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            a = np.fromstring(joined, dtype=np.int64, sep=",")
    except (ValueError, DeprecationWarning):
        a = None
    if a is None or len(a) != 5 * n:
        complain(path, block, line)
    a = a.reshape(n, 5)
    if (
        (a[:, :4] < 0).any()
        or (a[:, 0] >= MAX_SECONDS).any()
        or (a[:, 2:4] > 0xFFFF).any()
        or (a[:, 1] >= 1_000_000).any()
        or (a[:, 4] < -(2**31)).any()  # an evdev value is a signed 32-bit integer
        or (a[:, 4] >= 2**31).any()
    ):
        complain(path, block, line)
    return a[:, 0] + a[:, 1] / 1_000_000, a[:, 2], a[:, 3], a[:, 4]


def complain(path: str, block: bytes, line: int) -> NoReturn:
    """Find the first bad line of a block that failed the quick checks, and say so."""
    for i, raw in enumerate(block.split(b"\n")):
        text = _COMMENT.sub(b"", raw)
        m = _ROW.match(text)
        flow = _FLOW.match(text)
        if m or flow:
            if flow and _FLOW_ROW.sub(b"", flow.group(1)).replace(b",", b"").strip():
                raise CaptureError(
                    located(path, line + i, f"malformed evdev event list: {_show(raw)}")
                )
            rows = [m.group(1)] if m else _FLOW_ROW.findall(flow.group(1)) if flow else []
            for row in rows:
                if not _row_ok(row):
                    raise CaptureError(
                        located(
                            path,
                            line + i,
                            "an evdev event must be [sec, usec, type, code, value] "
                            "(non-negative integers, but the value: a signed 32-bit "
                            f"one), got [{_show(row)}]",
                        )
                    )
        elif not _OTHER.fullmatch(text):
            raise CaptureError(located(path, line + i, f"unexpected line in events: {_show(raw)}"))
    raise CaptureError(located(path, line, "malformed events"))


def cut_torn_tail(
    path: str, block: bytes, line: int, stats: DeviceStats, messages: list[str]
) -> bytes:
    """The file's last line without a newline: a recording cut off mid-row (crash, full
    disk) loses that row only, with a warning, as in evemu; a whole row is kept."""
    head, nl, tail = block.rpartition(b"\n")
    text = _COMMENT.sub(b"", tail)
    m = _ROW.match(text)
    if not tail.strip() or (m and _row_ok(m.group(1))) or _OTHER.fullmatch(text):
        return block
    stats.torn_bytes += len(tail)
    at = line + head.count(b"\n") + bool(nl)
    messages.append(f"{path}:{at}: last line cut off (truncated recording); skipped")
    return head + nl


def backwards(path: str, block: bytes, line: int, last_t: float) -> NoReturn:
    """Name the row at which time goes backwards (the block is known to hold one)."""
    prev = last_t
    for i, raw in enumerate(block.split(b"\n")):
        text = _COMMENT.sub(b"", raw)
        m = _ROW.match(text)
        flow = None if m else _FLOW.match(text)
        rows = [m.group(1)] if m else _FLOW_ROW.findall(flow.group(1)) if flow else []
        for row in rows:
            sec, usec = (int(x) for x in row.split(b",")[:2])
            t = sec + usec / 1_000_000
            if t < prev:
                raise CaptureError(
                    located(
                        path,
                        line + i,
                        f"time goes backwards ({t:.6f} after {prev:.6f}); "
                        "a recording must be in time order",
                    )
                )
            prev = t
    raise AssertionError("unreachable: no backwards step found")  # pragma: no cover


def _every_field_has_a_digit(joined: bytes) -> bool:
    """Whether each comma-separated field holds a digit.  numpy's fromstring refuses
    letters and stray signs inside a number, but reads a field that is blank, or only a
    sign, as 0: a silent REL_X of 0.  One vectorised pass (a regular expression over the
    block would cost 30 times the parse)."""
    b = np.frombuffer(joined, dtype=np.uint8)
    digits = np.concatenate([[0], np.cumsum((b >= 48) & (b <= 57))])
    commas = np.flatnonzero(b == 44)
    starts = np.concatenate([[0], commas + 1])
    ends = np.concatenate([commas, [len(b)]])
    return bool((digits[ends] - digits[starts] > 0).all())


def _row_ok(row: bytes) -> bool:
    fields = [x.strip() for x in row.split(b",")]
    if len(fields) != 5:
        return False
    # (and no more digits than a 32-bit value's with leading zeros: int() refuses 4,300)
    if not all(decimal_field(x) and len(x) <= 32 for x in fields):
        return False
    vals = [int(x) for x in fields]
    return (
        min(vals[:4]) >= 0
        and vals[0] < MAX_SECONDS
        and vals[1] < 1_000_000
        and vals[2] <= 0xFFFF
        and vals[3] <= 0xFFFF
        and -(2**31) <= vals[4] < 2**31
    )


def _flow_rows(m: re.Match[bytes]) -> bytes:
    """A flow-style event list -> the same rows in block style, one per line (only the
    rows are read from this text; messages come from the original lines)."""
    inner = m.group(1)
    if _FLOW_ROW.sub(b"", inner).replace(b",", b"").strip():
        return m.group(0)  # not plain rows: _OTHER refuses it, complain names the line
    return b"\n".join(b"- [" + r + b"]" for r in _FLOW_ROW.findall(inner))


def _show(raw: bytes) -> str:
    """A piece of a line for a message: control characters escaped (a raw \\x1c or \\r
    would end or garble the message's line in a terminal)."""
    text = raw.decode("utf-8", "replace").strip()
    return escaped(text if len(text) <= 50 else text[:47] + "...")
