"""Cost of one live evdev read, as the daemon makes it: the small path vs the bulk numpy
path vs a bare reader, on the same pipe, in one run.

    /work/venv/bin/python bench/readpath.py [--reads 20000] [--frames 10] [--sweep 2000]

Each read finds ``frames`` mouse reports (REL_X, REL_Y, SYN_REPORT: 72 bytes each; 10
frames = 720 bytes, what a 1 kHz mouse leaves between two 100 Hz wake-ups) in a real
pipe.  The write is not timed; the read is, with ``time.perf_counter_ns``:

- bare:   poll(0) + os.read(fd, 24 KiB), and nothing else (the least a Python reader
          pays; bench/daemon.py's baseline reader does this);
- bulk:   ``EvdevSource.read`` forced onto its bulk path (``small_read = 0``:
          np.frombuffer, ``FrameAssembler.feed_events``, the array clamp, Reports of
          arrays), then ``Tracker.push`` of the arrays: the read path before the small path;
- small:  ``EvdevSource.read`` as the daemon runs it (``FrameAssembler.feed_bytes``, Python
          lists end to end), then ``Tracker.push`` of ``Reports.columns()``.

"read" figures stop after ``EvdevSource.read``; "read+push" include the hand-over to the
tracker, as ``Daemon._read_slot`` does it.  The paths take turns read by read, so that
they share the machine's noise; medians over all reads.  Then a sweep over read sizes
shows where the bulk path gets cheaper (``SMALL_READ`` in mousedom/sources/evdev.py).
"""

from __future__ import annotations

import argparse
import os
import select
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mousedom.config import EvdevMatch, Mount, MouseConfig  # noqa: E402
from mousedom.fusion import sim  # noqa: E402
from mousedom.fusion.tracker import Tracker  # noqa: E402
from mousedom.sources.evdev import EvdevSource  # noqa: E402
from mousedom.sources.events import (  # noqa: E402
    EV_REL,
    EV_SYN,
    REL_X,
    REL_Y,
    SYN_REPORT,
    encode_input_events,
)

READ_BYTES = 24 * 1024


def frames_bytes(t0: float, n: int, rng: np.random.Generator) -> bytes:
    """``n`` frames of a 1 kHz mouse from ``t0``: REL_X, REL_Y, SYN_REPORT each."""
    t = np.repeat(t0 + np.arange(n) * 0.001, 3)
    ty = np.tile([EV_REL, EV_REL, EV_SYN], n)
    co = np.tile([REL_X, REL_Y, SYN_REPORT], n)
    va = np.zeros(3 * n, dtype=np.int64)
    va[0::3] = rng.integers(-30, 31, n)
    va[1::3] = rng.integers(-30, 31, n)
    return encode_input_events(t, ty, co, va)


class Lane:
    """One pipe, one reader, one tracker: a path under test."""

    def __init__(self, name: str, small_read: int | None, push: bool) -> None:
        self.name = name
        r, self.w = os.pipe()
        self.src: EvdevSource | None = None
        if small_read is None:  # the bare reader
            self.fd = r
            os.set_blocking(r, False)
            self.poll = select.poll()
            self.poll.register(r, select.POLLIN)
        else:
            m = MouseConfig("m", 800.0, 800.0, Mount(), evdev=EvdevMatch(path=f"/proc/self/fd/{r}"))
            self.src = EvdevSource(m)
            self.src.small_read = small_read
            self.src.open()
            os.close(r)
        self.push = push
        self.small = small_read != 0
        # The daemon's tracker (three mice at 1 kHz; this pipe feeds the first).
        self.tracker = Tracker(sim.rig_config(sim.three_mouse_rig(report_hz=1000.0)), t0=0.0)
        self.times: list[int] = []

    def once(self, chunk: bytes, t_end: float) -> None:
        os.write(self.w, chunk)
        pc = time.perf_counter_ns
        if self.src is None:
            t0 = pc()
            self.poll.poll(0)
            os.read(self.fd, READ_BYTES)
            self.times.append(pc() - t0)
            return
        src, tracker = self.src, self.tracker
        t0 = pc()
        batches = src.read(t_end)
        if self.push:
            for b in batches:
                if self.small:
                    tracker.push(0, *b.columns())
                else:
                    tracker.push(0, b.t, b.dx, b.dy)
        self.times.append(pc() - t0)
        if self.push:  # not timed: close the window, so that the tracker stays small
            tracker.complete_until(t_end)
            tracker.poll()

    def median_us(self) -> float:
        return statistics.median(self.times) / 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reads", type=int, default=20_000)
    ap.add_argument("--frames", type=int, default=10, help="mouse reports per read")
    ap.add_argument(
        "--sweep", type=int, default=2000, metavar="READS", help="reads per size (0: no sweep)"
    )
    a = ap.parse_args()
    lanes = [
        Lane("bare poll + os.read", None, False),
        Lane("bulk path: read", 0, False),
        Lane("small path: read", 24 * 256, False),
        Lane("bulk path: read + push", 0, True),
        Lane("small path: read + push", 24 * 256, True),
    ]
    rng = np.random.default_rng(0)
    period = a.frames * 0.001
    for k in range(a.reads):
        chunk = frames_bytes(k * period, a.frames, rng)
        for lane in lanes:
            lane.once(chunk, (k + 1) * period)
    bare = lanes[0].median_us()
    print(
        f"one live read of {a.frames} frames ({a.frames * 72} bytes) through a pipe, "
        f"median of {a.reads} reads"
    )
    for lane in lanes:
        us = lane.median_us()
        print(f"  {lane.name:26s} {us:7.2f} us   bare + {us - bare:6.2f} us   x{us / bare:5.1f}")
    b_read, s_read = lanes[1].median_us(), lanes[2].median_us()
    b_push, s_push = lanes[3].median_us(), lanes[4].median_us()
    print(f"small vs bulk: read x{b_read / s_read:.2f} cheaper, read + push x{b_push / s_push:.2f}")
    if a.sweep:
        sweep(rng, a.sweep)


def sweep(rng: np.random.Generator, reads: int) -> None:
    """Where the small path stops paying: bigger reads, both paths (``SMALL_READ``)."""
    print(f"read only, by read size (median of {reads} reads each): small vs bulk")
    for frames in (1, 10, 30, 60, 85, 100, 150, 341):
        bulk, small = Lane("bulk", 0, False), Lane("small", 24 * 1024, False)
        for k in range(reads):
            chunk = frames_bytes(k * frames * 0.001, frames, rng)
            for lane in (bulk, small):
                lane.once(chunk, (k + 1) * frames * 0.001)
        b, sm = bulk.median_us(), small.median_us()
        print(
            f"  {frames * 3:5d} events ({frames * 72:6d} bytes): small {sm:7.2f} us, "
            f"bulk {b:7.2f} us   small/bulk {sm / b:5.2f}"
        )


if __name__ == "__main__":
    main()
