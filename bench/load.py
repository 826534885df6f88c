"""The daemon's CPU as a function of load, to size a board: 1 to 8 mice at 125 to 8000 Hz.

    .venv/bin/python bench/load.py [--seconds 3] [--cores c python] [--plot docs/cpu-vs-load.png]

For each number of mice and report rate, bench/daemon.py's floor (a 100 Hz batched reader
of the same FIFOs) and ``mousedom run`` (POSE at 100 Hz) with each core (``MOUSEDOM_CORE``:
the compiled one and the Python, issue 28) are measured in turn on the same feeder; printed
as a table of % of one core (this machine's: scale by a board's speed), and drawn with
``--plot`` (matplotlib).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))

import daemon as bench_daemon  # noqa: E402  (bench/daemon.py)

MICE = (1, 2, 4, 8)
RATES = (125.0, 500.0, 1000.0, 8000.0)
STYLE = {"c": "o-", "python": "s--"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--cores", nargs="+", choices=("c", "python"), default=["c", "python"])
    ap.add_argument("--plot", metavar="OUT.png")
    args = ap.parse_args()
    ours: dict[tuple[str, int, float], float] = {}
    floor: dict[tuple[int, float], float] = {}
    saved = os.environ.get("MOUSEDOM_CORE")
    with tempfile.TemporaryDirectory(prefix="mousedom-load-") as tmp:
        for n in MICE:
            for hz in RATES:
                bench_daemon.configure(n, hz)
                d = Path(tmp) / f"{n}x{hz:g}"
                d.mkdir()
                floor[n, hz] = 100 * bench_daemon.run_floor(d, args.seconds, args.rate_hz)["cpu"]
                line = f"{n} mice x {hz:6g} Hz: floor {floor[n, hz]:5.2f} %"
                for core in args.cores:
                    os.environ["MOUSEDOM_CORE"] = core  # the daemon inherits it
                    run = d / core
                    run.mkdir()
                    cpu = bench_daemon.run_daemon(run, args.seconds, args.rate_hz)["cpu"]
                    ours[core, n, hz] = 100 * cpu
                    line += f", core {core} {ours[core, n, hz]:6.2f} %"
                print(line, flush=True)
    if saved is None:
        os.environ.pop("MOUSEDOM_CORE", None)
    else:
        os.environ["MOUSEDOM_CORE"] = saved
    print(f"\n% of one core, POSE at {args.rate_hz:g} Hz ("
          + " / ".join(f"core {c}" for c in args.cores) + " / floor)")  # fmt: skip
    print("mice  " + "".join(f"{hz:>24g} Hz" for hz in RATES))
    for n in MICE:
        cells = (" /".join(f"{ours[c, n, hz]:6.2f}" for c in args.cores)
                 + f" /{floor[n, hz]:5.2f}" for hz in RATES)  # fmt: skip
        print(f"{n:4d}  " + "".join(f"{cell:>27s}" for cell in cells))
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4.5))
        for n in MICE:
            xs = [n * hz for hz in RATES]
            color = None
            for core in args.cores:
                (line,) = ax.plot(xs, [ours[core, n, hz] for hz in RATES], STYLE[core],
                                  color=color, label=f"{n} mice, core {core}")  # fmt: skip
                color = line.get_color()
            ax.plot(xs, [floor[n, hz] for hz in RATES], "x:", color=color)
        ax.set_xscale("log")
        ax.set_xlabel("reports per second (all mice)")
        ax.set_ylabel("% of one core")
        ax.set_title(f"mousedom run, POSE at {args.rate_hz:g} Hz (dotted: the 100 Hz floor)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=100)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
