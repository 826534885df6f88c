"""Decoding rate of raw input_event bytes into motion frames: mousedom's decoders vs
python-evdev's InputEvent objects doing the same work, on the same bytes, in one run.

python-evdev's read path (InputDevice.read) turns each record into a (sec, usec, type,
code, value) tuple in C and then an ``evdev.InputEvent`` in Python.  A reader then still
has to group the events into frames and sum REL_X/REL_Y at each SYN_REPORT, which is what
mousedom's decoders deliver; so the baseline of every figure here does that too (the
headline used to compare with bare objects, which do less).  mousedom has two paths: the
bulk one (``decode_input_events``, one np.frombuffer, and ``FrameAssembler.feed_events``)
for big reads, and the small one (``FrameAssembler.feed_bytes`` on Python lists) that a
live read of a few frames takes; each per-read row times the path the source takes for
that read size (``EvdevSource.small_read`` bytes and below: the small one).

Usage: python bench/decode.py [--events N] [--repeats R]
"""

from __future__ import annotations

import argparse
import statistics
import struct
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from evdev import InputEvent  # noqa: E402

from mousedom.sources.events import (  # noqa: E402
    EV_REL,
    EV_SYN,
    REL_X,
    REL_Y,
    SYN_REPORT,
    FrameAssembler,
    decode_input_events,
    encode_input_events,
)


def mouse_stream(n_frames: int, seed: int = 0) -> bytes:
    """A 1 kHz mouse moving on both axes: REL_X, REL_Y, SYN_REPORT per frame."""
    rng = np.random.default_rng(seed)
    t = np.repeat(np.arange(n_frames) * 0.001, 3)
    ty = np.tile([EV_REL, EV_REL, EV_SYN], n_frames)
    co = np.tile([REL_X, REL_Y, SYN_REPORT], n_frames)
    va = np.zeros(3 * n_frames, dtype=np.int64)
    va[0::3] = rng.integers(-30, 31, n_frames)
    va[1::3] = rng.integers(-30, 31, n_frames)
    return encode_input_events(t, ty, co, va)


def python_evdev_objects(buf: bytes) -> int:
    """As InputDevice.read(): per read of up to 64 records, a tuple per record (done in C
    by device_read_many), then one InputEvent per tuple, handed out and dropped."""
    n = 0
    for lo in range(0, len(buf), 64 * 24):
        for rec in tuple(struct.iter_unpack("llHHi", buf[lo : lo + 64 * 24])):
            InputEvent(*rec)
            n += 1
    return n


def python_evdev_frames(buf: bytes) -> int:
    """InputEvent objects as InputDevice.read() makes them, then what a reader does with
    them: sum REL_X and REL_Y until each SYN_REPORT and keep (time, dx, dy) per frame."""
    n = 0
    frames = []
    dx = dy = 0
    for lo in range(0, len(buf), 64 * 24):
        for rec in tuple(struct.iter_unpack("llHHi", buf[lo : lo + 64 * 24])):
            e = InputEvent(*rec)
            n += 1
            if e.type == EV_REL:
                if e.code == REL_X:
                    dx += e.value
                elif e.code == REL_Y:
                    dy += e.value
            elif e.type == EV_SYN and e.code == SYN_REPORT:
                frames.append((e.timestamp(), dx, dy))
                dx = dy = 0
    return n


def small_path(buf: bytes) -> int:
    """The live read's path for a few frames: bytes -> (t, dx, dy) lists, no numpy."""
    FrameAssembler().feed_bytes(buf)
    return len(buf) // 24


def bulk_decode(buf: bytes) -> int:
    events, _ = decode_input_events(buf)
    # Touch every field so that the view is really read, as the assembler would.
    _ = events["type"].sum() + events["code"].sum() + events["value"].sum()
    return len(events)


def bulk_decode_and_frames(buf: bytes) -> int:
    events, _ = decode_input_events(buf)
    FrameAssembler().feed_events(events)
    return len(events)


def through_pipe(buf: bytes, consume) -> float:
    """events/s for a writer process pushing ``buf`` through a real pipe to ``consume(fd)``.

    The writer is a forked process, not a thread: python-evdev's C read keeps the GIL
    while it blocks in read(2), so a writer thread would never run (deadlock), and a
    process also keeps the writer from competing with the reader for the GIL."""
    import os

    r, w = os.pipe()
    t0 = time.perf_counter()
    pid = os.fork()
    if pid == 0:  # the writer
        try:
            os.close(r)
            os.write(w, buf)
            os.close(w)
        finally:
            os._exit(0)
    os.close(w)
    consume(r)
    elapsed = time.perf_counter() - t0
    os.waitpid(pid, 0)
    os.close(r)
    return len(buf) // 24 / elapsed


def consume_source(fd: int) -> None:
    from mousedom.config import EvdevMatch, Mount, MouseConfig
    from mousedom.sources.base import SourceGone
    from mousedom.sources.evdev import EvdevSource

    src = EvdevSource(
        MouseConfig("m", 800, 800, Mount(), evdev=EvdevMatch(path=f"/proc/self/fd/{fd}"))
    )
    src.open()
    try:
        while True:
            src.read(0.0)
    except SourceGone:
        pass


def consume_python_evdev(fd: int) -> None:
    """python-evdev's own read path, as InputDevice.read() runs it: the C extension's
    device_read_many (up to 64 records per read(2), a tuple each) and one InputEvent per
    tuple.  It reads any fd, so a pipe stands in for the node."""
    from evdev import _input

    while True:
        events = _input.device_read_many(fd)
        if not events:  # end of stream (the writer closed)
            return
        for e in events:
            InputEvent(*e)


def consume_objects(fd: int) -> None:
    """python-evdev's read path: read up to 64 events, one InputEvent each (device_read_many)."""
    import os

    rest = b""
    while True:
        data = os.read(fd, 64 * 24)
        if not data:
            return
        data = rest + data
        n = len(data) // 24 * 24
        rest = data[n:]
        for rec in struct.iter_unpack("llHHi", data[:n]):
            InputEvent(*rec)


def bench(fn, buf: bytes, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        n = fn(buf)
        times.append(time.perf_counter() - t0)
    return n / statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=300_000)
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args()
    buf = mouse_stream(a.events // 3)
    rows = [
        ("python-evdev objects + frame sums", bench(python_evdev_frames, buf, a.repeats)),
        ("bulk decode + frame assembly", bench(bulk_decode_and_frames, buf, a.repeats)),
        ("(bulk decode alone, np.frombuffer)", bench(bulk_decode, buf, a.repeats)),
        ("(python-evdev objects alone)", bench(python_evdev_objects, buf, a.repeats)),
    ]
    base = rows[0][1]
    print(f"input_event decoding, {len(buf) // 24} events in one buffer, median of {a.repeats}")
    for name, rate in rows:
        print(f"  {name:36s} {rate / 1e6:8.2f} M events/s   x{rate / base:7.1f}")
    pipe_rows = [
        (
            "pipe -> InputEvent objects (64/read)",
            statistics.median(through_pipe(buf, consume_objects) for _ in range(3)),
        ),
        (
            "pipe -> python-evdev device_read_many",
            statistics.median(through_pipe(buf, consume_python_evdev) for _ in range(3)),
        ),
        (
            "pipe -> EvdevSource (Reports)",
            statistics.median(through_pipe(buf, consume_source) for _ in range(3)),
        ),
    ]
    pbase = pipe_rows[0][1]
    print("through a real pipe, writer process + reader, median of 3")
    for name, rate in pipe_rows:
        print(f"  {name:36s} {rate / 1e6:8.2f} M events/s   x{rate / pbase:7.1f}")
    # What one live read hands the decoder: a few frames (a 1 kHz mouse woken every ms)
    # up to a full 1024-record read.  Small chunks take the assembler's loop path.
    from mousedom.sources.evdev import SMALL_READ

    print("per read, bytes -> frames, the path the source takes for the read's size, vs "
          "python-evdev objects + frame sums (median of many reads)")  # fmt: skip
    for frames in (1, 10, 50, 341):
        chunk = mouse_stream(frames, seed=frames)
        reps = max(a.repeats * 20, 20_000 // frames)
        small = len(chunk) <= SMALL_READ
        ours = bench(small_path if small else bulk_decode_and_frames, chunk, reps)
        theirs = bench(python_evdev_frames, chunk, reps)
        print(
            f"  {frames * 3:5d} events/read ({'small' if small else 'bulk'} path): ours "
            f"{ours / 1e6:6.2f} M/s, python-evdev {theirs / 1e6:6.2f} M/s   x{ours / theirs:5.1f}"
        )
    # The small path on each core (docs/install.md), in this run: us per read.
    from mousedom import core

    if core.native is None:
        print(f"the small path on the compiled core: not here ({core.NAME})")
        return
    print("the small path (feed_bytes) per read on each core, us (median of many reads)")
    native = core.native
    for frames in (1, 3, 10, 50, 300):
        chunk = mouse_stream(frames, seed=frames)
        reps = max(a.repeats * 20, 20_000 // frames)
        per_read = {}
        for name, which in (("c", native), ("python", None)):
            core.native = which
            per_read[name] = 3 * frames / bench(small_path, chunk, reps) * 1e6
        core.native = native
        c_us, py_us = per_read["c"], per_read["python"]
        print(f"  {frames * 3:5d} events/read: compiled {c_us:7.2f} us, Python {py_us:7.2f} us"
              f"   x{py_us / c_us:5.1f}")  # fmt: skip


if __name__ == "__main__":
    main()
