"""A gyro with the mice (issue 30): heading and position errors with and without it.

    .venv/bin/python bench/gyro.py [--seeds 12] [--seconds 60]

Realistic drives (fusion/drives.py: straights, arcs, pivots, stops) of ``--seconds``,
each from 2 s at rest (a robot just switched on: where the gyro's bias is first learnt),
on a one-mouse diff-drive rig (Hong's: the mouse 0.1 m ahead of the axle), two mice on
the axle (diff-drive) and three (lsq), with an MPU-6050-like gyro (fusion/simgyro.py:
datasheet noise, a 0.5 deg/s bias that wanders).  Healthy mice, one mouse lifted for 3 s
or under-reading by half for 5 s (fusion/scenarios.py's faults), a gyro whose scale
is 3 % off (an MPU-6050's sensitivity tolerance), and one whose range the drive's faster
turns exceed (it clips at 0.8 rad/s, as a gyro set to a sensitive range on a robot that
then spins fast: its samples there marked saturated, as the IIO source marks them).  For each: the
median over seeds of the end pose's heading and position errors, mice alone and mice
with the gyro (use: both), their ratio, and the end-pose NEES (3 is honest); for the
lift, the share of its windows in which the lifted mouse was left out.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mousedom.fusion import scenarios, sim, simgyro  # noqa: E402
from mousedom.fusion.drives import drive  # noqa: E402
from mousedom.fusion.health import Health  # noqa: E402

RIGS = {
    "1 mouse": ("one", "diff-drive"),
    "2 mice (axle)": ("pair", "diff-drive"),
    "3 mice": ("triangle", "lsq"),
}
# the last two: the gyro's scale is off; its range is exceeded
FAULTS = ("none", "lift", "under-read", "gyro +3 %", "gyro clips")
CLIP = 0.8  # rad/s: "gyro clips"'s full scale (the drives turn at up to 1.9 rad/s)
REST_S = 2.0


def base_rig(layout: str, model: str) -> sim.Rig:
    if layout == "one":
        mouse = sim.SimMouse("front", 0.1, 0.0, cpi_x=1000.0, cpi_y=1000.0, report_hz=500.0,
                             noise=0.3, stamp_delay=0.001)  # fmt: skip
        return sim.Rig((mouse,), model=model)
    return dataclasses.replace(scenarios.rig(layout), model=model)


def one_run(layout: str, model: str, fault: str, seed: int, seconds: float) -> dict:
    scale_error = 0.03 if fault == "gyro +3 %" else 0.0  # within an MPU-6050's tolerance
    gyro = simgyro.SimGyro(phase=0.0007 * seed, scale_error=scale_error)
    if fault == "gyro clips":
        gyro = dataclasses.replace(gyro, full_scale=CLIP)
    rig = dataclasses.replace(base_rig(layout, model), gyro=gyro)
    mouse_fault = "none" if fault.startswith("gyro") else fault
    f = scenarios.fault_for(mouse_fault, rig, seconds, seed)
    f = dataclasses.replace(f, start=f.start + REST_S, end=f.end + REST_S)
    rig = scenarios.apply(rig, f)
    traj = sim.sequence(sim.pause(REST_S), drive(seconds, seed=seed))
    result = sim.simulate(rig, traj, seed=seed)
    out = {}
    for name, with_gyro in (("mice", False), ("gyro", True)):
        cfg = dataclasses.replace(sim.rig_config(rig), model=model)
        if not with_gyro:
            cfg = dataclasses.replace(cfg, gyro=None)
        batch, _ = sim.run_tracker(result, cfg)
        end = result.truth(batch.t[-1:])[0]
        turn = (batch.theta[-1] - end[2] + math.pi) % (2 * math.pi) - math.pi
        err = np.array([batch.x[-1] - end[0], batch.y[-1] - end[1], turn])
        out[name] = (abs(err[2]), math.hypot(err[0], err[1]), scenarios.nees(err, batch.cov[-1])[0])
        if with_gyro and fault == "lift":
            span = (batch.t > f.start + 0.05) & (batch.t < f.end - 0.05)
            out["left out"] = float((batch.state[span, 0] == Health.EXCLUDED).mean())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    t0 = time.monotonic()
    print(f"{args.seeds} seeds of {args.seconds:g} s drives from {REST_S:g} s at rest; medians")
    print(f"{'rig':<15} {'fault':<11} {'heading deg':>21} {'ratio':>6} {'position mm':>19} "
          f"{'ratio':>6} {'NEES':>11} {'lift left out':>13}")  # fmt: skip
    print(f"{'':<15} {'':<11} {'mice':>10} {'+gyro':>10} {'':>6} {'mice':>9} {'+gyro':>9} "
          f"{'':>6} {'mice':>5} {'+gyro':>5}")  # fmt: skip
    for label, (layout, model) in RIGS.items():
        for fault in FAULTS:
            runs = [one_run(layout, model, fault, s, args.seconds) for s in range(args.seeds)]
            h = [statistics.median(math.degrees(r[k][0]) for r in runs) for k in ("mice", "gyro")]
            p = [statistics.median(1000 * r[k][1] for r in runs) for k in ("mice", "gyro")]
            n = [statistics.mean(r[k][2] for r in runs) for k in ("mice", "gyro")]
            lift = ""
            if fault == "lift":
                lift = f"{100 * statistics.mean(r['left out'] for r in runs):.0f} %"
            print(f"{label:<15} {fault:<11} {h[0]:>10.3f} {h[1]:>10.3f} {h[1] / h[0]:>6.2f} "
                  f"{p[0]:>9.1f} {p[1]:>9.1f} {p[1] / p[0]:>6.2f} {n[0]:>5.1f} {n[1]:>5.1f} "
                  f"{lift:>13}")  # fmt: skip
    print(f"({time.monotonic() - t0:.0f} s)")


if __name__ == "__main__":
    main()
