"""Daemon cost and latency next to the two baselines a user would compare it with.

    .venv/bin/python bench/daemon.py [--mice 4] [--report-hz 1000] [--seconds 8] [--rounds 3]
                                     [--sparse 1] [--still 0]

A feeder process writes each mouse's reports (REL_X, REL_Y, SYN_REPORT; 72 bytes) into its
FIFO when due, stamped with the CLOCK_MONOTONIC time of the write, as the kernel stamps a
real mouse's events.  Four readers of the same load take turns, each round all four:

- the floor: a reader that wakes at the output rate (100 Hz) and reads all the FIFOs,
  discarding the bytes: the least any design that batches per window can pay;
- a peer-style daemon: a plain Python loop that wakes for every report (poll on the
  FIFOs), sums its counts, and per window solves the least squares with numpy and writes a
  JSON pose line to a client;
- the Python minimum: what a pure-Python daemon of this design cannot do without (one wake
  and one read per FIFO per window, counts summed, a fixed pseudo-inverse, a chi-square,
  the arc, the covariance, a 16-float line sent; see MINIMUM): how near the floor Python
  can come at all;
- ``mousedom run`` (the evdev source's FIFO hook), with a client reading POSE lines.

Figures: each one's CPU (from /proc/PID/schedstat) as % of one core, medians over the
rounds and the median per-round ratios to the floor and to the peer; mousedom's latency
beyond the window wait (a window [T - P, T] can close only once every mouse has reported
past T, at c(T); the latency is from c(T) to that window's POSE reaching the client).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mousedom.sources.base import Source  # noqa: E402
from mousedom.sources.events import EV_REL, EV_SYN, EVENT_DTYPE, SYN_REPORT  # noqa: E402

ALL_MICE = ("front", "left", "rear", "right", "m4", "m5", "m6", "m7")
MICE = ALL_MICE[:4]
REPORT_HZ = 1000.0
SPARSE = 1  # each mouse reports every SPARSE-th period (a slow robot: only with a count)
# The last STILL mice stop reporting after STILL_AFTER_S (a mouse on the axis of a turn in
# place, or lifted): each window waits late_report_s for them, while the others report.
STILL = 0
STILL_AFTER_S = 0.5


def configure(n_mice: int, report_hz: float, sparse: int = 1, still: int = 0) -> None:
    """The load of the runs that follow (module settings: the feeder child reads them
    from its arguments)."""
    global MICE, REPORT_HZ, SPARSE, STILL
    MICE = ALL_MICE[:n_mice]
    REPORT_HZ = float(report_hz)
    SPARSE = int(sparse)
    STILL = int(still)


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/schedstat") as f:
        return int(f.read().split()[0]) / 1e9


def record(t: float, dx: int, dy: int) -> bytes:
    ev = np.zeros(3, dtype=EVENT_DTYPE)
    usec = int(round(t * 1e6))
    ev["sec"], ev["usec"] = usec // 1_000_000, usec % 1_000_000
    ev["type"] = [EV_REL, EV_REL, EV_SYN]
    ev["code"] = [0, 1, SYN_REPORT]
    ev["value"] = [dx, dy, 0]
    return ev.tobytes()


# ----------------------------------------------------------------------------- feeder


def feeder(
    paths: list[str], seconds: float, out: str, report_hz: float, sparse: int = 1, still: int = 0
) -> None:
    """Child process: write every mouse's reports when due (every ``sparse``-th period;
    the last ``still`` mice only for STILL_AFTER_S); save the stamps."""
    fds = []
    for p in paths:
        while True:
            try:
                fds.append(os.open(p, os.O_WRONLY | os.O_NONBLOCK))
                break
            except OSError:
                time.sleep(0.01)
    for fd in fds:
        os.set_blocking(fd, True)
    n = len(paths)
    period = 1.0 / report_hz
    start = time.monotonic() + 0.2
    # mouse i reports at start + i*period/n + k*period: phases spread over the period
    stamps: list[list[float]] = [[] for _ in range(n)]
    k = 0
    end = start + seconds
    while True:
        moving = n if k * period < STILL_AFTER_S else n - still
        for i in range(moving if k % sparse == 0 else 0):
            due = start + k * period + i * period / n
            now = time.monotonic()
            if due > now:
                # no busy-wait: on this shared 2-core machine it would steal the daemon's
                # core; the stamp is the real write time, so a late write is still exact
                time.sleep(due - now)
            t = time.monotonic()
            try:
                os.write(fds[i], record(t, 1, -3))
            except BrokenPipeError:
                return
            stamps[i].append(t)
        k += 1
        if start + k * period > end:
            break
    for fd in fds:
        os.close(fd)
    np.savez(out, *[np.array(s) for s in stamps])


# ----------------------------------------------------------------------------- daemon run


def positions(n: int) -> list[tuple[float, float]]:
    """Mice on a circle of 15 cm round the body origin."""
    return [(0.15 * np.cos(2 * np.pi * k / n), 0.15 * np.sin(2 * np.pi * k / n)) for k in range(n)]


def write_config(d: Path, fifos: list[Path], rate_hz: float, extra: str = "") -> Path:
    model = "lsq" if len(fifos) > 1 else "diff-drive"  # one mouse: Hong's model
    lines = [f"rate_hz: {rate_hz}", f"model: {model}", "integrator: exact", "mice:"]
    for name, (x, y), fifo in zip(MICE[: len(fifos)], positions(len(fifos)), fifos, strict=True):
        lines += [
            f"  {name}:",
            f"    evdev: {{path: {fifo}, grab: false}}",
            "    cpi: 1000",
            f"    mount: {{x: {float(x)!r}, y: {float(y)!r}, yaw: 0}}",
            f"    report_hz: {REPORT_HZ}",
        ]
    path = d / "bench.yaml"
    path.write_text("\n".join(lines) + "\n" + extra)
    return path


# Every child this bench starts (readers, daemons, feeders): main() ends them if the bench
# itself is stopped, so that none goes on loading the machine (a ``mousedom run`` left by
# a bench killed by ``timeout`` once ran for 40 minutes under the next measurements).
_CHILDREN: list[subprocess.Popen] = []


def _spawn(args: list[str], **kw) -> subprocess.Popen:
    proc = subprocess.Popen(args, **kw)
    _CHILDREN.append(proc)
    return proc


def start_feeder(fifos: list[Path], seconds: float, out: Path) -> subprocess.Popen:
    """The feeder runs as this file with --feed, in its own process (its own core)."""
    return _spawn(
        [sys.executable, __file__, "--feed", str(out), str(seconds), str(REPORT_HZ),
         str(SPARSE), str(STILL), *map(str, fifos)]
    )  # fmt: skip


def run_daemon(d: Path, seconds: float, rate_hz: float, extra: str = "", on_ready=None) -> dict:
    """One measured run; ``extra`` is appended to the rig config, ``on_ready()`` is called
    once the daemon listens (bench/ros2.py starts its subscriber there)."""
    fifos = [d / f"{m}.fifo" for m in MICE]
    for f in fifos:
        os.mkfifo(f)
    daemon, sock_path = _start_daemon(d, fifos, rate_hz, extra)
    if on_ready is not None:
        on_ready()
    stamps_file = d / "stamps.npz"
    feed = start_feeder(fifos, seconds + 1.5, stamps_file)
    poses = _PoseReader(sock_path)
    ctl = _Control(sock_path)

    time.sleep(1.2)  # warm-up: the feeder starts, windows begin to close
    cpu0, wall0 = cpu_seconds(daemon.pid), time.monotonic()
    wakes0, reads0 = ctl.counters()
    time.sleep(seconds)
    wakes1, reads1 = ctl.counters()
    cpu1, wall1 = cpu_seconds(daemon.pid), time.monotonic()
    ctl.close()
    feed.wait()
    time.sleep(0.2)
    poses.stop.set()
    daemon.send_signal(signal.SIGTERM)
    daemon.wait(5)
    poses.sock.close()

    data = np.load(stamps_file)
    stamps = [data[k] for k in data.files][: len(MICE) - STILL]  # (latency: the moving)
    after_c, after_f = _latencies(poses.received, stamps, wall0, wall1)
    n_poses = sum(1 for _, a in poses.received if wall0 <= a <= wall1)
    return {
        "stamps": stamps,
        "window": (wall0, wall1),
        "cpu": (cpu1 - cpu0) / (wall1 - wall0),
        "lat_ms": np.array(after_c) * 1e3,
        "lat_final_ms": np.array(after_f) * 1e3,
        "pose_hz": n_poses / (wall1 - wall0),
        "period": 1.0 / rate_hz,
        "reports": sum(len(s) for s in stamps),
        "wakes_hz": (wakes1 - wakes0) / (wall1 - wall0),
        "reads_hz": (reads1 - reads0) / (wall1 - wall0),
    }


def _start_daemon(
    d: Path, fifos: list[Path], rate_hz: float, extra: str
) -> tuple[subprocess.Popen, Path]:
    """``mousedom run`` on the FIFOs, once its socket is there."""
    config = write_config(d, fifos, rate_hz, extra)
    sock_path = d / "mousedom.sock"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    daemon = _spawn(
        [
            sys.executable,
            *os.environ.get("BENCH_DAEMON_PY_ARGS", "").split(),
            "-m",
            "mousedom",
            "run",
            "--config",
            str(config),
        ]
        + ["--socket", str(sock_path)],
        env=env,
        stderr=subprocess.DEVNULL,
    )
    while not sock_path.exists():
        if daemon.poll() is not None:
            raise SystemExit("daemon did not start")
        time.sleep(0.02)
    return daemon, sock_path


class _PoseReader:
    """A client on its own thread that notes each POSE's t and when it arrived."""

    def __init__(self, sock_path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(str(sock_path))
        self.received: list[tuple[float, float]] = []  # (pose t, arrival time)
        self.stop = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        f = self.sock.makefile("rb")
        for line in f:
            now = time.monotonic()
            if line.startswith(b'{"class":"POSE"'):
                self.received.append((json.loads(line)["t"], now))
            if self.stop.is_set():
                break


class _Control:
    """A second client, with no poses of its own, that asks for the daemon's counters."""

    def __init__(self, sock_path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(str(sock_path))
        self.lines = self.sock.makefile("rb")
        self.sock.sendall(b'{"cmd": "rate", "hz": 0}\n')

    def counters(self) -> tuple[int, int]:
        """(wakes, source reads) so far."""
        self.sock.sendall(b'{"cmd": "status"}\n')
        for line in self.lines:
            msg = json.loads(line)
            if msg["class"] == "STATUS":
                return msg["wakes"], msg["source_reads"]
        raise SystemExit("daemon went away")

    def close(self) -> None:
        self.sock.close()


def _latencies(
    received: list[tuple[float, float]], stamps: list[np.ndarray], wall0: float, wall1: float
) -> tuple[list[float], list[float]]:
    """Each pose that arrived in [wall0, wall1]: its arrival after c(T), when the last mouse
    reported past its T (that mouse's first stamp after T), and after f(T), when the count
    functions make the window final: each mouse's second report after T, or P/2 plus the
    source's read latency after its first, whichever is sooner (a report within P/2 may
    still join the first one's span: CountFunction.frontier).  The targets are set on the
    first; the second is what the loop adds to the rule's own wait.  Poses past a mouse's
    last report but one are left out."""
    after_c, after_f = [], []
    for t_pose, arrival in received:
        firsts, finals = [], []
        for s in stamps:
            j = np.searchsorted(s, t_pose, side="right")
            if j + 1 >= len(s):
                break
            firsts.append(s[j])
            finals.append(min(s[j + 1], s[j] + 0.5 / REPORT_HZ + Source.latency))
        else:
            if wall0 <= arrival <= wall1:
                after_c.append(arrival - max(firsts))
                after_f.append(arrival - max(finals))
    return after_c, after_f


# ----------------------------------------------------------------------------- baselines

FLOOR = r"""
import os, sys, time
rate = float(sys.argv[1])
fds = [os.open(p, os.O_RDONLY | os.O_NONBLOCK) for p in sys.argv[2:]]
open_ = set(fds)
tick = time.monotonic()
while open_:
    tick += 1.0 / rate
    delay = tick - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    for fd in list(open_):
        try:
            while len(os.read(fd, 65536)) == 65536:
                pass
        except BlockingIOError:
            pass
        else:
            pass
        # a writer that has gone reads as b"" at once: stop when all have
    if time.monotonic() > float(os.environ["BENCH_END"]):
        break
"""

PEER = r"""
import json, os, select, socket, struct, sys, time
import numpy as np
rate, sock_path, xy = float(sys.argv[1]), sys.argv[2], json.loads(sys.argv[3])
paths = sys.argv[4:]
fds = [os.open(p, os.O_RDONLY | os.O_NONBLOCK) for p in paths]
index = {fd: i for i, fd in enumerate(fds)}
n = len(fds)
A = np.zeros((2 * n, 3))
for i, (x, y) in enumerate(xy):
    A[2 * i] = (1, 0, -y)
    A[2 * i + 1] = (0, 1, x)
srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
srv.bind(sock_path)
srv.listen(1)
client, _ = srv.accept()
poll = select.poll()
for fd in fds:
    poll.register(fd, select.POLLIN)
ev = struct.Struct("<qqHHi")
acc = np.zeros((n, 2))
pose = np.zeros(3)
rest = {fd: b"" for fd in fds}
period = 1.0 / rate
next_t = time.monotonic() + period
end = float(os.environ["BENCH_END"])
while time.monotonic() < end:
    timeout = max(0.0, next_t - time.monotonic())
    for fd, _ in poll.poll(timeout * 1000):
        try:
            data = rest[fd] + os.read(fd, 4096)
        except BlockingIOError:
            continue
        k = len(data) - len(data) % 24
        rest[fd] = data[k:]
        i = index[fd]
        for sec, usec, typ, code, value in ev.iter_unpack(data[:k]):
            if typ == 2 and code < 2:
                acc[i, code] += value
    now = time.monotonic()
    if now >= next_t:
        d = (acc * (0.0254 / 1000.0)).reshape(-1)
        q = np.linalg.lstsq(A, d, rcond=None)[0]
        c, s_ = np.cos(pose[2]), np.sin(pose[2])
        pose += (c * q[0] - s_ * q[1], s_ * q[0] + c * q[1], q[2])
        line = json.dumps({"t": next_t, "x": pose[0], "y": pose[1], "theta": pose[2]})
        client.sendall(line.encode() + b"\n")
        acc[:] = 0
        next_t += period
"""

# The least a pure-Python fusion daemon of this design can do per window, with nothing a
# robot user would miss removed only where it costs per report: wake at the output rate,
# one read per FIFO, the counts summed (no split of a report across a window edge), the
# least squares by a fixed pseudo-inverse, a chi-square of the residual (the fault test's
# arithmetic, no noise model, no health states), the exact arc, the covariance F P F' + Q,
# one POSE-sized JSON line of 16 floats sent to a client.  It shows how near the floor a
# Python daemon can come at all: mousedom adds report splitting, the learnt noise model,
# health, the silence rule, reconnection and the full POSE.
MINIMUM = r"""
import json, math, os, socket, struct, sys, time
rate, sock_path, xy = float(sys.argv[1]), sys.argv[2], json.loads(sys.argv[3])
fds = [os.open(p, os.O_RDONLY | os.O_NONBLOCK) for p in sys.argv[4:]]
n = len(fds)
A = []
for x, y in xy:
    A += [(1.0, 0.0, -y), (0.0, 1.0, x)]
# pinv = (A'A)^-1 A' once, as row lists (3 x 2n)
ata = [[sum(r[i] * r[j] for r in A) for j in range(3)] for i in range(3)]
a, b, c = ata
det = (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
       + a[2] * (b[0] * c[1] - b[1] * c[0]))
inv = [[(ata[(j + 1) % 3][(i + 1) % 3] * ata[(j + 2) % 3][(i + 2) % 3]
         - ata[(j + 1) % 3][(i + 2) % 3] * ata[(j + 2) % 3][(i + 1) % 3]) / det
        for j in range(3)] for i in range(3)]
pinv = [[sum(inv[i][k] * r[k] for k in range(3)) for r in A] for i in range(3)]
srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
srv.bind(sock_path)
srv.listen(1)
client, _ = srv.accept()
unpack = struct.Struct("<qqIi").iter_unpack  # sec, usec, type | code << 16, value
scale = 0.0254 / 1000.0
KX, KY = 2 | (0 << 16), 2 | (1 << 16)
x = y = th = 0.0
P = [[0.0] * 3 for _ in range(3)]
q2 = (scale * 0.5) ** 2
period = 1.0 / rate
tick = time.monotonic()
rest = [b""] * n
line = ('{"class":"POSE","t":%r,"x":%r,"y":%r,"theta":%r,"vx":%r,"vy":%r,"omega":%r,'
        '"cov":[%r,%r,%r,%r,%r,%r,%r,%r,%r],"used":%d,"updating":true}\n')
end = float(os.environ["BENCH_END"])
while time.monotonic() < end:
    tick += period
    delay = tick - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    d = []
    for i, fd in enumerate(fds):
        sx = sy = 0
        try:
            data = rest[i] + os.read(fd, 65536)
        except BlockingIOError:
            data = rest[i]
        k = len(data) - len(data) % 24
        rest[i] = data[k:]
        for sec, usec, key, value in unpack(data[:k]):
            if key == KX:
                sx += value
            elif key == KY:
                sy += value
        d += (sx * scale, -sy * scale)
    q = [sum(p * v for p, v in zip(row, d)) for row in pinv]
    chi2 = 0.0
    for row, v in zip(A, d):
        r = v - (row[0] * q[0] + row[1] * q[1] + row[2] * q[2])
        chi2 += r * r
    ok = chi2 < 9.0 * q2 * len(d)
    s, co = math.sin(th), math.cos(th)
    dth = q[2]
    if abs(dth) > 1e-12:
        k1, k2 = math.sin(dth) / dth, (1.0 - math.cos(dth)) / dth
    else:
        k1, k2 = 1.0, dth / 2
    bx, by = k1 * q[0] - k2 * q[1], k2 * q[0] + k1 * q[1]
    x += co * bx - s * by
    y += s * bx + co * by
    F = [[1.0, 0.0, -(s * bx + co * by)], [0.0, 1.0, co * bx - s * by], [0.0, 0.0, 1.0]]
    FP = [[sum(F[i][k] * P[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    P = [[sum(FP[i][k] * F[j][k] for k in range(3)) + (q2 if i == j else 0.0)
          for j in range(3)] for i in range(3)]
    th += dth
    client.sendall((line % (round(tick, 6), x, y, th, q[0] * rate, q[1] * rate, dth * rate,
                            *P[0], *P[1], *P[2], n if ok else 0)).encode())
"""


def _measure(proc: subprocess.Popen, seconds: float) -> tuple[float, float, float]:
    time.sleep(1.2)  # warm-up: the feeder starts
    cpu0, wall0 = cpu_seconds(proc.pid), time.monotonic()
    time.sleep(seconds)
    cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
    return (cpu1 - cpu0) / (wall1 - wall0), wall0, wall1


def run_floor(d: Path, seconds: float, rate_hz: float) -> dict:
    """The floor: wake at the output rate, read every FIFO, discard."""
    fifos = [d / f"f{m}.fifo" for m in MICE]
    for f in fifos:
        os.mkfifo(f)
    env = dict(os.environ, BENCH_END=str(time.monotonic() + seconds + 4.0))
    proc = _spawn([sys.executable, "-c", FLOOR, str(rate_hz), *map(str, fifos)], env=env)
    time.sleep(0.3)
    feed = start_feeder(fifos, seconds + 1.5, d / "fstamps.npz")
    cpu, _, _ = _measure(proc, seconds)
    feed.wait()
    proc.kill()
    proc.wait()
    return {"cpu": cpu}


def _run_script_reader(d: Path, name: str, script: str, seconds: float, rate_hz: float):
    """Run a baseline reader (a script taking rate, socket, mounts and FIFOs) on its own
    FIFOs with a client on its socket; returns (CPU share, the lines it sent)."""
    fifos = [d / f"{name}-{m}.fifo" for m in MICE]
    for f in fifos:
        os.mkfifo(f)
    sock_path = d / f"{name}.sock"
    env = dict(os.environ, BENCH_END=str(time.monotonic() + seconds + 4.0))
    xy = json.dumps([[float(x), float(y)] for x, y in positions(len(MICE))])
    proc = _spawn([sys.executable, "-c", script, str(rate_hz), str(sock_path), xy,
                   *map(str, fifos)], env=env)  # fmt: skip
    while not sock_path.exists():
        time.sleep(0.01)
    client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    client.connect(str(sock_path))
    lines: list[bytes] = []
    th = threading.Thread(target=lambda: lines.extend(client.makefile("rb")), daemon=True)
    th.start()
    feed = start_feeder(fifos, seconds + 1.5, d / f"{name}-stamps.npz")
    cpu, _, _ = _measure(proc, seconds)
    feed.wait()
    proc.kill()
    proc.wait()
    client.close()
    return cpu, lines


def run_peer(d: Path, seconds: float, rate_hz: float) -> dict:
    """A peer-style daemon: a wake per report, numpy least squares per window."""
    cpu, lines = _run_script_reader(d, "peer", PEER, seconds, rate_hz)
    return {"cpu": cpu, "poses": len(lines)}


def run_minimum(d: Path, seconds: float, rate_hz: float) -> dict:
    """The least a Python fusion daemon of this design does (MINIMUM above)."""
    cpu, lines = _run_script_reader(d, "minimum", MINIMUM, seconds, rate_hz)
    if len(lines) < 2 or not json.loads(lines[-2])["used"]:  # the last may be cut
        raise SystemExit("the minimum reader sent no pose, or its fault test failed")
    return {"cpu": cpu, "poses": len(lines)}


def tracker_cost(d: Path, rate_hz: float, windows: int = 2000) -> float:
    """Seconds of CPU per window that the tracker alone takes for this load (in-process):
    a push of one window's reports per mouse, the silence-rule calls and the poll."""
    from mousedom.config import load_config
    from mousedom.fusion.tracker import Tracker

    config = load_config(write_config(d, [d / f"x{m}" for m in MICE], rate_hz))
    tracker = Tracker(config, t0=0.0)
    per = max(1, int(REPORT_HZ / rate_hz))
    t0 = time.process_time()
    for w in range(windows):
        start = w / rate_hz
        for i in range(len(MICE)):
            t = [start + (i + 0.5) / (len(MICE) * REPORT_HZ) + k / REPORT_HZ
                 for k in range(per) if (w * per + k) % SPARSE == 0]  # fmt: skip
            if t:
                tracker.push(i, t, [1] * len(t), [-3] * len(t))
            tracker.complete_until(start + 1 / rate_hz, mouse=i)
        tracker.poll()
    return (time.process_time() - t0) / windows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mice", type=int, default=4)
    ap.add_argument("--report-hz", type=float, default=1000.0)
    ap.add_argument("--seconds", type=float, default=8.0, help="measured seconds per run")
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--rounds", type=int, default=3, help="floor, peer, mousedom, in turn")
    ap.add_argument("--sparse", type=int, default=1, metavar="K",
                    help="each mouse reports every K-th period, as at a slow speed "
                         "(only with a count): K >= 2 makes windows cut long spans")  # fmt: skip
    ap.add_argument("--still", type=int, default=0, metavar="N",
                    help="the last N mice stop reporting after the warm-up (a mouse on "
                         "the axis of a turn in place): windows wait late_report_s for "
                         "them")  # fmt: skip
    ap.add_argument("--feed", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.feed:
        out, seconds, report_hz, sparse, still, *paths = args.feed
        feeder(paths, float(seconds), out, float(report_hz), int(sparse), int(still))
        return
    configure(args.mice, args.report_hz, args.sparse, args.still)
    # SIGTERM (a timeout's) as an exit, so that the children are ended below
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        measure(args)
    finally:
        for proc in _CHILDREN:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def measure(args: argparse.Namespace) -> None:
    """The rounds and their figures (main's, once it has parsed the arguments)."""
    ours, floors, peers, minima = [], [], [], []
    with tempfile.TemporaryDirectory(prefix="mousedom-bench-") as tmp:
        for r in range(args.rounds):
            d = Path(tmp) / f"round{r}"
            d.mkdir()
            floors.append(run_floor(d, args.seconds, args.rate_hz))
            peers.append(run_peer(d, args.seconds, args.rate_hz))
            minima.append(run_minimum(d, args.seconds, args.rate_hz))
            ours.append(run_daemon(d, args.seconds, args.rate_hz))
            print(f"round {r + 1}: floor {100 * floors[-1]['cpu']:.2f} %, peer "
                  f"{100 * peers[-1]['cpu']:.2f} %, minimum {100 * minima[-1]['cpu']:.2f} %, "
                  f"mousedom {100 * ours[-1]['cpu']:.2f} %, "
                  f"latency p99 {np.percentile(ours[-1]['lat_ms'], 99):.3f} ms",
                  flush=True)  # fmt: skip
        per_window = tracker_cost(Path(tmp), args.rate_hz)

    def med(runs):
        return 100 * float(np.median([r["cpu"] for r in runs]))

    to_floor = float(np.median([o["cpu"] / f["cpu"] for o, f in zip(ours, floors, strict=True)]))
    to_peer = float(np.median([o["cpu"] / p["cpu"] for o, p in zip(ours, peers, strict=True)]))
    min_floor = float(np.median([m["cpu"] / f["cpu"] for m, f in zip(minima, floors, strict=True)]))
    min_peer = float(np.median([m["cpu"] / p["cpu"] for m, p in zip(minima, peers, strict=True)]))
    lat = np.concatenate([r["lat_ms"] for r in ours])
    lat_final = np.concatenate([r["lat_final_ms"] for r in ours])
    every = f" (every {args.sparse} periods)" if args.sparse > 1 else ""
    every += f" ({args.still} of them still)" if args.still else ""
    print(f"{args.mice} mice x {args.report_hz:g} Hz{every} through FIFOs, POSE at "
          f"{args.rate_hz:g} Hz, {args.rounds} rounds x {args.seconds:g} s measured "
          "(medians)")  # fmt: skip
    print(f"floor (100 Hz batched reader)  {med(floors):6.2f} % of one core")
    print(f"peer-style daemon              {med(peers):6.2f} %")
    print(f"Python minimum (see MINIMUM)   {med(minima):6.2f} %   ratio to the floor "
          f"{min_floor:.2f}, to the peer {min_peer:.2f}")  # fmt: skip
    print(
        f"mousedom run                   {med(ours):6.2f} %   ratio to the floor "
        f"{to_floor:.2f} (target <= 1.5), to the peer {to_peer:.2f} (target <= 0.25)"
    )
    print(
        f"loop                           {np.median([r['wakes_hz'] for r in ours]):.0f} "
        f"wakes/s, {np.median([r['reads_hz'] for r in ours]):.0f} source reads/s"
    )
    print(
        f"latency beyond the window      p50 {np.median(lat):.3f} ms  p99 "
        f"{np.percentile(lat, 99):.3f} ms  over {len(lat)} poses (target p99 <= 1 ms)"
    )
    print(
        f"  beyond the window being final p50 {np.median(lat_final):.3f} ms  p99 "
        f"{np.percentile(lat_final, 99):.3f} ms  (the count function's rule, see _latencies)"
    )
    print(f"of which the tracker           {per_window * 1e6:.0f} us per window in-process")


if __name__ == "__main__":
    main()
