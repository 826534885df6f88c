"""Real mouse recordings (../shared/captures/external) replayed as raw input_event bytes
through a real pipe into the evdev source: the motion frames and net counts must be
those stated in SOURCES.md, which were counted independently of this code."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from mousedom.config import EvdevMatch, Mount, MouseConfig
from mousedom.sources.base import SourceGone
from mousedom.sources.evdev import EvdevSource
from mousedom.sources.events import EVENT_DTYPE

# file: (motion frames, net X, net Y, all frames) from SOURCES.md
FACTS = {
    "evemu-devices__PS2_Generic_Mouse.events": (2707, -5424, -929, 2707),
    "evemu-devices__Saitek_Cyborg_RAT5_Mouse.events": (796, -111, -13, 803),
    "evemu-devices__Ultrathin_Touch_Mouse.events": (349, -319, -7, 406),
    "evemu-devices__TPPS2_IBM_TrackPoint.events": (945, -21, -10, 964),
}


def evemu_to_bytes(path) -> bytes:
    """``E: sec.usec type code value`` lines (hex type/code) -> struct input_event bytes."""
    rows = []
    for line in path.read_text().splitlines():
        if not line.startswith("E:"):
            continue
        stamp, ty, co, va = line[2:].split("#")[0].split()  # evemu 1.2 adds comments
        sec, usec = stamp.split(".")
        rows.append((int(sec), int(usec), int(ty, 16), int(co, 16), int(va)))
    return np.array(rows, dtype=EVENT_DTYPE).tobytes()


@pytest.mark.parametrize("name", sorted(FACTS))
def test_external_capture_through_a_pipe(external_captures, name):
    data = evemu_to_bytes(external_captures / name)
    r, w = os.pipe()
    src = EvdevSource(
        MouseConfig("m", 800.0, 800.0, Mount(), evdev=EvdevMatch(path=f"/proc/self/fd/{r}"))
    )
    src.open()
    os.close(r)
    rng = np.random.default_rng(len(data))

    def writer():
        pos = 0
        while pos < len(data):  # odd-sized writes: records and frames cut anywhere
            n = int(rng.integers(1, 5000))
            os.write(w, data[pos : pos + n])
            pos += n
        os.close(w)

    th = threading.Thread(target=writer)
    th.start()
    t, dx, dy = [], [], []
    while True:
        try:
            for b in src.read(0.0):
                t.append(b.t)
                dx.append(b.dx)
                dy.append(b.dy)
        except SourceGone:
            break
    th.join()
    t, dx, dy = np.concatenate(t), np.concatenate(dx), np.concatenate(dy)
    motion, net_x, net_y, frames = FACTS[name]
    s = src.assembler.stats
    assert (len(t), int(dx.sum()), int(dy.sum())) == (motion, net_x, net_y)
    assert s.frames == frames and s.dropped_frames == 0 and s.incomplete_frames == 0
    assert np.all(np.diff(t) >= 0)
    assert src.truncated_bytes == 0
