"""Messages a real ROS 2 node receives from the daemon, per topic, in each discovery setting.

    .venv/bin/python bench/ros2_topics.py [--ros2-python .ros-venv/bin/python]

As tests/test_ros2_interop.py runs them (and with its code): the daemon on the demo rig
(50 Hz POSE, ``counts: true``) and an rclpy node on rmw_fastrtps_cpp for 8 s, both in a
network namespace with only loopback (root, ``unshare -n``; nothing leaves the machine),
with default discovery, ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and
``ROS_LOCALHOST_ONLY=1``.  Printed per setting: the POSE lines the socket gave in that
time, and what the node received on each topic.  The ROS 2 venv: bash scripts/ros2_venv.sh.
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

import test_ros2_interop as interop  # noqa: E402  (the test's set-up, reused as it is)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ros2-python", default=str(ROOT / ".ros-venv" / "bin" / "python"))
    args = ap.parse_args()
    interop.ROS_PY = args.ros2_python
    why = interop._why_not()
    if why:
        sys.exit(f"ros2_topics: {why}")
    for setting in ("default", "LOCALHOST", "ROS_LOCALHOST_ONLY"):
        with tempfile.TemporaryDirectory(prefix="mousedom-ros2-") as tmp:
            poses, lines, _ = interop._run_pair(args.ros2_python, Path(tmp), setting,
                                                ", counts: true")  # fmt: skip
        got = collections.Counter(x["topic"] for x in lines[:-1])
        topics = ", ".join(f"{t} {n}" for t, n in sorted(got.items()))
        print(f"{setting:18s} POSE on the socket {len(poses)}; received: {topics}", flush=True)


if __name__ == "__main__":
    main()
