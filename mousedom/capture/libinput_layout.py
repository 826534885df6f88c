"""libinput record files in another layout of the same YAML, re-laid out for the reader.

``LibinputCapture`` finds devices and event rows by their lines, as ``libinput record``
writes them (``- node:`` first in each device, one ``- [sec, usec, type, code, value]``
row per line), which is what makes long recordings fast to read.  The same document can
be written other ways that any YAML reader takes: re-dumped by PyYAML in block style (keys
sorted, so ``- evdev:`` comes before ``node:``, and each row a nested block list), a device
as a flow mapping, ``node :`` with a space.  Such a file was skipped device by device, or
refused.  Now, when the line scan and the document disagree (no device found where the
document has some, more devices than ``ndevices``, or fewer where a flow-mapping device or
a block row shows another layout, a device as a flow mapping), the whole document is read
as YAML (with safeyaml's bounds: such files are small, or are refused with the reason) and
written again in the recorder's own layout into a private temporary copy, which the reader
then reads as usual.  Fewer devices than ``ndevices`` in the recorder's own layout is a
recording cut off, which the reader reads as it is, with a warning.
"""

from __future__ import annotations

import json
import os
import tempfile
from typing import Any

import yaml

from mousedom import safeyaml
from mousedom.capture.base import CaptureError
from mousedom.errors import located
from mousedom.saferead import read_bytes


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _event_row(path: str, row: Any, where: str) -> str:
    if not (isinstance(row, list) and len(row) == 5 and all(_int(x) for x in row)):
        raise CaptureError(
            located(path, None, f"{where}: an evdev event must be [sec, usec, type, code, "
                    f"value] (integers), got {row!r:.80}")
        )  # fmt: skip
    return "    - [" + ", ".join(str(x) for x in row) + "]"


def _device_lines(path: str, k: int, dev: Any) -> list[str]:
    where = f"device {k + 1}"
    if not isinstance(dev, dict):
        raise CaptureError(located(path, None, f"{where}: not a mapping"))
    evdev = dev.get("evdev") or {}
    if not isinstance(evdev, dict):
        raise CaptureError(located(path, None, f"{where}: evdev: not a mapping"))
    header = {"evdev": {k: evdev[k] for k in ("name", "id", "codes") if k in evdev}}
    node = dev.get("node")
    lines = [f"- node: {json.dumps(node)}"]  # JSON is YAML: quoted, one line
    dumped = yaml.safe_dump(header, default_flow_style=False, sort_keys=False)
    lines += ["  " + ln for ln in dumped.splitlines() if ln.strip() not in ("...",)]
    events = dev.get("events")
    if events is None:
        return lines
    if not isinstance(events, list):
        raise CaptureError(located(path, None, f"{where}: events: not a list"))
    lines.append("  events:")
    for entry in events:
        if not isinstance(entry, dict):
            raise CaptureError(located(path, None, f"{where}: an event entry is not a mapping"))
        rows = entry.get("evdev")
        if rows is None:
            continue  # hid and libinput entries: not evdev events
        if not isinstance(rows, list):
            raise CaptureError(located(path, None, f"{where}: evdev events: not a list"))
        lines.append("  - evdev:")
        lines += [_event_row(path, row, where) for row in rows]
    return lines


def relayout(path: str, data_path: str) -> str:
    """A private temporary copy of the recording in ``libinput record``'s own layout;
    the caller owns it (``capture.plain.discard``)."""
    try:
        raw = read_bytes(data_path, safeyaml.MAX_BYTES)
    except OSError as e:
        raise CaptureError(f"{path}: cannot read: {e.strerror}") from None
    if len(raw) > safeyaml.MAX_BYTES:
        raise CaptureError(
            f"{path}: not in libinput record's own layout (re-dumped YAML?), and larger "
            f"than the {safeyaml.MAX_BYTES} bytes read as a whole YAML document: write it "
            "with one '- node:' per device and one '- [sec, usec, type, code, value]' row "
            "per line"
        )
    try:
        doc = safeyaml.load(raw)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        line = mark.line + 1 if mark else None
        raise CaptureError(located(path, line, f"invalid YAML: {e.problem}")) from None
    except yaml.YAMLError as e:
        raise CaptureError(located(path, None, f"invalid YAML: {e}")) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("devices"), list):
        raise CaptureError(located(path, None, "not a libinput record file (no devices list)"))
    top = {k: v for k, v in doc.items() if k != "devices"}
    top["ndevices"] = len(doc["devices"])
    lines = ["# libinput record (re-laid out by mousedom)"]
    lines += yaml.safe_dump(top, default_flow_style=False, sort_keys=False).splitlines()
    lines.append("devices:")
    for k, dev in enumerate(doc["devices"]):
        lines += _device_lines(path, k, dev)
    fd, tmp = tempfile.mkstemp(prefix="mousedom-capture-", suffix=".yml")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write("\n".join(lines) + "\n")
    except BaseException:
        os.unlink(tmp)
        raise
    return tmp
