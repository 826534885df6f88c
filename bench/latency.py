"""What waiting for a late mouse costs: the delay from a window's end to its pose.

    .venv/bin/python bench/latency.py [--seeds 5] [--duration 60] [--late 0,0.1,0.15,0.2]

A report within ``late_report_s`` of its mouse's previous one covers all the time since
(a USB catch-up), so a window waits for a silent mouse up to that long before closing
without it (docs/config.md).  This feeds simulated drives to the tracker as the daemon
does: every report at its arrival stamp, and every millisecond the daemon's tick
(``complete_each(now - latency)`` for every mouse, then ``poll``), and measures, for
every window, the time from its end to the tick that closed it.  Printed per condition
and ``late_report_s`` (0: the old rule of one report period; 0.15: the default): the
median, 99th percentile and largest delay, and the share of windows delayed over 20 ms.
Drives: healthy (the triangle rig's minute of straights, arcs, pivots and stops), the
125 Hz mouse with 30 ms USB gaps 3 times a second, and the square rig.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics

import numpy as np

from mousedom.fusion import conditions, scenarios, sim
from mousedom.fusion.tracker import Tracker
from mousedom.sources.base import Source

LATENCY_S = Source.latency  # the daemon's margin

TICK_S = 0.001


def delays(result: sim.SimResult, cfg, duration: float) -> np.ndarray:
    tracker = Tracker(cfg, t0=0.0)
    names = {m.name: i for i, m in enumerate(cfg.mice)}
    merged = sorted(
        (float(t), names[name], int(dx), int(dy))
        for name, r in result.reports.items()
        for t, dx, dy in zip(r.t, r.dx, r.dy, strict=True)
    )
    out, k = [], 0
    for now in np.arange(0.0, duration + 0.5, TICK_S).tolist():
        while k < len(merged) and merged[k][0] <= now:
            t, i, dx, dy = merged[k]
            tracker.push(i, [t], [dx], [dy])
            k += 1
        tracker.complete_each([(i, now - LATENCY_S) for i in range(len(cfg.mice))])
        batch = tracker.poll()
        if len(batch):
            out.extend((now - batch.t).tolist())
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument(
        "--late", default="0,0.1,0.15,0.2", help="late_report_s values, comma-separated"
    )
    args = ap.parse_args()
    lates = [float(v) for v in args.late.split(",")]
    cases = [("triangle", "healthy"), ("triangle", "usb-gaps"), ("square", "healthy")]
    print(f"{'rig':9} {'drive':9} {'late_report_s':>13} {'median':>8} {'p99':>8} {'max':>8} "
          f"{'>20 ms':>7}")  # fmt: skip
    for layout, kind in cases:
        for late in lates:
            all_d = []
            for seed in range(args.seeds):
                base = scenarios.rig(layout)
                rig = base
                if kind == "usb-gaps":
                    cond = conditions.condition("usb-gaps", seed, gap_rate=3.0, gap_length=0.03)
                    rig = conditions.apply_condition(base, cond, args.duration)
                result = sim.simulate(rig, scenarios.drive(args.duration, seed), seed=seed)
                cfg = dataclasses.replace(scenarios.config(base), late_report_s=late)
                all_d.append(delays(result, cfg, args.duration))
            d = np.concatenate(all_d) * 1e3
            med, p99, over = statistics.median(d), np.percentile(d, 99), np.mean(d > 20) * 100
            print(f"{layout:9} {kind:9} {late:13g} {med:7.1f}  {p99:7.1f}  {d.max():7.1f}  "
                  f"{over:5.1f} %")  # fmt: skip


if __name__ == "__main__":
    main()
