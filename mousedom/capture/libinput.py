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
import weakref
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TypeGuard

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
    check_line_length,
    check_lines,
    sec_usec,
)
from mousedom.capture.base import open_binary as _open
from mousedom.capture.libinput_layout import relayout
from mousedom.capture.libinput_rows import backwards, cut_torn_tail, parse_rows
from mousedom.capture.plain import discard
from mousedom.errors import located
from mousedom.sources.events import EV_REL, REL_X, REL_Y

KNOWN_VERSIONS = (1,)
BLOCK_BYTES = 4 << 20

_DEVICE = re.compile(rb"(?m)^[ \t]*- node[ \t]*:")
# What the line scan cannot read (capture.libinput_layout re-lays such files out): a
# device written as a flow mapping, an event row as a block list ("- - 0").
_FLOW_DEVICE = re.compile(
    rb"(?m)^[ \t]*- \{[ \t]*[\"']?(?:node|evdev|udev|events|hid|quirks)[\"']?[ \t]*:"
)
_BLOCK_ROW = re.compile(rb"(?m)^[ \t]*- - ")
# (``events: []`` or a null, ``events: null`` / ``~``: a device without events, as a re-dump
# by yq or PyYAML writes it; every spelling YAML reads as an empty list or none)
_EVENTS = re.compile(
    rb"(?m)^[ \t]+events:[ \t]*(?:(?:\[[ \t]*\]|null|Null|NULL|~)[ \t]*)?(?:#.*)?$"
)
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


@dataclass(frozen=True)
class _Span:
    """Byte range of one device: header [start, events) and event list [events, end)."""

    start: int
    events: int
    end: int
    first_line: int
    events_line: int  # 0: the device has no events list


class _OpenSpan:
    """A device's span while the index is being built: its ends not found yet."""

    def __init__(self, start: int) -> None:
        self.start = start
        self.events: int | None = None
        self.first_line = 0
        self.events_line = 0

    def closed(self, end: int) -> _Span:
        """The span, its end (and its event list, if none was found) at ``end``."""
        if self.events is None:
            return _Span(self.start, end, end, self.first_line, 0)
        return _Span(self.start, self.events, end, self.first_line, self.events_line)


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
        copy = None
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
        if self._spans and not self._spans[-1].events_line and copy is None:
            # libinput record writes "events:" right after each device's header: a last
            # device without it is a header cut off (a crash while the recording began),
            # never a device (its name would be whatever the cut left, "/de").
            cut = self._spans.pop()
            if not self._spans:
                raise CaptureError(
                    located(path, cut.first_line, "the recording is cut off in its first "
                            "device's header (truncated): no device to read")
                )  # fmt: skip
            self.open_warnings.append(
                f"{path}:{cut.first_line}: the last device's header is cut off before its "
                "events list (truncated recording); that device is skipped"
            )
        for span in self._spans:
            self.devices.append(self._device(span))
        if not self.devices:
            raise CaptureError(located(path, None, "no devices in this libinput recording"))
        recorded = top.get("ndevices")
        if _int(recorded) and recorded > len(self.devices):
            self.open_warnings.append(
                f"{path}: {recorded} devices recorded (ndevices), {len(self.devices)} in the "
                "file: the recording is cut off (truncated); the devices after the last one "
                "found are lost"
            )
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
        if _int(n) and n != len(self._spans):
            # Fewer devices than recorded, all in the recorder's own layout: a recording
            # cut off (read as it is, with a warning), not another layout; a cut document
            # is not YAML, and one of more than safeyaml's bound is not read as one.
            return n < len(self._spans) or not self._own_layout()
        with _open(self.data_path) as f:
            f.seek(self._spans[0].start)
            head = f.read(1 << 16)
        return bool(_FLOW_DEVICE.search(head) or _BLOCK_ROW.search(head))

    def _own_layout(self) -> bool:
        """Whether no device is a flow mapping and no row a block list, in the whole file
        from the first device on (only read where the device count is off)."""
        with _open(self.data_path) as f:
            f.seek(self._spans[0].start)
            carry = b""
            line = self._spans[0].first_line  # the carried line's number
            while True:
                buf = f.read(self.block_bytes)
                text = carry + buf
                cut = len(text) if not buf else text.rfind(b"\n") + 1
                block, carry = text[:cut], text[cut:]
                if _FLOW_DEVICE.search(block) or _BLOCK_ROW.search(block):
                    return False
                if not buf:
                    return True
                line += block.count(b"\n")
                check_line_length(self.path, carry, line)

    def _index(self) -> list[_Span]:
        spans: list[_OpenSpan] = []
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
                check_lines(self.path, block, line)
                check_line_length(self.path, carry, line + block.count(b"\n"))
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
                        span = _OpenSpan(offset + pos)
                        span.first_line = at_line
                        spans.append(span)
                    elif spans and spans[-1].events is None:
                        nl = block.find(b"\n", pos)
                        spans[-1].events = offset + (nl + 1 if nl >= 0 else len(block))
                        spans[-1].events_line = at_line + 1
                    elif spans:
                        # A device has one events list (YAML would keep the last of two
                        # keys, a scan both): which one the user meant is not ours to
                        # guess, so the file is refused where the second begins.
                        raise CaptureError(
                            located(
                                self.path,
                                at_line,
                                "a second 'events:' list in one device (its first is at "
                                f"line {spans[-1].events_line - 1}): one list per device",
                            )
                        )
                line += block.count(b"\n")
                offset += len(block)
                if eof:
                    break
        self._size = offset
        # Each device ends where the next begins, the last at the end of the file.
        ends = [s.start for s in spans[1:]] + [offset] if spans else []
        return [s.closed(end) for s, end in zip(spans, ends, strict=True)]

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
            # (a document re-dumped as JSON has its keys as strings: "2")
            rel = codes.get(EV_REL, codes.get(str(EV_REL))) or []
            info.rel_xy = isinstance(rel, list) and REL_X in rel and REL_Y in rel
        info.extra["node"] = item.get("node")
        if span.events_line == 0:
            self.open_warnings.append(  # said with every read (reset_stats)
                f"{self.path}:{span.first_line}: device {info.name!r} has no events list"
            )
        return info

    # ----------------------------------------------------------------- events

    def first_time(self) -> float | None:
        first = None
        for span in self._spans:
            for block, line in self._blocks(span, limit=1 << 16):
                ev = parse_rows(self.path, block, line)
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
                check_line_length(self.path, carry, line)

    def _batches(self, index: int) -> Iterator[Batch]:
        stats = self.stats[index]
        span = self._spans[index]
        frames = FrameBatcher(index, stats)
        last_t = -np.inf
        at_end = span.end == self._size
        for block, line in self._blocks(span):
            if at_end and not block.endswith(b"\n"):
                block = cut_torn_tail(self.path, block, line, stats, self.warnings)
            t, typ, code, value = parse_rows(self.path, block, line)
            if not len(t):
                continue
            if t[0] < last_t or (np.diff(t) < 0).any():
                backwards(self.path, block, line, last_t)
            last_t = float(t[-1])
            yield frames.batch(t, typ, code, value)
        yield frames.last(self.warnings, f"{self.path}: device {self.devices[index].name!r}")


def _int(v: object) -> TypeGuard[int]:
    return isinstance(v, int) and not isinstance(v, bool)


def _line_of(text: bytes, needle: bytes) -> int | None:
    at = text.find(needle)
    return None if at < 0 else text.count(b"\n", 0, at) + 1


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
