"""Healthy rigs at short windows: how long the fault screen keeps a healthy mouse out, and
the end error with fault handling on against off, over generated rigs and drives.

    .venv/bin/python bench/short_windows.py [--seeds 0-149] [--min-rate 200] [--jobs 2]

The rigs are tests/test_robust_short_windows.py's ``healthy_rig`` (2-8 mice in any layout
and yaw, 125-8000 Hz, USB gaps and late stamps on some, the true CPIs configured, windows
at 50-400 Hz); only those whose windows are at ``--min-rate`` Hz or more are run.  A
window's motion shrinks with its length while the error late stamps put in it does not,
which is what robust.EVIDENCE_S (the re-admission's groups) is for: docs/models.md,
"Health".

Prints one line per drive (seed, window rate, mice, model, the largest share of the drive
a mouse spent excluded and its longest exclusion, end error on and off, mm), then how many
drives kept a mouse out for 80 % of the drive or more, the end errors' median and p90,
and how many drives ended worse than twice fault handling off's error plus 10 mm.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from test_robust_short_windows import healthy_config, healthy_rig  # noqa: E402  (one generator)

from mousedom.fusion import robust, scenarios, sim  # noqa: E402
from mousedom.fusion.drives import drive  # noqa: E402

Row = tuple[int, float, int, str, float, float, float, float]


def one(seed: int, min_rate: float) -> Row | None:
    """(seed, window rate, mice, model, largest share out, longest exclusion s, end error
    on, off, metres), or None where the rig's windows are slower than ``min_rate``."""
    rig, duration, drive_seed = healthy_rig(seed)
    if rig.rate_hz < min_rate:
        return None
    result = sim.simulate(rig, drive(duration, drive_seed), seed=seed)
    errors = []
    share = longest = 0.0
    for enabled in (True, False):
        batch, _ = scenarios.run(result, healthy_config(rig, enabled))
        e = scenarios.end_pose_error(result, batch)
        errors.append(float(np.hypot(e[0], e[1])))
        if enabled:
            out = np.asarray(batch.state) == robust.EXCLUDED
            share = float(out.mean(axis=0).max()) if out.size else 0.0
            for column in out.T:
                # the longest run of True: where each run starts and ends
                edges = np.flatnonzero(np.diff(np.r_[0, column.astype(np.int8), 0]))
                runs = edges[1::2] - edges[0::2]
                if runs.size:
                    longest = max(longest, float(runs.max()) / rig.rate_hz)
    return seed, rig.rate_hz, len(rig.mice), rig.model, share, longest, errors[0], errors[1]


def _seeds(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=_seeds, default=_seeds("0-149"), help="first-last")
    ap.add_argument("--min-rate", type=float, default=200.0, help="windows per second")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    with ProcessPoolExecutor(args.jobs) as pool:
        found = pool.map(one, args.seeds, [args.min_rate] * len(args.seeds))
        rows = [r for r in found if r is not None]
    print(f"{'seed':>5s} {'Hz':>5s} {'mice':>4s} {'model':>10s} {'out':>5s} {'longest s':>9s} "
          f"{'on mm':>8s} {'off mm':>8s}")  # fmt: skip
    for seed, rate, n, model, share, longest, on, off in rows:
        print(f"{seed:5d} {rate:5g} {n:4d} {model:>10s} {share:5.2f} {longest:9.1f} "
              f"{1000 * on:8.1f} {1000 * off:8.1f}")  # fmt: skip
    if not rows:
        print("no drive at that window rate")
        return
    on = 1000 * np.array([r[6] for r in rows])
    off = 1000 * np.array([r[7] for r in rows])
    kept = sum(r[4] >= 0.8 for r in rows)
    worse = int(np.sum(on > 2 * off + 10))
    print(f"{len(rows)} drives at {args.min_rate:g} Hz windows or more: a mouse out for 80 % of "
          f"the drive or more in {kept}")  # fmt: skip
    print(f"  end error mm, median / p90: on {np.median(on):.1f} / {np.percentile(on, 90):.1f}, "
          f"off {np.median(off):.1f} / {np.percentile(off, 90):.1f}")  # fmt: skip
    print(f"  on worse than twice off and 10 mm: {worse}")


if __name__ == "__main__":
    main()
