"""Capture files: evemu, libinput record and mousedom's native format.

Entry points:

- ``open_capture(path)``: sniff the format and open it for streaming (a ``Capture``;
  ``capture.sniff``).
- ``parse_capture_arg("NAME=FILE")``: one ``--capture`` argument (``capture.assignment``).
- ``assign(config, specs)``: open every ``--capture`` (and the config's own ``replay:``
  entries), and map each capture device onto a mouse of the config (``capture.assignment``).
- ``time_offset(captures)``: what to subtract so that epoch-stamped files start at 0
  (``capture.timebase``).
- ``read_reports(config, specs)``: whole captures as per-mouse report arrays on one time
  base (for calibration and other tools that want everything in memory;
  ``capture.reports``).

This module only gathers those names: the logic lives in the modules named.
"""

from __future__ import annotations

from mousedom.capture.assignment import (
    Assignment,
    assign,
    captures_of,
    config_inputs,
    input_files,
    mice_by_device,
    parse_capture_arg,
)
from mousedom.capture.base import (
    Batch,
    Capture,
    CaptureError,
    DeviceInfo,
    DeviceStats,
    Feed,
    Motion,
    Serial,
)
from mousedom.capture.native import NativeWriter
from mousedom.capture.reports import read_reports
from mousedom.capture.sniff import open_capture, sniff
from mousedom.capture.timebase import relative_alignment_warning, time_offset

__all__ = [
    "Assignment",
    "Batch",
    "Capture",
    "CaptureError",
    "DeviceInfo",
    "DeviceStats",
    "Feed",
    "Motion",
    "NativeWriter",
    "Serial",
    "assign",
    "captures_of",
    "config_inputs",
    "input_files",
    "mice_by_device",
    "open_capture",
    "parse_capture_arg",
    "read_reports",
    "relative_alignment_warning",
    "sniff",
    "time_offset",
]
