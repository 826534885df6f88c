"""Mice whose stamps are 0-4 ms late (a host that stamps evdev events late) with a gyro fused:
the gyro makes the heading no worse than the mice alone.

The stamps then lag the gyro's by 2 ms on average, and spread by as much.  Before
(24 drives of 30 s per rig, end heading in degrees, median / worst, mice alone against
``gyro.use: both``): one mouse 0.38 / 0.71 against 1.09 / 3.25, a pair 0.22 / 0.92 against
0.41 / 2.0, a triangle 0.15 / 0.51 against 0.77 / 12.4, a square 0.09 / 0.39 against
0.28 / 7.5.  The first turn's spans taught the gyro's scale the lag and the spread (the
rig's timing not learnt yet), and three mice that agree read the spans that then failed as
a bias jump, relearnt from one span (docs/gyro.md).  These are two or three drives per
rig, among them the worst of those 24 (seeds 23, 10, 19 and 16).

Nine drives (twelve before; left out: one 18, triangle 16, square 18, none of them a
worst of the 24, the worst with the gyro here, pair 10, or the drive the bug below sends
off): median 0.14 with the gyro against 0.20 alone (its bound 0.30; with all twelve 0.13
against 0.24), worst 0.72 (the bound 1.0).  With a span's timing taken as its mean (the
mutant gyro-span-timing-its-mean) triangle 4 ends 2.46 off, and the median, 0.32, is just
over its bound as well."""

from __future__ import annotations

import dataclasses
import math
import statistics

from mousedom.fusion import scenarios, sim, simgyro
from mousedom.fusion.drives import drive

LATE_S = 0.004
SEEDS = {"one": (23, 5), "pair": (10, 21, 3), "triangle": (19, 4), "square": (16, 2)}
MARGIN_DEG = 0.1  # the gyro's median may exceed the mice's alone by this much
WORST_DEG = 1.0  # no drive ends further off with the gyro


def _rig(layout: str, seed: int) -> sim.Rig:
    if layout == "one":  # bench/gyro.py's one-mouse rig (Hong's model)
        mouse = sim.SimMouse("front", 0.1, 0.0, cpi_x=1000.0, cpi_y=1000.0, report_hz=500.0,
                             noise=0.3)  # fmt: skip
        rig = sim.Rig((mouse,), model="diff-drive")
    else:
        model = "diff-drive" if layout == "pair" else "lsq"
        rig = dataclasses.replace(scenarios.rig(layout), model=model)
    return dataclasses.replace(
        rig,
        mice=tuple(dataclasses.replace(m, stamp_delay=LATE_S) for m in rig.mice),
        gyro=simgyro.SimGyro(sample_hz=200.0, phase=0.0007 * seed),
    )


def _errors(layout: str, seed: int) -> tuple[float, float]:
    """The end heading's error (degrees) of one drive without the gyro and with it."""
    rig = _rig(layout, seed)
    result = sim.simulate(rig, sim.sequence(sim.pause(2.0), drive(30.0, seed=seed)), seed=seed)
    cfg = sim.rig_config(rig)
    out = []
    for config in (dataclasses.replace(cfg, gyro=None), cfg):
        batch, _ = sim.run_tracker(result, config)
        end = result.truth(batch.t[-1:])[0]
        out.append(math.degrees(abs(math.remainder(batch.theta[-1] - end[2], math.tau))))
    return out[0], out[1]


def test_mice_stamped_late_keep_their_heading_with_a_gyro():
    runs = {(layout, s): _errors(layout, s) for layout, seeds in SEEDS.items() for s in seeds}
    without = [r[0] for r in runs.values()]
    with_gyro = [r[1] for r in runs.values()]
    assert statistics.median(with_gyro) <= statistics.median(without) + MARGIN_DEG, runs
    assert max(with_gyro) < WORST_DEG, runs
