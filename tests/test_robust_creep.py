"""One mouse creeps (reads 10-50 mm/s that did not happen) while the robot stands still: the
mice that stand still are not blamed for it (robust.Screen._quiet_blame).

Every used mouse's prediction came from a fit that holds the creeping one, so each still
mouse read "short" of what the fit moved it by, and they were held out one after another as
silent while others move, until the creeping mouse and one other carried the pose (a
review's random rigs of 3-6 mice: healthy mice held out in 7 of 20, six of them ending
worse than with fault handling off, up to 0.74 m against 0.16; 6 of the 20 here).  Lifts
come one mouse at a time: half the mice in use or more reading nothing, or short, is the
prediction's fault, and no silent mouse is blamed in that window."""

from __future__ import annotations

import dataclasses
import math
import statistics

import numpy as np
import pytest

from mousedom.config.rig import RobustConfig
from mousedom.fusion import robust, scenarios, sim
from mousedom.fusion.drives import drive

RATES = (125.0, 250.0, 500.0, 1000.0, 2000.0, 4000.0, 8000.0)


def _rig(seed: int) -> sim.Rig:
    rng = np.random.default_rng((777, seed))
    mice = []
    for k in range(int(rng.integers(3, 7))):
        r, a = rng.uniform(0.04, 0.3), rng.uniform(0, 2 * math.pi)
        cpi = rng.uniform(400, 3200)
        hz = float(rng.choice(RATES))
        mice.append(sim.SimMouse(
            f"m{k}", float(r * math.cos(a)), float(r * math.sin(a)), yaw=float(rng.uniform(0, 360)),
            cpi_x=float(cpi), cpi_y=float(cpi), report_hz=hz, phase=float(rng.uniform(0, 1 / hz)),
            noise=0.3, stamp_delay=0.001, flip=bool(rng.random() < 0.3),
        ))  # fmt: skip
    return sim.Rig(tuple(mice), model="lsq")


def _creeping(mouse: sim.SimMouse, t0: float, t1: float, v: tuple[float, float]) -> sim.SimMouse:
    """``mouse`` reading a body velocity ``v`` it did not move over [t0, t1)."""
    dt = max(1.0 / mouse.report_hz, 0.002)
    step = mouse.counts_per_body_metre() @ np.asarray(v) * dt
    jumps = tuple((float(t), float(step[0]), float(step[1])) for t in np.arange(t0, t1, dt))
    return dataclasses.replace(mouse, jumps=jumps)


def _run(seed: int):
    rng = np.random.default_rng((41, seed))
    rig = _rig(seed)
    first = drive(6.0, seed)
    stop = sum(s.duration for s in first)
    t0 = stop + rng.uniform(1.0, 3.0)
    speed, angle = rng.uniform(0.01, 0.05), rng.uniform(0, 2 * math.pi)
    mice = list(rig.mice)
    mice[0] = _creeping(mice[0], t0, t0 + 2.0, (speed * math.cos(angle), speed * math.sin(angle)))
    rig = dataclasses.replace(rig, mice=tuple(mice))
    result = sim.simulate(rig, first + [sim.Segment(6.0)] + drive(6.0, seed + 500), seed=seed)
    out = {}
    for robust_on in (True, False):
        cfg = dataclasses.replace(sim.rig_config(rig), robust=RobustConfig(enabled=robust_on))
        batch, _ = scenarios.run(result, cfg)
        e = scenarios.end_pose_error(result, batch)
        state = np.asarray(batch.state)[:, 1:]
        healthy_out = bool(((state == robust.EXCLUDED) | (state == robust.LATE)).any())
        out[robust_on] = (math.hypot(e[0], e[1]), healthy_out)
    return out


def test_still_mice_are_not_blamed_for_one_that_creeps():
    runs = [_run(seed) for seed in range(100, 120)]
    blamed = [seed for seed, r in zip(range(100, 120), runs, strict=True) if r[True][1]]
    assert len(blamed) <= 1, blamed
    on = [r[True][0] for r in runs]
    off = [r[False][0] for r in runs]
    assert statistics.median(on) <= statistics.median(off), (on, off)
    worse = [k for k in range(len(runs)) if on[k] > 1.5 * off[k] + 0.005]
    assert len(worse) <= 1, (worse, on, off)


CENTRE = {  # a mouse at the spin's centre, and two or three about it (name, x, y, Hz)
    "three": (("c", 0.0, 0.0, 125.0), ("a", 0.12, 0.08, 500.0), ("b", -0.10, -0.09, 1000.0)),
    "four": (("c", 0.0, 0.0, 125.0), ("a", 0.12, 0.0, 500.0), ("b", -0.06, 0.10, 1000.0),
             ("d", -0.06, -0.10, 250.0)),
}  # fmt: skip


@pytest.mark.parametrize(("layout", "rate", "late"), [("three", 1.0, 0.004), ("four", 0.3, 0.001)])
def test_a_lift_in_a_spin_about_a_mouse_at_the_centre_is_blamed(layout, rate, late):
    """The other side of the rule above: after 8 s of driving, a spin about the mouse at
    the centre with another mouse lifted for 4 s of it.  The centre mouse reads nothing and
    the lifted one nothing: two of three silent (two of four), as with a creeping mouse,
    but this lift must be held out (a first version of the rule let it by: 0.45-2.75 m and
    23-120 degrees off; a review's sweep)."""
    warm = drive(8.0, 1)
    start = sum(s.duration for s in warm) + 2.0
    mice = tuple(
        sim.SimMouse(n, x, y, cpi_x=1000.0, cpi_y=1000.0, report_hz=hz, phase=0.00131 * k,
                     noise=0.3, stamp_delay=late, lost=((start, start + 4.0),) if n == "a" else ())
        for k, (n, x, y, hz) in enumerate(CENTRE[layout])
    )  # fmt: skip
    rig = sim.Rig(mice, model="lsq")
    traj = warm + [sim.Segment(8.0, omega=rate)] + drive(4.0, 78)
    result = sim.simulate(rig, traj, seed=1)
    batch, _ = scenarios.run(result, sim.rig_config(rig))
    lift = (batch.t > start + 0.1) & (batch.t < start + 4.0)
    held = np.isin(np.asarray(batch.state)[lift, 1], (robust.EXCLUDED, robust.LATE))
    e = scenarios.end_pose_error(result, batch)
    assert held.mean() > 0.8, held.mean()
    assert math.hypot(e[0], e[1]) < 0.02 and abs(e[2]) < math.radians(1.0), e
