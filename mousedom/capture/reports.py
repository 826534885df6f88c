"""Whole captures in memory: every assigned mouse's reports as one array on one time base,
for tools that need all the data at once (calibration); replay streams instead."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mousedom.capture.assignment import Assignment, assign, captures_of, mice_by_device
from mousedom.capture.base import Capture, DeviceStats, Motion, Serial
from mousedom.capture.timebase import time_offset
from mousedom.config import Config
from mousedom.sources.base import Reports

if TYPE_CHECKING:
    from mousedom.sources.adns_decode import AdnsDecoder


def read_reports(
    config: Config, specs: list[tuple[str | None, str]], *, require_all: bool = True
) -> tuple[dict[str, Reports], dict[str, DeviceStats], list[str]]:
    """Every assigned mouse's whole capture as ``Reports`` on one time base.

    Returns (reports by mouse name, reader stats by mouse name, warnings).  For tools that
    need all the data at once (calibration); replay streams instead.
    """
    assignments = assign(config, specs, require_all=require_all)
    captures = captures_of(assignments)
    offset, warnings = time_offset(captures)
    parts: dict[int, list[Motion]] = {a.mouse: [] for a in assignments}
    stats: dict[str, DeviceStats] = {}
    for cap in captures:
        wanted = mice_by_device(assignments, cap)
        _read_capture(config, cap, wanted, parts)
        for dev, mice in wanted.items():
            for mouse in mice:
                stats[config.mice[mouse].name] = cap.stats[dev]
        warnings += cap.warnings
    out = {}
    for mouse, mos in parts.items():
        sub = offset if _capture_of(assignments, mouse).time_base == "epoch" else 0.0
        t = np.concatenate([m.t for m in mos]) if mos else np.empty(0)
        dx = np.concatenate([m.dx for m in mos]) if mos else np.empty(0)
        dy = np.concatenate([m.dy for m in mos]) if mos else np.empty(0)
        name = config.mice[mouse].name
        out[name] = Reports(name, t - sub, dx, dy)
    return out, stats, warnings


def _read_capture(
    config: Config,
    cap: Capture,
    wanted: dict[int, tuple[int, ...]],
    parts: dict[int, list[Motion]],
) -> None:
    """Append the motion of ``cap``'s wanted devices to their mice's ``parts``."""
    decoders: dict[int, AdnsDecoder] = {}
    for feed in cap.feeds():
        for batch in feed.batches:
            for mo in batch.motion:
                for mouse in wanted.get(mo.device, ()):
                    parts[mouse].append(mo)
            for chunk in batch.serial:
                if chunk.device in wanted:
                    _decode_serial(config, cap, chunk, wanted[chunk.device], decoders, parts)


def _decode_serial(
    config: Config,
    cap: Capture,
    chunk: Serial,
    mice: tuple[int, ...],
    decoders: dict[int, AdnsDecoder],
    parts: dict[int, list[Motion]],
) -> None:
    """Raw ADNS-3080 bytes: the daemon's own decoder, on the file's times (the epoch offset
    is applied by the caller, as for motion)."""
    from mousedom.sources.adns import replay_decoder

    dec = decoders.get(chunk.device)
    if dec is None:  # not setdefault: that would build one per chunk
        dec = decoders[chunk.device] = replay_decoder(config.mice[mice[0]])
    r = dec.feed_many(chunk.t, chunk.data)
    t, dx, dy = r.t, r.dx, r.dy
    cap.stats[chunk.device].add_motion(t, dx, dy)
    for mouse in mice:
        parts[mouse].append(Motion(chunk.device, t, dx, dy))


def _capture_of(assignments: list[Assignment], mouse: int) -> Capture:
    return next(a.capture for a in assignments if a.mouse == mouse)
