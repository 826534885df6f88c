"""The daemon's window, phase by phase, in process: CPU after a sleep, and code touched.

    .venv/bin/python bench/window.py [--mice 4] [--report-hz 1000] [--windows 400] [--sparse 1]

A real ``Daemon`` (real FIFOs as its evdev sources, its socket, one client in a child
process) is driven window by window from here, without its loop: each window's reports
are written into the FIFOs, the process sleeps 10 ms as the daemon does between windows,
and then the three phases of a window run as the loop runs them:

- read: ``Sensors.read_due`` (one read per source, decoding, the tracker's queue);
- poll: ``Tracker.poll`` (the count functions, the solve, the fault test, the covariance);
- publish: ``Publisher.publish`` (the POSE line, the send to the client);
- settle: ``Tracker.settle``, the learning of the blocks a window ends, after its POSE.

Prints each phase's thread CPU time (median over the windows after the first tenth), the
first three's sum (the window's work before its POSE) at the 99th percentile, and
for one window after the warm-up the bytecode it runs: distinct instructions (a window's
cost after a sleep follows how much code and data it touches, see docs/performance.md),
instructions executed and code objects.  The instruction counts are exact and the same
on any machine, so a change to the per-window path can be judged by them where the CPU
figures are too noisy.  Stamps are those of the window (a virtual clock), so the wait
for reports is not part of it: ``bench/daemon.py`` measures the whole daemon.
"""

from __future__ import annotations

import argparse
import collections
import math
import os
import statistics
import subprocess
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
from mousedom.service.daemon import Daemon  # noqa: E402
from mousedom.sources.events import EV_REL, EV_SYN, EVENT_DTYPE, SYN_REPORT  # noqa: E402

PERIOD = 0.01  # POSE at 100 Hz
T0 = 1000.0  # the virtual clock's start
CLIENT = "import socket, sys\ns = socket.socket(socket.AF_UNIX)\ns.connect(sys.argv[1])\n" \
         "while s.recv(65536):\n    pass\n"  # fmt: skip


def reports(times: list[float], dx: int, dy: int) -> bytes:
    """REL_X, REL_Y, SYN_REPORT per stamp, as the kernel writes them."""
    n = len(times)
    ev = np.zeros(3 * n, dtype=EVENT_DTYPE)
    usec = np.round(np.asarray(times) * 1e6).astype(np.int64)
    for j in range(3):
        ev["sec"][j::3], ev["usec"][j::3] = usec // 1_000_000, usec % 1_000_000
    ev["type"] = [EV_REL, EV_REL, EV_SYN] * n
    ev["code"] = [0, 1, SYN_REPORT] * n
    ev["value"] = [dx, dy, 0] * n
    return ev.tobytes()


class Rig:
    """A daemon with its sources open on FIFOs and a client on its socket."""

    def __init__(self, d: Path, n_mice: int, report_hz: float, sparse: int = 1) -> None:
        bench_daemon.configure(n_mice, report_hz)
        self.n_mice, self.report_hz, self.sparse = n_mice, report_hz, sparse
        fifos = [d / f"{m}.fifo" for m in bench_daemon.MICE]
        for f in fifos:
            os.mkfifo(f)
        config = load_config(bench_daemon.write_config(d, fifos, 1.0 / PERIOD))
        self.now = T0
        self.daemon = dm = Daemon(config, str(d / "d.sock"), clock=lambda: self.now,
                                  handle_signals=False)  # fmt: skip
        # A FIFO opens for writing only once it has a reader: hold one while the daemon
        # opens its own.
        held = [os.open(f, os.O_RDONLY | os.O_NONBLOCK) for f in fifos]
        self.writers = [os.open(f, os.O_WRONLY | os.O_NONBLOCK) for f in fifos]
        dm.server.refuse_if_taken()
        dm.running.replace(dm.config, dm.reloader.tracker_class(dm.config, t0=T0))
        dm.sensors.start(T0)
        for fd in held:
            os.close(fd)
        dm.tracker.complete_until(T0 - dm.sensors.max_latency())
        dm.server.open()
        self.client = subprocess.Popen([sys.executable, "-c", CLIENT, str(d / "d.sock")])
        deadline = time.monotonic() + 10
        while not dm.server.clients:
            for key, mask in dm.selector.select(0.01):
                key.data(mask)
            if time.monotonic() > deadline:
                raise SystemExit("the client did not connect")
        self.k = 0
        self.sent = [0] * n_mice  # reports written per mouse
        self.last = [-math.inf] * n_mice  # the last one's stamp

    def feed(self) -> None:
        """Window k's reports: each mouse's up to its first one past the window's end (its
        own rate, phase-shifted per mouse, whatever the rate's ratio to the windows), and
        the clock set to when the daemon would wake for that window."""
        end = T0 + (self.k + 1) * PERIOD
        period = 1.0 / self.report_hz
        gap = self.sparse * period  # (a slow mouse reports only when it has a count)
        first_after = []
        for i, fd in enumerate(self.writers):
            times = []
            while self.last[i] <= end:
                self.sent[i] += 1
                self.last[i] = T0 + (i + 0.5) * gap / self.n_mice + self.sent[i] * gap
                times.append(self.last[i])
            if times:
                os.write(fd, reports(times, 1, -3))
            first_after.append(self.last[i])
        # As the daemon wakes (its _plan): the window is final when no report still to
        # come can join a mouse's first span past its end, half a period after it, plus
        # the read latency (0 for a paced source such as these FIFOs), here 0.1 ms on.
        self.now = max(first_after) + 0.5 * period + self.daemon.sensors.max_latency() + 1e-4
        self.k += 1

    def phases(self):
        dm = self.daemon
        box = []
        return (
            ("read", lambda: dm.sensors.read_due(self.now)),
            ("poll", lambda: box.append(dm.tracker.poll(defer_learning=True, one_by_one=True))),
            ("publish", lambda: dm.publisher.publish(box.pop())),
            ("settle", lambda: dm.tracker.settle()),
        )

    def close(self) -> None:
        self.client.kill()
        self.client.wait()


def timed(rig: Rig, windows: int) -> dict[str, list[int]]:
    costs: dict[str, list[int]] = collections.defaultdict(list)
    clock = time.thread_time_ns
    for w in range(windows):
        rig.feed()
        time.sleep(PERIOD)
        total = to_pose = 0
        for name, run in rig.phases():
            t0 = clock()
            run()
            spent = clock() - t0
            total += spent
            if name != "settle":
                to_pose += spent
            if w >= windows // 10:
                costs[name].append(spent)
        if w >= windows // 10:
            costs["window"].append(total)
            costs["to POSE"].append(to_pose)
    return costs


def footprint(rig: Rig) -> dict[str, tuple[int, int, int]]:
    """(distinct instructions, instructions executed, code objects) per phase, one window."""
    rig.feed()
    out = {}
    for name, run in rig.phases():
        seen: collections.Counter = collections.Counter()

        def tracer(frame, event, arg, seen=seen):
            frame.f_trace_opcodes = True
            if event == "opcode":
                seen[(frame.f_code, frame.f_lasti)] += 1
            return tracer

        sys.settrace(tracer)
        try:
            run()
        finally:
            sys.settrace(None)
        out[name] = (len(seen), sum(seen.values()), len({code for code, _ in seen}))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mice", type=int, default=4)
    ap.add_argument("--report-hz", type=float, default=1000.0)
    ap.add_argument("--windows", type=int, default=400)
    ap.add_argument("--sparse", type=int, default=1, metavar="K",
                    help="each mouse reports every K-th period, as a mouse moving slowly "
                         "(only when it has a count): K >= 2 makes the windows' edges cut "
                         "long report spans")  # fmt: skip
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="mousedom-window-") as tmp:
        rig = Rig(Path(tmp), args.mice, args.report_hz, args.sparse)
        try:
            costs = timed(rig, args.windows)
            code = footprint(rig)
        finally:
            rig.close()
    # Each window is closed by the next one's reports or by the time past its last ones;
    # the last (footprint's) may wait for the silence rule (late_report_s), never reached.
    if not rig.k - 1 <= rig.daemon.poses <= rig.k:
        raise SystemExit(f"{rig.daemon.poses} poses for {rig.k} windows: the rig is off")
    every = f" (reporting every {args.sparse} periods)" if args.sparse > 1 else ""
    print(f"{args.mice} mice x {args.report_hz:g} Hz{every}, POSE at {1 / PERIOD:g} Hz, "
          f"{args.windows} windows, each after a {PERIOD * 1e3:g} ms sleep")  # fmt: skip
    print(f"{'phase':10s}{'CPU us (median)':>17s}{'distinct instr.':>17s}{'executed':>10s}"
          f"{'code objects':>14s}")  # fmt: skip
    for name in ("read", "poll", "publish", "settle"):
        distinct, executed, objects = code[name]
        print(f"{name:10s}{statistics.median(costs[name]) / 1e3:17.1f}{distinct:17d}"
              f"{executed:10d}{objects:14d}")  # fmt: skip
    total = [sum(v[i] for v in code.values()) for i in range(3)]  # (code objects: per phase)
    print(f"{'window':10s}{statistics.median(costs['window']) / 1e3:17.1f}{total[0]:17d}"
          f"{total[1]:10d}{total[2]:14d}")  # fmt: skip
    before = sorted(costs["to POSE"])
    p99 = before[99 * len(before) // 100]
    print(f"before the POSE (read, poll, publish): median "
          f"{statistics.median(before) / 1e3:.1f} us, p99 {p99 / 1e3:.1f} us, "
          f"max {before[-1] / 1e3:.1f} us")  # fmt: skip


if __name__ == "__main__":
    main()
