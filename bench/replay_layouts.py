"""Replay's fusion on the named layouts: time per drive, and the windows left to the decision.

    .venv/bin/python bench/replay_layouts.py [--seconds 30] [--repeat 3] [--seed 5]

bench/replay.py measures replay on one rig (four mice at 1 kHz on steady arcs), where
every report has counts.  The named layouts (``scenarios.LAYOUTS``: mice at 125-1000 Hz)
on ``scenarios.drive``'s drives slow down and turn, and then a fast mouse reports only
when it has a count: half their windows cut a long report span.  For each layout this
simulates one drive and prints the median time of ``scenarios.run`` (the Tracker's batch:
the count functions, the solve, the screen, the learners, the covariance) over
``--repeat`` runs, windows per second, and how many windows cut a long span and how many
went to ``Screen.decide`` (the rest the common case took: ``screenbatch._fast_rows``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from mousedom.fusion import robust, scenarios, screenbatch, sim  # noqa: E402

LAYOUTS = ("triangle", "square", "pentagon", "wide", "kite", "offset-ring", "far-one")


def counted(layout: str, seconds: float, seed: int) -> tuple[int, int, int]:
    """(windows, windows cutting a long span, windows decided) of one drive's replay."""
    base = scenarios.rig(layout)
    result = sim.simulate(base, scenarios.drive(seconds, seed), seed=seed)
    tally = {"cut": 0, "decided": 0}
    screen, decide = screenbatch.screen, robust.Screen.decide

    def counting_screen(sc, d, mask, q, squal_scale=None, low_quality=None, spans=None):
        if spans is not None:
            tally["cut"] += int(np.any(mask & (spans > 0), axis=1).sum())
        return screen(sc, d, mask, q, squal_scale, low_quality, spans)

    def counting_decide(self, *args, **kwargs):
        tally["decided"] += 1
        return decide(self, *args, **kwargs)

    screenbatch.screen, robust.Screen.decide = counting_screen, counting_decide
    try:
        batch, _ = scenarios.run(result, scenarios.config(base))
    finally:
        screenbatch.screen, robust.Screen.decide = screen, decide
    return len(batch.t), tally["cut"], tally["decided"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args()
    print(f"{'layout':14s}{'ms (median)':>12s}{'windows/s':>11s}{'windows':>9s}"
          f"{'cut a span':>12s}{'decided':>9s}")  # fmt: skip
    total = 0.0
    for layout in LAYOUTS:
        base = scenarios.rig(layout)
        result = sim.simulate(base, scenarios.drive(args.seconds, args.seed), seed=args.seed)
        cfg = scenarios.config(base)
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            scenarios.run(result, cfg)
            times.append(time.perf_counter() - t0)
        median = statistics.median(times)
        total += median
        windows, cut, decided = counted(layout, args.seconds, args.seed)
        print(f"{layout:14s}{median * 1e3:12.0f}{windows / median:11.0f}{windows:9d}"
              f"{cut:12d}{decided:9d}")  # fmt: skip
    print(f"all layouts: {total:.2f} s")


if __name__ == "__main__":
    main()
