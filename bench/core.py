"""Core engine figures: accuracy on the simulated UMBmark square, and throughput.

    python bench/core.py [--seconds 600] [--repeats 5]

Accuracy: the 4 m UMBmark square clockwise and counter-clockwise, mice at 450 CPI reporting
at 125 Hz with asynchronous phases, quantization only (no other noise); end-position and
heading error for every model and integrator.  Throughput: mouse reports per second through
the core (windowing with proportional splitting, model, integration, covariance), medians
over repeats, next to a baseline measured in the same run: naive bucketing of each report
into the window of its time stamp (np.bincount) followed by the same model and integrator.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from timing import median_time  # noqa: E402  (bench/timing.py)

from mousedom.fusion import (
    integrate,
    models,
    sim,  # noqa: E402
)
from mousedom.fusion.tracker import Tracker  # noqa: E402
from mousedom.fusion.units import counts_matrices, sigma_metres  # noqa: E402


def two_mouse_rig() -> sim.Rig:
    return sim.Rig(
        (
            sim.SimMouse("left", 0.0, 0.135, phase=0.0),
            sim.SimMouse("right", 0.0, -0.135, phase=0.0031),
        )
    )


def accuracy(rate_hz: float) -> None:
    rigs = {"3 mice": sim.three_mouse_rig(), "2 mice": two_mouse_rig()}
    runs = {
        (name, cw): sim.simulate(rig, sim.umbmark_square(cw=cw))
        for name, rig in rigs.items()
        for cw in (True, False)
    }
    print(
        f"\nUMBmark 4 m square, 450 CPI, 125 Hz, async phases, quantization only, "
        f"{rate_hz:g} Hz output windows"
    )
    print(
        f"{'rig':7} {'model':10} {'integrator':9} | {'cw mm':>8} {'cw deg':>8} |"
        f" {'ccw mm':>8} {'ccw deg':>8}"
    )
    for rig_name in rigs:
        for model in ("lsq", "diff-drive", "bonarini"):
            if model == "bonarini" and rig_name != "2 mice":
                continue
            for integrator in integrate.INTEGRATORS:
                cells = []
                for cw in (True, False):
                    res = runs[(rig_name, cw)]
                    cfg = sim.rig_config(sim.Rig(res.rig.mice, rate_hz=rate_hz, model=model))
                    poses, _ = sim.run_tracker(res, cfg, integrator=integrator)
                    truth = res.truth(poses.t[-1])[0]
                    pos = 1000 * math.hypot(poses.x[-1] - truth[0], poses.y[-1] - truth[1])
                    head = math.degrees(poses.theta[-1] - truth[2])
                    cells.append(f"{pos:8.3f} {head:8.4f}")
                print(f"{rig_name:7} {model:10} {integrator:9} | {cells[0]} | {cells[1]}")


def naive(cfg, result: sim.SimResult) -> int:
    """Baseline: bucket each report into the window of its stamp, then the same maths."""
    period = 1 / cfg.rate_hz
    n_win = int(result.duration / period) + 2
    counts = np.zeros((n_win, len(cfg.mice), 2))
    for i, m in enumerate(cfg.mice):
        r = result.reports[m.name]
        k = (r.t / period).astype(int)
        counts[:, i, 0] = np.bincount(k, r.dx, n_win)
        counts[:, i, 1] = np.bincount(k, r.dy, n_win)
    d = np.einsum("nij,knj->kni", counts_matrices(cfg.mice), counts)
    pos = np.array([[m.mount.x, m.mount.y] for m in cfg.mice])
    sol = models.solve(cfg.model, d, pos, np.array([sigma_metres(m) for m in cfg.mice]))
    poses = integrate.compose(np.zeros(3), integrate.body_step(sol.q, cfg.integrator))
    return len(poses)


def throughput(seconds: float, repeats: int) -> None:
    mice = tuple(
        sim.SimMouse(f"m{i}", 0.15 * math.cos(a), 0.15 * math.sin(a), report_hz=1000,
                     phase=i * 0.00023)
        for i, a in enumerate(np.linspace(0, 2 * math.pi, 4, endpoint=False))
    )  # fmt: skip
    rig = sim.Rig(mice)
    legs = [sim.arc(0.5, 1.0, 0.3), sim.turn(-1.5), sim.straight(2.0, 0.3), sim.arc(-0.8, 2.0)]
    path = []
    while sum(s.duration for s in path) < seconds:
        path += [s for leg in legs for s in leg]
    result = sim.simulate(rig, path)
    n = result.total_reports()
    cfg = sim.rig_config(rig)

    def one_batch() -> None:
        sim.run_tracker(result, cfg)

    def chunked() -> None:
        tr = Tracker(cfg, t0=0.0)
        chunk = 1.0
        for lo in np.arange(0.0, result.duration + chunk, chunk):
            for name, r in result.reports.items():
                a, b = np.searchsorted(r.t, [lo, lo + chunk], side="right")
                tr.push(name, r.t[a:b], r.dx[a:b], r.dy[a:b])
            tr.complete_until(lo + chunk)
            tr.poll()
        tr.finish()

    def baseline() -> None:
        naive(cfg, result)

    print(
        f"\nthroughput: {n} reports from 4 mice at 1 kHz, {result.duration:.0f} s, "
        f"{cfg.rate_hz:g} Hz windows, lsq + exact; median of {repeats}"
    )
    rates = {}
    for label, fn in (
        ("baseline (naive bucketing)", baseline),
        ("tracker, one batch", one_batch),
        ("tracker, 1 s chunks", chunked),
    ):
        rates[label] = n / median_time(fn, repeats)
    base = rates["baseline (naive bucketing)"]
    for label, rate in rates.items():
        print(f"  {label:28} {rate / 1e6:7.2f} M reports/s  ({rate / base:5.2f} x baseline)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0, help="simulated run length")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    # 100 Hz is the default; 4 Hz windows (turning 0.125 rad per window) separate the
    # integrators the way Hong's table predicts.
    for rate in (100.0, 4.0):
        accuracy(rate)
    throughput(args.seconds, args.repeats)


if __name__ == "__main__":
    main()
