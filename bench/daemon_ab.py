"""Two daemon builds side by side: the same feeder, the same seconds, the same noise.

    /work/venv/bin/python bench/daemon_ab.py OTHER_CHECKOUT [--seconds 8] [--rounds 3]

``bench/daemon.py`` measures one build; on this shared machine its CPU figure moves by a
factor of two with the load of the moment, so a change is best judged against the build
before it *in the same run*.  Here both builds run at once, each on its own four FIFOs
(four mice at 1000 Hz, as in bench/daemon.py), fed by one feeder process, each with one
client reading its POSE lines; their CPU is read over the same interval.  A is this
checkout, B the other one (e.g. ``git worktree add /tmp/old HEAD~5``).
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))

from daemon import MICE, REPORT_HZ, cpu_seconds, write_config  # noqa: E402  (bench/daemon.py)


def start_build(root: Path, d: Path) -> tuple[subprocess.Popen, Path, list[Path]]:
    d.mkdir()
    fifos = [d / f"{m}.fifo" for m in MICE]
    for f in fifos:
        os.mkfifo(f)
    sock = d / "mousedom.sock"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "run", "--config", str(write_config(d, fifos, 100.0))]
        + ["--socket", str(sock)],
        env=dict(os.environ, PYTHONPATH=str(root)),
        cwd=root,
        stderr=subprocess.DEVNULL,
    )
    return proc, sock, fifos


def drain(path: Path) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(str(path))

    def read() -> None:
        for _ in s.makefile("rb"):
            pass

    threading.Thread(target=read, daemon=True).start()
    return s


def one_round(builds: dict[str, Path], seconds: float) -> dict[str, float]:
    with tempfile.TemporaryDirectory(prefix="mousedom-ab-") as tmp:
        d = Path(tmp)
        started = {k: start_build(root, d / k) for k, root in builds.items()}
        for proc, sock, _ in started.values():
            while not sock.exists():
                if proc.poll() is not None:
                    raise SystemExit("a daemon did not start")
                time.sleep(0.02)
        fifos = [f for _, _, fs in started.values() for f in fs]
        feed = subprocess.Popen(
            [sys.executable, str(ROOT / "bench" / "daemon.py"), "--feed", str(d / "stamps.npz")]
            + [str(seconds + 1.5), str(REPORT_HZ), *map(str, fifos)]
        )
        clients = [drain(sock) for _, sock, _ in started.values()]
        time.sleep(1.2)  # warm-up: windows begin to close
        cpu0 = {k: cpu_seconds(p.pid) for k, (p, _, _) in started.items()}
        wall0 = time.monotonic()
        time.sleep(seconds)
        cpu1 = {k: cpu_seconds(p.pid) for k, (p, _, _) in started.items()}
        wall = time.monotonic() - wall0
        feed.wait()
        for proc, _, _ in started.values():
            proc.send_signal(signal.SIGTERM)
            proc.wait(5)
        for c in clients:
            c.close()
        return {k: (cpu1[k] - cpu0[k]) / wall for k in builds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path, help="the other checkout (B)")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    # Either layout: before and after mousedom/service/ (a build to compare may be older).
    if not any((args.other / "mousedom" / p).exists() for p in ("daemon.py", "service/daemon.py")):
        raise SystemExit(f"{args.other}: not a mousedom checkout (no mousedom daemon)")
    builds = {"A": ROOT, "B": args.other.resolve()}
    runs = []
    for r in range(args.rounds):
        runs.append(one_round(builds, args.seconds))
        print(
            f"round {r + 1}: A {100 * runs[-1]['A']:.2f} %  B {100 * runs[-1]['B']:.2f} %",
            flush=True,
        )
    a = statistics.median(x["A"] for x in runs)
    b = statistics.median(x["B"] for x in runs)
    ratio = statistics.median(x["A"] / x["B"] for x in runs)
    print(f"A = {ROOT}\nB = {builds['B']}")
    print(f"daemon CPU, median of {args.rounds}: A {100 * a:.2f} %, B {100 * b:.2f} % of one core;"
          f" median ratio A/B {ratio:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
