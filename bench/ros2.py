"""The ROS 2 output's cost and latency: the daemon with and without DDS, same load.

    .venv/bin/python bench/ros2.py [--seconds 8] [--rounds 3] [--rate-hz 100]
                                   [--subscriber rclpy|cyclone]

Four mice at 1000 Hz through FIFOs (bench/daemon.py's feeder and rig), POSE at 100 Hz.
Rounds alternate the daemon without an output and with ``outputs: {ros2: ...}`` (Odometry
and TF every window, diagnostics once a second), on a throw-away domain over loopback, with
a subscriber in its own process.  Printed: the daemon's CPU (% of one core) for each, their
medians and the median of the per-round ratio; for the DDS run, the latency from the stamp
of the report that let a window close (c(T), as bench/daemon.py) to the subscriber's
receipt of that window's Odometry, and from the window's end T itself, p50 and p99.

The subscriber is a real ROS 2 node by default: rclpy on rmw_fastrtps_cpp from the venv
``bash scripts/ros2_venv.sh`` makes (``--ros2-python``), both sides limited to this host
with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``; ``--subscriber cyclone`` takes a Cyclone
DDS reader in this project's venv instead, over loopback.
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT))

from daemon import run_daemon  # noqa: E402  (bench/daemon.py)

LOOPBACK = (
    '<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery>"
    '<ParticipantIndex>auto</ParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>'
    "</Discovery></Domain></CycloneDDS>"
)

SUBSCRIBER = r"""
import sys, time, select
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.qos import Qos, Policy
from cyclonedds.util import duration
from mousedom.service import ros2msgs
dp = DomainParticipant(int(sys.argv[1]))
qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.Volatile,
          Policy.History.KeepLast(10))
r = DataReader(dp, Topic(dp, "rt/odom", ros2msgs.idl_types()["nav_msgs/Odometry"], qos=qos), qos)
out = open(sys.argv[2], "w")
print("ready", flush=True)
from cyclonedds.core import WaitSet, ReadCondition, SampleState, ViewState, InstanceState
ws = WaitSet(dp)
ws.attach(ReadCondition(r, SampleState.Any | ViewState.Any | InstanceState.Any))
while True:
    ws.wait(duration(milliseconds=50))
    for m in r.take(N=64):
        now = time.monotonic()
        if not hasattr(m, "header"):  # the writer's disposal at the end
            continue
        s = m.header.stamp
        out.write(f"{s.sec + s.nanosec * 1e-9:.9f} {now:.9f}\n")
    if select.select([sys.stdin], [], [], 0)[0] and not sys.stdin.readline():
        break
out.close()
"""


def rclpy_subscriber(ros_py: str, domain: int, log: Path, seconds: float, env: dict):
    """tests/ros2_rclpy_subscriber.py for /odom; its JSON lines become (stamp, arrival)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_ros2_interop import _tf2_env

    cmd = ["env", f"ROS_DOMAIN_ID={domain}", "RMW_IMPLEMENTATION=rmw_fastrtps_cpp",
           *_tf2_env(ros_py).split(), ros_py, str(ROOT / "tests" / "ros2_rclpy_subscriber.py"),
           str(seconds), str(log) + ".jsonl", "/odom=nav_msgs/msg/Odometry"]  # fmt: skip
    return subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env=env)  # fmt: skip


def rclpy_received(log: Path) -> np.ndarray:
    import json

    rows = []
    for line in Path(str(log) + ".jsonl").read_text().splitlines():
        m = json.loads(line)
        if m.get("topic") == "/odom":
            st = m["msg"]["header"]["stamp"]
            rows.append((st["sec"] + st["nanosec"] * 1e-9, m["t_recv"]))
    return np.array(rows).reshape(-1, 2)


def latencies(run: dict, received: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(from c(T), from T) in ms for the Odometry received in the measured interval."""
    wall0, wall1 = run["window"]
    beyond, total = [], []
    for t_pose, arrival in received:
        if not wall0 <= arrival <= wall1:
            continue
        firsts = []
        for s in run["stamps"]:
            j = np.searchsorted(s, t_pose, side="right")
            if j >= len(s):
                break
            firsts.append(s[j])
        else:
            beyond.append(arrival - max(firsts))
            total.append(arrival - t_pose)
    return np.array(beyond) * 1e3, np.array(total) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--subscriber", choices=("rclpy", "cyclone"), default="rclpy")
    ap.add_argument("--ros2-python", default=str(ROOT / ".ros-venv" / "bin" / "python"),
                    help="the ROS 2 venv's python (bash scripts/ros2_venv.sh)")  # fmt: skip
    args = ap.parse_args()
    rclpy = args.subscriber == "rclpy"
    if rclpy:
        if not os.path.exists(args.ros2_python):
            ap.error(f"{args.ros2_python}: no ROS 2 venv (bash scripts/ros2_venv.sh), "
                     "or --subscriber cyclone")  # fmt: skip
        os.environ.pop("CYCLONEDDS_URI", None)
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # nothing leaves the host
    else:
        os.environ["CYCLONEDDS_URI"] = LOOPBACK
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    plain, dds, beyond, total = [], [], [], []
    for k in range(args.rounds):
        with tempfile.TemporaryDirectory() as tmp:
            plain.append(run_daemon(Path(tmp), args.seconds, args.rate_hz))
        with tempfile.TemporaryDirectory() as tmp:
            d = Path(tmp)
            domain = random.randrange(100, 230)
            extra = f"outputs:\n  ros2: {{domain_id: {domain}, stamps: monotonic}}\n"
            log = d / "received.txt"
            holder = {}

            def start_sub(domain=domain, log=log, holder=holder) -> None:
                if rclpy:
                    sub = rclpy_subscriber(args.ros2_python, domain, log, args.seconds + 6, env)
                else:
                    sub = subprocess.Popen(
                        [sys.executable, "-c", SUBSCRIBER, str(domain), str(log)],
                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
                    )  # fmt: skip
                assert sub.stdout.readline().strip() == "ready"
                holder["sub"] = sub
                time.sleep(1.0)  # discovery

            run = run_daemon(d, args.seconds, args.rate_hz, extra, on_ready=start_sub)
            sub = holder["sub"]
            sub.stdin.close()
            sub.wait(args.seconds + 20)
            received = rclpy_received(log) if rclpy else np.loadtxt(log).reshape(-1, 2)
            b, t = latencies(run, received)
            beyond.append(b)
            total.append(t)
            dds.append(run)
        print(f"round {k + 1}: CPU {plain[-1]['cpu'] * 100:.2f} % without, "
              f"{dds[-1]['cpu'] * 100:.2f} % with DDS; {len(received)} Odometry received",
              flush=True)  # fmt: skip
    cp = float(np.median([r["cpu"] for r in plain])) * 100
    cd = float(np.median([r["cpu"] for r in dds])) * 100
    ratio = float(np.median([b["cpu"] / a["cpu"] for a, b in zip(plain, dds, strict=True)]))
    b = np.concatenate(beyond)
    t = np.concatenate(total)
    who = "rclpy on rmw_fastrtps_cpp" if rclpy else "a Cyclone DDS reader"
    print(f"four mice at 1000 Hz, POSE at {args.rate_hz:g} Hz, {args.rounds} rounds of "
          f"{args.seconds:g} s (medians); subscriber: {who}")  # fmt: skip
    print(f"daemon CPU without DDS     {cp:.2f} % of one core")
    print(f"daemon CPU with DDS        {cd:.2f} % (ratio {ratio:.2f}, per round)")
    print(
        f"Odometry latency from c(T) p50 {np.percentile(b, 50):.2f} ms, "
        f"p99 {np.percentile(b, 99):.2f} ms ({len(b)} windows)"
    )
    print(
        f"Odometry latency from T    p50 {np.percentile(t, 50):.2f} ms, "
        f"p99 {np.percentile(t, 99):.2f} ms"
    )


if __name__ == "__main__":
    main()
