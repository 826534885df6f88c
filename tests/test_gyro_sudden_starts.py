"""A healthy gyro on random rigs driven with sudden starts and stops (a review's generated
drives): the gyro's learnt scale stays near its truth and its heading is no worse than
the mice's alone.

A span of still windows but for a sudden start at its edge had its timing variance taken
as twice the span's mean, a span's length below that edge's own: one such span taught the
scale 0.03 off its truth (seed 18: +0.030 learnt for -0.028 true), the spans after it
failed the test and reset the bias again and again, and the heading ended 6.0 degrees off
against 0.18 with the mice alone (seeds 5 and 59: 2.7 and 1.7 against 0.08 and 0.03).
fusion/gyrobias.py now takes the edges' own variances.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mousedom.fusion import sim, simgyro
from mousedom.fusion.drives import drive


def _rig(rng: np.random.Generator) -> sim.Rig:
    n = int(rng.integers(1, 6))
    mice = []
    for k in range(n):
        if n == 1:
            x, y = float(rng.uniform(0.05, 0.2)), float(rng.uniform(-0.03, 0.03))
        else:
            r, a = rng.uniform(0.06, 0.2), 2 * math.pi * k / n + rng.uniform(-0.3, 0.3)
            x, y = r * math.cos(a), r * math.sin(a)
        yaw = float(rng.choice([0.0, 90.0, float(rng.uniform(-180, 180))]))
        hz = float(rng.choice([125.0, 250.0, 500.0, 1000.0]))
        mice.append(sim.SimMouse(f"m{k}", float(x), float(y), yaw=yaw, cpi_x=1000.0,
                                 cpi_y=1000.0, report_hz=hz, phase=float(rng.uniform(0, 0.008)),
                                 noise=0.3, stamp_delay=0.001))  # fmt: skip
    model = "diff-drive" if n == 1 else str(rng.choice(["lsq", "diff-drive"]))
    return sim.Rig(tuple(mice), model=model)


def _gyro(rng: np.random.Generator) -> simgyro.SimGyro:
    return simgyro.SimGyro(
        sample_hz=float(rng.choice([50.0, 100.0, 200.0, 500.0, 1000.0, 2000.0])),
        density=math.radians(float(rng.uniform(0.003, 0.02))),
        bias=math.radians(float(rng.uniform(-1.0, 1.0))),
        scale_error=float(rng.uniform(-0.03, 0.03)),
        phase=float(rng.uniform(0, 0.02)),
    )


def _sudden(rng: np.random.Generator, seconds: float) -> list:
    """Segments of constant twist from and to standstill: instant starts and stops."""
    segs = [sim.Segment(0.5)]
    t = 0.5
    while t < seconds - 1:
        kind, hold = rng.choice(["s", "a", "t", "p"]), float(rng.uniform(0.5, 3.0))
        if kind == "s":
            segs.append(sim.Segment(hold, float(rng.uniform(0.1, 0.5)), 0.0, 0.0))
        elif kind == "a":
            v = float(rng.uniform(0.1, 0.4))
            w = v / float(rng.uniform(0.3, 1.5)) * float(rng.choice([-1, 1]))
            segs.append(sim.Segment(hold, v, 0.0, w))
        elif kind == "t":
            segs.append(
                sim.Segment(hold, 0.0, 0.0, float(rng.choice([-1, 1]) * rng.uniform(0.3, 2.0)))
            )
        else:
            segs.append(sim.Segment(hold))
        t += hold
    segs.append(sim.Segment(0.5))
    return segs


def _heading_error(result: sim.SimResult, cfg) -> tuple[float, float | None]:
    batch, _ = sim.run_tracker(result, cfg)
    end = result.truth(batch.t[-1:])[0]
    err = (batch.theta[-1] - end[2] + math.pi) % (2 * math.pi) - math.pi
    scale = None if batch.gyro is None else float(batch.gyro[-1][4])
    return abs(math.degrees(err)), scale


# seeds of the review's 58 whose drives are sudden (5, 18: the worst before) and others
@pytest.mark.parametrize("seed", [5, 18, 3, 4, 10, 20])
def test_a_healthy_gyro_is_no_worse_than_the_mice_after_sudden_starts(seed):
    rng = np.random.default_rng(1000 + seed)
    rig = _rig(rng)
    g = _gyro(rng)
    rig = dataclasses.replace(rig, gyro=g)
    rest = float(rng.choice([0.5, 2.0, 10.0]))
    dr = drive(30.0, seed=seed) if rng.random() < 0.5 else _sudden(rng, 30.0)
    traj = sim.sequence(sim.pause(rest), dr, sim.pause(float(rng.choice([0.5, 5.0]))))
    result = sim.simulate(rig, traj, seed=seed)
    cfg = sim.rig_config(rig)
    mice, _ = _heading_error(result, dataclasses.replace(cfg, gyro=None))
    both, scale = _heading_error(result, cfg)
    assert scale is not None and abs(scale - g.scale_error) < 0.003, (scale, g.scale_error)
    # (two mice on a diff-drive's seed 3 end 0.34 against 0.08: the heading's spans still
    # learn little in straights, a weakness left, docs/gyro.md)
    assert both < 2.0 * mice + 0.3, (both, mice)
