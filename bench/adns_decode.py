"""Throughput of the ADNS host side: parser, full replay (parser + clock sync + reports)
and the clock sync alone, on 20000 MOTION packets (5.5 minutes of data at K = 12).

Baseline, measured in the same run: splitting the stream on 0x00 and unpacking each
frame with struct, without COBS, CRC or checks; the least any parser could do.
Prints medians of 5 runs and ratios to the baseline.

    /work/venv/bin/python bench/adns_decode.py
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from timing import median_time  # noqa: E402  (bench/timing.py)

from mousedom.sources import adns_protocol as P  # noqa: E402
from mousedom.sources.adns_decode import packets_to_reports  # noqa: E402
from mousedom.sources.clocksync import ClockSync  # noqa: E402

N = 20000
RUNS = 5


def stream() -> bytes:
    return b"".join(
        P.encode_packet(P.Motion(i % 65536, i * 15000 % (1 << 32), i % 50 - 25, 7, 12, 80, 0x10))
        for i in range(N)
    )


def main() -> None:
    wire = stream()
    chunks = [(i * 0.001, wire[i : i + 64]) for i in range(0, len(wire), 64)]
    layout = struct.Struct("<BHIiiHBB")

    def baseline():
        for f in wire.split(b"\0"):
            if len(f) >= 19:
                layout.unpack_from(f, 1)

    def parser():
        p = P.Parser()
        for t, c in chunks:
            p.feed(c, t)
        assert p.stats.packets == N

    def replay():
        reports, _ = packets_to_reports(chunks)
        assert len(reports) == N

    def clock():
        s = ClockSync()
        for i in range(N):
            s.update(i * 0.015, 100 + i * 0.015 + (i * 7919 % 13) * 1e-4)

    base = median_time(baseline, RUNS)
    print(f"packets: {N}, bytes: {len(wire)}, chunks of 64 bytes: {len(chunks)}")
    print(f"baseline split+unpack: {base * 1e3:8.2f} ms  {N / base:12.0f} packets/s")
    for name, fn in [("parser", parser), ("replay", replay), ("clocksync", clock)]:
        t = median_time(fn, RUNS)
        print(
            f"{name:22s}: {t * 1e3:8.2f} ms  {N / t:12.0f} packets/s  "
            f"{t / base:6.1f}x baseline  {t / N * 1e6:6.2f} us/packet"
        )
    live = 1e6 / (12 * 1250)
    t = median_time(replay, RUNS)
    print(f"live rate at K=12: {live:.1f} packets/s -> {live * t / N * 100:.3f} % of one core")


if __name__ == "__main__":
    main()
