"""What one window costs after the daemon's sleep: the cold-cache figures of performance.md.

    .venv/bin/python bench/cold.py [--mice 2] [--report-hz 125] [--windows 400]

The daemon sleeps between windows, so each one starts on caches that other work (or the
core's idle state) has emptied.  Prints, as medians of the thread's CPU time over
``--windows`` tries, each after a sleep of 0, 1 and 10 ms:

- the tracker's window for the load (the reports of one window pushed, then the poll);
- an empty call, the first numpy call and the first float repr of a wake-up, and 200
  lines of float arithmetic (one function), to show what the cost follows: the first use
  of each C path after the wake-up, not the number of bytecodes.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import daemon as bench_daemon  # noqa: E402  (bench/daemon.py: its rig config)
import numpy as np  # noqa: E402

from mousedom.config import load_config  # noqa: E402
from mousedom.fusion.tracker import Tracker  # noqa: E402

SLEEPS = (0.0, 0.001, 0.01)

_ARITHMETIC = "def arithmetic(x, y):\n    a0 = 1.0\n" + "".join(
    f"    a{i} = x * {i}.5 + y * a{i - 1}\n" for i in range(1, 200)
) + "    return a199\n"  # fmt: skip
_NS: dict = {}
exec(_ARITHMETIC, _NS)  # noqa: S102 - a fixed, generated function body


def cost_after(sleep: float, step, tries: int) -> float:
    """Median thread CPU time (us) of ``step()`` run right after sleeping ``sleep`` s."""
    costs = []
    for _ in range(tries):
        if sleep:
            time.sleep(sleep)
        t0 = time.thread_time_ns()
        step()
        costs.append(time.thread_time_ns() - t0)
    return statistics.median(costs[tries // 10 :]) / 1e3


def tracker_step(n_mice: int, report_hz: float):
    """A step that pushes one window's reports per mouse and polls, window after window."""
    d = Path(tempfile.mkdtemp(prefix="mousedom-cold-"))
    config = load_config(bench_daemon.write_config(d, [d / f"x{m}" for m in bench_daemon.MICE],
                                                   100.0))  # fmt: skip
    tracker = Tracker(config, t0=0.0)
    per = max(1, int(report_hz / 100))
    window = [0]

    def step() -> None:
        start = window[0] / 100
        for i in range(n_mice):
            t = [start + (i + 0.5) / (n_mice * report_hz) + k / report_hz for k in range(per)]
            tracker.push(i, t, [1] * per, [-3] * per)
            tracker.complete_until(start + 0.01, mouse=i)
        tracker.poll()
        window[0] += 1

    return step


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mice", type=int, default=2)
    ap.add_argument("--report-hz", type=float, default=125.0)
    ap.add_argument("--windows", type=int, default=400)
    args = ap.parse_args()
    bench_daemon.configure(args.mice, args.report_hz)
    arithmetic = _NS["arithmetic"]
    steps = {
        f"tracker window, {args.mice} mice x {args.report_hz:g} Hz": None,
        "empty call": lambda: None,
        "np.array of three floats": lambda: np.array([1.0, 2.0, 3.0]),
        "one float repr": lambda: repr(0.123456789),
        "200 lines of float arithmetic": lambda: arithmetic(1.0, 1e-9),
    }
    print(f"thread CPU per step, us (median of {args.windows}), after a sleep of")
    print(f"{'':40s}" + "".join(f"{s * 1e3:>9g} ms" for s in SLEEPS))
    for name, step in steps.items():
        row = []
        for sleep in SLEEPS:
            run = step or tracker_step(args.mice, args.report_hz)  # a fresh tracker per column
            row.append(cost_after(sleep, run, args.windows))
        print(f"{name:40s}" + "".join(f"{v:12.1f}" for v in row))


if __name__ == "__main__":
    main()
