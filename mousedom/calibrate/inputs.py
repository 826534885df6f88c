"""``--capture`` arguments -> per-mouse report arrays, for calibration.

``mousedom.capture`` opens the files and maps their devices onto the config's mice
(``assign``: NAME=FILE, FILE alone when a device matches a mouse, and the config's own
``replay:`` entries).  Calibration then needs each mouse's whole recording in memory, on
the captures' *own* time base: unlike replay, no epoch rebasing here, because
``calibrate mounts`` lines the captures up with a reference file recorded on that same
clock.  Captures that cannot share one time base are refused.

An ADNS-3080 downsampler is recorded as its raw serial bytes; they are decoded here with
the same parser and clock mapping as the live source and replay
(``sources.adns.replay_decoder``).  A packet lost or refused on the line means counts
that are missing from the calibration, so it is an error, not a silent wrong answer; so
is an evdev frame the kernel dropped (SYN_DROPPED).  What the capture readers warn of (a
cut-off tail, a last frame without SYN_REPORT) is handed on with the other warnings.
"""

from __future__ import annotations

from collections.abc import Sequence

from mousedom.calibrate.runs import in_time_order
from mousedom.capture.assignment import assign, captures_of, parse_capture_arg
from mousedom.capture.base import Capture, CaptureError
from mousedom.capture.timebase import relative_alignment_warning
from mousedom.config import Config, MouseConfig
from mousedom.errors import UserError
from mousedom.sources.adns import replay_decoder
from mousedom.sources.base import Reports


def read_motion(cap: Capture, wanted: Sequence[tuple[int, MouseConfig]]) -> dict[str, Reports]:
    """All motion reports of the ``wanted`` (device index, mouse) pairs of ``cap``, per
    mouse name, in time order, times as recorded; the file is read once for all of them.

    A serial device (ADNS-3080 downsampler) is decoded from its raw bytes.
    """
    decoders = {m.name: replay_decoder(m) for i, m in wanted if cap.devices[i].kind == "serial"}
    parts: dict[str, tuple[list, list, list]] = {m.name: ([], [], []) for _, m in wanted}
    for feed in cap.feeds():
        mine = [(i, m.name) for i, m in wanted if i in feed.devices]
        if not mine:
            continue
        for batch in feed.batches:
            for index, name in mine:
                ts, dxs, dys = parts[name]
                for mo in batch.motion:
                    if mo.device == index:
                        ts.append(mo.t)
                        dxs.append(mo.dx)
                        dys.append(mo.dy)
                decoder = decoders.get(name)
                if decoder is None:
                    continue
                for piece in batch.serial:
                    if piece.device == index:
                        rep = decoder.feed_many(piece.t, piece.data)
                        ts.append(rep.t)
                        dxs.append(rep.dx)
                        dys.append(rep.dy)
    for index, m in wanted:
        decoder = decoders.get(m.name)
        if decoder is None:
            dropped = cap.stats[index]
            if dropped.dropped_frames:
                # The kernel's buffer overflowed (SYN_DROPPED): what it lost is unknown,
                # and a CPI 20 % off was written from such a drive without a word.
                raise UserError(
                    f"{cap.path}: device {cap.devices[index].name!r} (mouse {m.name}): "
                    f"{dropped.dropped_frames} frame(s) dropped by the kernel (SYN_DROPPED; "
                    f"{dropped.lost_x} x / {dropped.lost_y} y counts seen in them, the "
                    "rest unknown): counts are missing, so a calibration from it would be "
                    "wrong; record it again (`mousedom record` reads as the kernel writes)"
                )
            continue
        st = decoder.parser.stats
        if decoder.lost or st.crc_errors or st.bad_frames:
            # A refused frame is a lost packet, counted once by sequence; one refused at
            # the very end has no later packet to show the gap, so it is named too.
            raise UserError(
                f"{cap.path}: device {cap.devices[index].name!r} (mouse {m.name}): "
                f"{decoder.lost} serial packet(s) lost (missing by sequence number; "
                f"{st.crc_errors} CRC errors, {st.bad_frames} bad frames): their counts "
                "are missing, so a calibration from it would be wrong"
            )
    return {name: in_time_order(name, *lists) for name, lists in parts.items()}


def load_captures(specs: Sequence[str], config: Config) -> tuple[dict[str, Reports], list[str]]:
    """Per-mouse reports of the mice that have a capture (``--capture`` or ``replay:``),
    and warnings (separate files with relative times: the rule replay applies too)."""
    try:
        assignments = assign(config, [parse_capture_arg(s) for s in specs], require_all=False)
    except CaptureError as e:
        raise UserError(str(e)) from None
    read: dict[str, Reports] = {}
    warnings: list[str] = []
    for cap in captures_of(assignments):
        wanted = [(a.device, config.mice[a.mouse]) for a in assignments if a.capture is cap]
        read.update(read_motion(cap, wanted))
        warnings += cap.warnings  # (a cut-off tail, a last frame without SYN_REPORT ...)
    recording: dict[str, Reports] = {}
    bases: dict[str, str] = {}
    for a in assignments:
        name = config.mice[a.mouse].name
        recording[name] = read[name]
        bases[name] = a.capture.time_base
    if len(set(bases.values())) > 1:
        listing = ", ".join(f"{n}: {b}" for n, b in bases.items())
        raise UserError(f"the captures do not share one time base ({listing})")
    aligned = relative_alignment_warning(captures_of(assignments))
    return recording, warnings + ([aligned] if aligned else [])
