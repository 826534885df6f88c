#!/usr/bin/env python3
"""Generated faulty drives, each run three ways: the default engine, fault handling off, and
fault handling off told the fault (its reports removed by hand: the informed reference).

    .venv/bin/python scripts/fault_sweep.py [--drives 300] [--seed 31337] [--jobs 2]
        [--kinds lift,under-read] [--conditions late-stamps,usb-gaps] [--only K,K]
        [--timeline]

Drive k draws from ``(seed, k)``: a layout of scenarios.LAYOUTS, a mouse, a fault kind
(lift, lift-noisy, under-read, jumps) starting at 4-12 s for 0.5-3 s, a condition of a
healthy rig (conditions.py; late stamps with a tail of 1-5 ms), and a 20 s drive.  Prints
one row per drive (end position and heading error of each run), then per kind and
condition the median errors and the drives where the default engine ends worse than three
times the informed reference and 30 mm ("far off"), each with what rebuilds it (``--only
k``).  A long run for finding wrong answers one step past the tests: the suite runs a few
of these drives in tests/test_readmission_evidence.py.

``--timeline`` (with ``--only``) prints under each drive's row what a far-off drive is
read from: the drive's held stretches (straight, arc, turn: a pivot, stop) and every window
in which the default engine's health of some mouse changed.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import NamedTuple

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mousedom.fusion import robust, scenarios  # noqa: E402
from mousedom.fusion.conditions import (  # noqa: E402
    FaultyDrive,
    condition,
    condition_config,
    faulty_drive,
)
from mousedom.fusion.drives import drive_spans  # noqa: E402

DURATION = 20.0
KINDS = ("lift", "lift-noisy", "under-read", "jumps")
CONDITIONS = ("healthy", "usb-gaps", "late-stamps", "usb-gaps+late-stamps", "noisy", "stamp-delay")


class Drive(NamedTuple):
    k: int
    layout: str
    mouse: str
    kind: str
    condition: str
    seed: int  # the drive's and the condition's
    stamp_tail: float  # s (late-stamps only)
    start: float
    end: float


class Result(NamedTuple):
    drive: Drive
    default: tuple[float, float]  # end (position mm, heading degrees)
    off: tuple[float, float]
    informed: tuple[float, float]

    @property
    def far_off(self) -> bool:
        return self.default[0] > 3.0 * self.informed[0] + 30.0


def draw(k: int, seed: int, kinds: tuple[str, ...], conditions: tuple[str, ...]) -> Drive:
    rng = np.random.default_rng((seed, k))
    layout = sorted(scenarios.LAYOUTS)[int(rng.integers(len(scenarios.LAYOUTS)))]
    mice = scenarios.LAYOUTS[layout]
    mouse = mice[int(rng.integers(len(mice)))][0]
    kind = kinds[int(rng.integers(len(kinds)))]
    cond = conditions[int(rng.integers(len(conditions)))]
    drive_seed = int(rng.integers(10000))
    tail = float(rng.uniform(0.001, 0.005)) if "late-stamps" in cond else 0.0
    start = float(rng.uniform(4.0, 12.0))
    return Drive(k, layout, mouse, kind, cond, drive_seed, tail, start,
                 start + float(rng.uniform(0.5, 3.0)))  # fmt: skip


def _end(run: scenarios.Run) -> tuple[float, float]:
    return 1000.0 * run.position, math.degrees(run.heading)


def build(d: Drive) -> FaultyDrive:
    """Drive d simulated (its fault: the drawn one, or the scenario's jumps on its mouse)."""
    params = {"stamp_tail": d.stamp_tail} if d.stamp_tail else {}
    cond = condition(d.condition, d.seed, **params)
    if d.kind == "jumps":  # the scenario's jumps, on the drawn mouse
        fault = scenarios.fault_for("jumps", scenarios.rig(d.layout), DURATION, d.seed)
        fault = dataclasses.replace(fault, mouse=d.mouse)
    else:
        fault = scenarios.Fault(d.kind, d.mouse, d.start, d.end)
    return faulty_drive(d.layout, cond, fault, d.seed, DURATION)


def run(d: Drive) -> Result:
    base, cond, fault, traj, result = build(d)
    off = condition_config(base, cond, robust=False)
    default = scenarios.measure(result, condition_config(base, cond))
    plain = scenarios.measure(result, off)
    informed = scenarios.measure(result, off, scenarios.informed_dead(fault, base, traj))
    if d.kind == "jumps":
        d = d._replace(start=fault.start, end=fault.end)
    return Result(d, _end(default), _end(plain), _end(informed))


def timeline(d: Drive) -> list[str]:
    """Drive d's held stretches, then each window in which the default engine's health
    of a mouse changed: its end time and every mouse's state (reason)."""
    built = build(d)
    spans = ", ".join(f"{sp.kind} {sp.start:.2f}-{sp.end:.2f}"
                      for sp in drive_spans(DURATION, d.seed))  # fmt: skip
    out = [f"  drive: {spans}"]
    batch, _ = scenarios.run(built.result, condition_config(built.base, built.cond))
    names = [m.name for m in built.base.mice]
    last = None
    for t, state, reason in zip(batch.t.tolist(), batch.state.tolist(), batch.reason.tolist(),
                                strict=True):  # fmt: skip
        now = tuple(zip(state, reason, strict=True))
        if now != last:
            health = "  ".join(f"{n} {robust.STATES[s]}"
                               + (f" ({robust.REASONS[r]})" if r else "")
                               for n, (s, r) in zip(names, now, strict=True))  # fmt: skip
            out.append(f"  {t:7.3f} s  {health}")
            last = now
    return out


def row(r: Result) -> str:
    d = r.drive
    return (f"k={d.k:<4d} {d.layout:15s} {d.mouse:6s} {d.kind:10s} {d.start:6.2f}-{d.end:6.2f} s "
            f"{d.condition:20s} tail {d.stamp_tail * 1000:4.2f} ms seed {d.seed:<5d} | "
            f"default {r.default[0]:8.1f} mm {r.default[1]:6.2f} deg  off {r.off[0]:8.1f} mm "
            f"{r.off[1]:6.2f} deg  informed {r.informed[0]:7.1f} mm {r.informed[1]:5.2f} deg"
            + ("  FAR OFF" if r.far_off else ""))  # fmt: skip


def summary(results: list[Result]) -> list[str]:
    groups: dict[tuple[str, str], list[Result]] = defaultdict(list)
    for r in results:
        groups[(r.drive.kind, r.drive.condition)].append(r)
    out = [f"{'kind':11s} {'condition':21s} {'n':>3s} {'default':>8s} {'informed':>8s} "
           f"{'off':>8s} {'far off':>7s}   (median end position error, mm)"]  # fmt: skip
    for (kind, cond), g in sorted(groups.items()):

        def med(which: str, g: list[Result] = g) -> float:
            return float(np.median([getattr(r, which)[0] for r in g]))

        far = sum(r.far_off for r in g)
        out.append(f"{kind:11s} {cond:21s} {len(g):3d} {med('default'):8.1f} "
                   f"{med('informed'):8.1f} {med('off'):8.1f} {far:7d}")  # fmt: skip
    far_off = sorted((r for r in results if r.far_off),
                     key=lambda r: r.default[0] - r.informed[0], reverse=True)  # fmt: skip
    out.append(f"far off (default > 3 x informed + 30 mm): {len(far_off)} of {len(results)}")
    out.extend(row(r) for r in far_off)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drives", type=int, default=300)
    ap.add_argument("--seed", type=int, default=31337)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--conditions", default=",".join(CONDITIONS))
    ap.add_argument("--only", default="", help="comma-separated drive numbers k to run")
    ap.add_argument("--timeline", action="store_true",
                    help="with --only: each drive's stretches and health changes")  # fmt: skip
    args = ap.parse_args(argv)
    if args.timeline and not args.only:
        ap.error("--timeline needs --only K: it prints every window's change of health")
    kinds, conds = tuple(args.kinds.split(",")), tuple(args.conditions.split(","))
    for k in kinds:
        if k not in KINDS:
            ap.error(f"--kinds: unknown kind {k!r}; choose of {', '.join(KINDS)}")
    for c in conds:
        if c not in CONDITIONS:
            ap.error(f"--conditions: unknown condition {c!r}; choose of {', '.join(CONDITIONS)}")
    ks = [int(k) for k in args.only.split(",")] if args.only else range(args.drives)
    drives = [draw(k, args.seed, kinds, conds) for k in ks]
    results = []
    with ProcessPoolExecutor(max(1, args.jobs)) as pool:
        for r in pool.map(run, drives):
            print(row(r), flush=True)
            if args.timeline:
                print("\n".join(timeline(r.drive)), flush=True)
            results.append(r)
    print("\n".join(summary(results)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
