"""``libinput record`` captures: YAML, several devices per file, events streamed.

The shape (libinput-record(1), FILE FORMAT)::

    version: 1
    ndevices: 2
    libinput: {version: ...}
    system: {...}
    devices:
      - node: /dev/input/event9
        evdev:
          name: ...
          id: [bus, vendor, product, version]
          codes: {0: [...], 1: [...], 2: [0, 1, 8, ...]}
        udev: {...}
        events:
          - evdev:
            - [  0,  11879,   2,   0,    -3] # EV_REL / REL_X  -3
            - [  0,  11879,   0,   0,     0] # ------------ SYN_REPORT (0) ------- +0ms
          - hid: {...}                       (and libinput entries: ignored)
      - node: ...                            (the next device, its events after its header)

Devices follow one another, each with its own event list, with times in seconds and
microseconds since the start of the recording (one time base for all devices).  PyYAML
reads only the small device headers; the event lists (nearly all of a large file) are
found by regular expressions and converted with numpy, one device at a time, from its own
byte range, so devices can be merged by time in bounded memory.  Mice are the devices
whose codes include EV_REL with REL_X and REL_Y.
"""

from __future__ import annotations

import re
import warnings
import weakref
from collections.abc import Iterator

import numpy as np
import yaml

from mousedom import safeyaml
from mousedom.capture.base import (
    Batch,
    Capture,
    CaptureError,
    DeviceInfo,
    Feed,
    FrameBatcher,
    sec_usec,
)
from mousedom.capture.base import open_binary as _open
from mousedom.capture.libinput_layout import relayout
from mousedom.capture.plain import discard
from mousedom.errors import located
from mousedom.sources.events import EV_REL, REL_X, REL_Y

KNOWN_VERSIONS = (1,)
# Seconds since the start of a recording: a century is far past any real one, and keeps
# every time exact in float64 and the window arithmetic bounded.
MAX_SECONDS = 3_155_760_000
BLOCK_BYTES = 4 << 20

_DEVICE = re.compile(rb"(?m)^[ \t]*- node[ \t]*:")
# What the line scan cannot read (capture.libinput_layout re-lays such files out): a
# device written as a flow mapping, an event row as a block list ("- - 0").
_FLOW_DEVICE = re.compile(rb"(?m)^[ \t]*- \{[ \t]*[\"']?node[\"']?[ \t]*:")
_BLOCK_ROW = re.compile(rb"(?m)^[ \t]*- - ")
_EVENTS = re.compile(rb"(?m)^[ \t]+events:[ \t]*(?:#.*)?$")
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
# A top-level key after the devices began: a second recording appended (``cat a.yml b.yml``).
_TOP = re.compile(rb"(?m)^(?:version|ndevices|libinput|system|devices):")


def looks_like_libinput(prefix: bytes) -> bool:
    head = prefix.lstrip()
    return (
        head.startswith(b"# libinput record")
        or (re.search(rb"(?m)^version:\s*\d", prefix) is not None and b"devices:" in prefix)
        or re.search(rb"(?m)^ndevices:", prefix) is not None
        # one flow mapping (or JSON) of the same document
        or re.match(rb"\s*\{\s*[\"']?(?:devices|version|ndevices)[\"']?\s*:", head) is not None
        # re-dumped with sorted keys: "devices:" first, version and ndevices at the end
        or (
            re.search(rb"(?m)^devices:", prefix) is not None
            and re.search(rb"(?m)^[ \t-]*evdev:", prefix) is not None
        )
    )


class _Span:
    """Byte range of one device: header [start, events) and event list [events, end)."""

    def __init__(self, start: int) -> None:
        self.start = start
        self.events: int | None = None
        self.end: int | None = None
        self.first_line = 0
        self.events_line = 0


class LibinputCapture(Capture):
    format = "libinput"

    def __init__(
        self, path: str, *, block_bytes: int = BLOCK_BYTES, data_path: str | None = None
    ) -> None:
        super().__init__(path, data_path)
        self.block_bytes = block_bytes
        self.time_base = "relative"
        self._spans = self._index()
        top_text, top = self._top()
        if self._other_layout(top):
            # The same YAML in another layout (see capture.libinput_layout): read through a
            # copy in the recorder's own layout, removed with this capture.
            copy = relayout(path, self.data_path)
            weakref.finalize(self, discard, copy)
            self.data_path = copy
            self._spans = self._index()
            top_text, top = self._top()
        version = top.get("version")
        if version not in KNOWN_VERSIONS:
            raise CaptureError(
                located(
                    path,
                    _line_of(top_text, b"version:"),
                    f"unknown libinput record version {version!r} (this reader knows 1)",
                )
            )
        self.header = {k: v for k, v in top.items() if k != "devices"}
        for span in self._spans:
            self.devices.append(self._device(span))
        if not self.devices:
            raise CaptureError(located(path, None, "no devices in this libinput recording"))
        self.reset_stats()

    # ----------------------------------------------------------------- structure

    def _top(self) -> tuple[bytes, dict]:
        """The text before the first device and its YAML (the whole file if no device)."""
        with _open(self.data_path) as f:
            top_text = f.read(self._spans[0].start if self._spans else self._size)
        top = self._yaml(top_text, 1)
        if not isinstance(top, dict):
            raise CaptureError(located(self.path, 1, "not a libinput record file (no top mapping)"))
        return top_text, top

    def _other_layout(self, top: dict) -> bool:
        """Whether the line scan missed what the document holds: devices where it found
        none, fewer or more than ``ndevices``, a device as a flow mapping, rows as block
        lists."""
        if not self._spans:
            return bool(top.get("devices"))
        n = top.get("ndevices")
        if isinstance(n, int) and not isinstance(n, bool) and n != len(self._spans):
            return True
        with _open(self.data_path) as f:
            f.seek(self._spans[0].start)
            head = f.read(1 << 16)
        return bool(_FLOW_DEVICE.search(head) or _BLOCK_ROW.search(head))

    def _index(self) -> list[_Span]:
        spans: list[_Span] = []
        line = 1
        offset = 0
        with _open(self.data_path) as f:
            carry = b""
            while True:
                buf = f.read(self.block_bytes)
                eof = not buf
                buf = carry + buf
                cut = len(buf) if eof else buf.rfind(b"\n") + 1
                block, carry = buf[:cut], buf[cut:]
                if eof and not block:
                    break
                marks = sorted(
                    [(m.start(), 0) for m in _DEVICE.finditer(block)]
                    + [(m.start(), 1) for m in _EVENTS.finditer(block)]
                    + [(m.start(), 2) for m in _TOP.finditer(block)]
                )
                for pos, kind in marks:
                    at_line = line + block.count(b"\n", 0, pos)
                    if kind == 2:
                        if spans:
                            raise CaptureError(
                                located(
                                    self.path,
                                    at_line,
                                    "a second recording starts here (files joined with cat?); "
                                    "their times have no common base: give each file its "
                                    "own --capture",
                                )
                            )
                        continue
                    if kind == 0:
                        if spans:
                            spans[-1].end = offset + pos
                        span = _Span(offset + pos)
                        span.first_line = at_line
                        spans.append(span)
                    elif spans and spans[-1].events is None:
                        nl = block.find(b"\n", pos)
                        spans[-1].events = offset + (nl + 1 if nl >= 0 else len(block))
                        spans[-1].events_line = at_line + 1
                line += block.count(b"\n")
                offset += len(block)
                if eof:
                    break
        self._size = offset
        if spans:
            spans[-1].end = offset
        for s in spans:
            if s.events is None:
                s.events = s.end
                s.events_line = 0
        return spans

    def _yaml(self, text: bytes, first_line: int):
        try:
            return safeyaml.load(text)
        except yaml.MarkedYAMLError as e:
            mark = e.problem_mark or e.context_mark
            line = first_line + mark.line if mark else None
            raise CaptureError(located(self.path, line, f"invalid YAML: {e.problem}")) from None
        except yaml.YAMLError as e:
            raise CaptureError(located(self.path, first_line, f"invalid YAML: {e}")) from None

    def _device(self, span: _Span) -> DeviceInfo:
        with _open(self.data_path) as f:
            f.seek(span.start)
            text = f.read(span.events - span.start)
        # The header is a one-item YAML list ("- node: ..."): drop its indentation.
        indent = len(text) - len(text.lstrip(b" \t"))
        lines = [ln[indent:] if ln[:indent].strip() == b"" else ln for ln in text.split(b"\n")]
        items = self._yaml(b"\n".join(lines), span.first_line)
        item = items[0] if isinstance(items, list) and items else None
        if not isinstance(item, dict):
            raise CaptureError(located(self.path, span.first_line, "malformed device entry"))
        evdev = item.get("evdev") or {}
        if not isinstance(evdev, dict):
            raise CaptureError(located(self.path, span.first_line, "device evdev: not a mapping"))
        info = DeviceInfo(name=str(evdev.get("name") or item.get("node") or "device"))
        ident = evdev.get("id")
        if isinstance(ident, list) and len(ident) == 4 and all(isinstance(i, int) for i in ident):
            info.bus, info.vendor, info.product, info.version = ident
        codes = evdev.get("codes")
        if isinstance(codes, dict):
            rel = codes.get(EV_REL) or []
            info.rel_xy = isinstance(rel, list) and REL_X in rel and REL_Y in rel
        info.extra["node"] = item.get("node")
        if span.events_line == 0:
            self.warnings.append(
                f"{self.path}:{span.first_line}: device {info.name!r} has no events list"
            )
        return info

    # ----------------------------------------------------------------- events

    def first_time(self) -> float | None:
        first = None
        for span in self._spans:
            for block, line in self._blocks(span, limit=1 << 16):
                ev = self._parse(block, line)
                if len(ev[0]):
                    t = float(ev[0][0])
                    first = t if first is None else min(first, t)
                    break
        return first

    def feeds(self) -> list[Feed]:
        self.reset_stats()
        return [
            Feed((i,), self._batches(i))
            for i, d in enumerate(self.devices)
            if d.rel_xy is not False
        ]

    def _blocks(self, span: _Span, limit: int | None = None) -> Iterator[tuple[bytes, int]]:
        if not span.events_line:
            return
        with _open(self.data_path) as f:
            f.seek(span.events)
            left = span.end - span.events
            line = span.events_line
            carry = b""
            size = limit or self.block_bytes
            while left > 0 or carry:
                buf = f.read(min(size, left)) if left > 0 else b""
                left -= len(buf)
                buf = carry + buf
                cut = buf.rfind(b"\n") + 1 if left > 0 else len(buf)
                block, carry = buf[:cut], buf[cut:]
                if block:
                    if not limit:
                        self.bytes_done += len(block)
                    yield block, line
                    line += block.count(b"\n")
                if limit:
                    return

    def _parse(self, block: bytes, line: int):
        """(t, type, code, value) arrays of the evdev rows of a block of whole lines."""
        rows = _ROW_C.findall(block)
        flow = _FLOW_HINT.search(block) is not None
        # Quick check: every line is a row or "- evdev:"; else look at each line closely.
        if flow or len(rows) + block.count(b"- evdev:") != block.count(b"\n"):
            text = _COMMENT.sub(b"", block) if b"#" in block else block
            if flow:
                text = _FLOW.sub(_flow_rows, text)
            if len(_OTHER.sub(b"", text).strip()) != 0:
                self._complain(block, line)
            rows = _ROW.findall(text)
        n = len(rows)
        if n == 0:
            e = np.empty(0, np.int64)
            return np.empty(0, np.float64), e, e, e
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
            self._complain(block, line)
        a = a.reshape(n, 5)
        if (
            (a[:, :4] < 0).any()
            or (a[:, 0] >= MAX_SECONDS).any()
            or (a[:, 2:4] > 0xFFFF).any()
            or (a[:, 1] >= 1_000_000).any()
            or (a[:, 4] < -(2**31)).any()  # an evdev value is a signed 32-bit integer
            or (a[:, 4] >= 2**31).any()
        ):
            self._complain(block, line)
        return a[:, 0] + a[:, 1] / 1_000_000, a[:, 2], a[:, 3], a[:, 4]

    def _complain(self, block: bytes, line: int) -> None:
        """Find the first bad line of a block that failed the quick checks, and say so."""
        for i, raw in enumerate(block.split(b"\n")):
            text = _COMMENT.sub(b"", raw)
            m = _ROW.match(text)
            flow = _FLOW.match(text)
            if m or flow:
                if flow and _FLOW_ROW.sub(b"", flow.group(1)).replace(b",", b"").strip():
                    raise CaptureError(
                        located(self.path, line + i, f"malformed evdev event list: {_show(raw)}")
                    )
                for row in [m.group(1)] if m else _FLOW_ROW.findall(flow.group(1)):
                    if not _row_ok(row):
                        raise CaptureError(
                            located(
                                self.path,
                                line + i,
                                "an evdev event must be [sec, usec, type, code, value] "
                                "(non-negative integers, but the value: a signed 32-bit "
                                f"one), got [{_show(row)}]",
                            )
                        )
            elif not _OTHER.fullmatch(text):
                raise CaptureError(
                    located(self.path, line + i, f"unexpected line in events: {_show(raw)}")
                )
        raise CaptureError(located(self.path, line, "malformed events"))

    def _batches(self, index: int) -> Iterator[Batch]:
        stats = self.stats[index]
        span = self._spans[index]
        frames = FrameBatcher(index, stats)
        last_t = -np.inf
        at_end = span.end == self._size
        for block, line in self._blocks(span):
            if at_end and not block.endswith(b"\n"):
                block = self._cut_torn_tail(block, line, stats)
            t, typ, code, value = self._parse(block, line)
            if not len(t):
                continue
            if t[0] < last_t or (np.diff(t) < 0).any():
                self._backwards(block, line, last_t)
            last_t = float(t[-1])
            yield frames.batch(t, typ, code, value)
        yield frames.last(self.warnings, f"{self.path}: device {self.devices[index].name!r}")

    def _cut_torn_tail(self, block: bytes, line: int, stats) -> bytes:
        """The file's last line without a newline: a recording cut off mid-row (crash, full
        disk) loses that row only, with a warning, as in evemu; a whole row is kept."""
        head, nl, tail = block.rpartition(b"\n")
        text = _COMMENT.sub(b"", tail)
        m = _ROW.match(text)
        if not tail.strip() or (m and _row_ok(m.group(1))) or _OTHER.fullmatch(text):
            return block
        stats.torn_bytes += len(tail)
        at = line + head.count(b"\n") + bool(nl)
        self.warnings.append(f"{self.path}:{at}: last line cut off (truncated recording); skipped")
        return head + nl

    def _backwards(self, block: bytes, line: int, last_t: float) -> None:
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
                            self.path,
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
    fields = row.split(b",")
    if len(fields) != 5:
        return False
    try:
        vals = [int(x) for x in fields]
    except ValueError:
        return False
    return (
        min(vals[:4]) >= 0
        and vals[0] < MAX_SECONDS
        and vals[1] < 1_000_000
        and vals[2] <= 0xFFFF
        and vals[3] <= 0xFFFF
        and -(2**31) <= vals[4] < 2**31
    )


def _flow_rows(m: re.Match) -> bytes:
    """A flow-style event list -> the same rows in block style, one per line (only the
    rows are read from this text; messages come from the original lines)."""
    inner = m.group(1)
    if _FLOW_ROW.sub(b"", inner).replace(b",", b"").strip():
        return m.group(0)  # not plain rows: _OTHER refuses it, _complain names the line
    return b"\n".join(b"- [" + r + b"]" for r in _FLOW_ROW.findall(inner))


def _line_of(text: bytes, needle: bytes) -> int | None:
    at = text.find(needle)
    return None if at < 0 else text.count(b"\n", 0, at) + 1


def _show(raw: bytes) -> str:
    """A piece of a line for a message: control characters escaped (a raw \\x1c or \\r
    would end or garble the message's line in a terminal)."""
    text = raw.decode("utf-8", "replace").strip()
    text = text if len(text) <= 50 else text[:47] + "..."
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def format_libinput(devices: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]) -> str:
    """A ``libinput record`` file holding one mouse per (name, t, dx, dy), for tests."""
    out = [
        "# libinput record",
        "version: 1",
        f"ndevices: {len(devices)}",
        "libinput:",
        "  version: 1.25.0",
        "system:",
        '  kernel: "6.8.0"',
        "devices:",
    ]
    for k, (name, t, dx, dy) in enumerate(devices):
        out += [
            f"- node: /dev/input/event{k + 5}",
            "  evdev:",
            f"    # Name: {name}",
            f"    name: {name}",
            f"    id: [3, 1133, {49271 + k}, 273]",
            "    codes:",
            "      0: [0, 1, 2] # EV_SYN",
            "      1: [272, 273, 274] # EV_KEY",
            "      2: [0, 1, 8, 11] # EV_REL",
            "    properties: []",
            "  udev:",
            "    properties:",
            "    - ID_INPUT_MOUSE=1",
            "  events:",
        ]
        sec, usec = sec_usec(t)
        for s, u, x, y in zip(sec, usec, dx.tolist(), dy.tolist(), strict=True):
            out.append("  - evdev:")
            if x:
                out.append(f"    - [{s:3d}, {u:6d},   2,   0, {int(x):5d}] # EV_REL / REL_X")
            if y:
                out.append(f"    - [{s:3d}, {u:6d},   2,   1, {int(y):5d}] # EV_REL / REL_Y")
            out.append(f"    - [{s:3d}, {u:6d},   0,   0,     0] # SYN_REPORT +0ms")
    return "\n".join(out) + "\n"
