"""The daemon's one-window path and replay's array path give the same windows on rigs
with a gyro, fault handling on and late mice (docs/models.md: replay makes the same
decisions as the daemon): the gyro's judge is told the same mice in each window's solve.

The array path told it every live mouse not excluded, a late one (held out of the solve)
included, where the daemon's path told it the solve's own: the same counts, states and
gyro turns gave headings 1.9e-5 rad apart, and rates 8.7e-4 rad/s (a review's generated
rigs: 4 of 13 with a gyro and late mice)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mousedom.fusion import sim, simgyro
from mousedom.fusion.drives import drive
from mousedom.fusion.posebatch import PoseBatch
from mousedom.fusion.tracker import Tracker


def _rig(rng: np.random.Generator) -> sim.Rig:
    n = int(rng.integers(3, 7))
    mice = []
    for k in range(n):
        a = 2 * math.pi * k / n + rng.uniform(-0.4, 0.4)
        r = rng.uniform(0.05, 0.25)
        hz = float(rng.choice([125.0, 500.0, 1000.0, 2000.0]))
        late = float(rng.choice([0.0, 0.002, 0.005, 0.02]))
        mice.append(sim.SimMouse(f"m{k}", float(r * math.cos(a)), float(r * math.sin(a)),
                                 yaw=float(rng.uniform(-180, 180)), cpi_x=800.0, cpi_y=800.0,
                                 report_hz=hz, phase=float(rng.uniform(0, 1 / hz)),
                                 noise=0.3, stamp_delay=0.001, stamp_tail=late))  # fmt: skip
    gyro = simgyro.SimGyro(sample_hz=float(rng.choice([100.0, 500.0])))
    return sim.Rig(tuple(mice), model=str(rng.choice(["lsq", "diff-drive"])), gyro=gyro)


@pytest.mark.parametrize("seed", range(10))
def test_the_daemons_windows_are_replays_with_a_gyro_and_late_mice(seed):
    rng = np.random.default_rng(4100 + seed)
    rig = _rig(rng)
    result = sim.simulate(rig, sim.sequence(sim.pause(1.0), drive(6.0, seed=seed)), seed=seed)
    cfg = sim.rig_config(rig)
    cfg = dataclasses.replace(cfg, late_report_s=float(rng.choice([0.05, 0.15])))
    batch, _ = sim.run_tracker(result, cfg)
    tracker = Tracker(cfg, t0=float(result.motion.starts[0]))
    live = PoseBatch.concat(sim.run_tracker_live(result, tracker), len(cfg.mice))
    assert np.array_equal(batch.t, live.t) and np.array_equal(batch.state, live.state)
    assert np.abs(batch.theta - live.theta).max() < 1e-9
    assert np.abs(batch.omega - live.omega).max() < 1e-7
