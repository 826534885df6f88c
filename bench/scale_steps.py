"""A mouse whose scale steps during a drive (onto a floor it reads more or less on, a lens
dirtied): end error with the engine as configured against the same drive without that
mouse configured (the oracle), over generated rigs and drives.

    .venv/bin/python bench/scale_steps.py [--steps 0.25 0.45] [--seeds 1-40] [--jobs 2]

The rigs, drives and steps are tests/test_scale_change.py's ``random_step`` (3-6 mice,
ring or scattered, 400-1600 CPI, 125-1000 Hz, USB polling gaps and late stamps on some;
one mouse reading more or less by a fraction drawn from ``--steps`` from 30-60 % of a
25-40 s drive to its end).  Steps of 0.05-0.10 are within ``robust.scale_limit`` (learnt
and applied), 0.12-0.25 beyond it (held out, ``ScaleLearner.beyond``), 0.25-0.45 a block's
own fault (``ScaleLearner._faults``, given back: ``_give_back_faults``).

Prints one line per drive (seed, the step's size, mice, end error on and oracle, mm) and
then median / p90 / worst of each and how many drives end within 50 mm of their oracle.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from test_scale_change import random_step  # noqa: E402  (the tests' generator, one definition)

from mousedom.fusion import scenarios, sim  # noqa: E402
from mousedom.fusion.drives import drive  # noqa: E402


def one(seed: int, steps: tuple[float, float]) -> tuple[int, float, int, float, float]:
    """(seed, size, mice, end error on, oracle's), metres."""
    base, duration, bad, start, size = random_step(seed, steps)
    mice = list(base.mice)
    mice[bad] = dataclasses.replace(mice[bad], scale=((start, math.inf, size),))
    result = sim.simulate(dataclasses.replace(base, mice=tuple(mice)), drive(duration, seed),
                          seed=seed)  # fmt: skip
    out = []
    for rig in (base, dataclasses.replace(base, mice=base.mice[:bad] + base.mice[bad + 1 :])):
        names = {m.name for m in rig.mice}
        kept = {k: v for k, v in result.reports.items() if k in names}
        batch, _ = scenarios.run(dataclasses.replace(result, reports=kept), scenarios.config(rig))
        e = scenarios.end_pose_error(result, batch)
        out.append(math.hypot(e[0], e[1]))
    return seed, size, len(base.mice), out[0], out[1]


def _seeds(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=float, nargs=2, default=(0.25, 0.45))
    ap.add_argument("--seeds", type=_seeds, default=_seeds("1-40"), help="first-last")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    steps = (args.steps[0], args.steps[1])
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(one, args.seeds, [steps] * len(args.seeds)))
    print(f"{'seed':>5s} {'size':>6s} {'mice':>4s} {'on mm':>8s} {'oracle mm':>10s}")
    for seed, size, n, on, oracle in rows:
        print(f"{seed:5d} {size:6.3f} {n:4d} {1000 * on:8.1f} {1000 * oracle:10.1f}")

    def stats(v: list[float]) -> str:
        a = 1000 * np.asarray(v)
        return f"{np.median(a):.0f} / {np.percentile(a, 90):.0f} / {a.max():.0f}"

    on = [r[3] for r in rows]
    oracle = [r[4] for r in rows]
    near = sum(a < b + 0.05 for a, b in zip(on, oracle, strict=True))
    print(f"steps {steps[0]:g}-{steps[1]:g}, {len(rows)} drives; end error mm, "
          f"median / p90 / worst:")  # fmt: skip
    print(f"  engine  {stats(on)}")
    print(f"  oracle  {stats(oracle)}  (the mouse not configured)")
    print(f"  within 50 mm of the oracle: {near} of {len(rows)}")


if __name__ == "__main__":
    main()
