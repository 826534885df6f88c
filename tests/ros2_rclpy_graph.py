"""A real ROS 2 node for tests/test_ros2_interop.py that watches the graph.

    python ros2_rclpy_graph.py SECONDS OUT.jsonl

Runs in the ROS 2 venv (rclpy on rmw_fastrtps_cpp unless RMW_IMPLEMENTATION says
otherwise) and writes, every 0.1 s for SECONDS, one JSON line {"t": time.time(), "nodes":
[[name, namespace], ...]} of the other nodes `ros2 node list` would show.
"""

import json
import sys
import time

import rclpy
from rclpy.node import Node


def main() -> None:
    seconds, out = float(sys.argv[1]), sys.argv[2]
    rclpy.init()
    node = Node("mousedom_graph_watch")
    end = time.monotonic() + seconds
    with open(out, "w") as f:
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
            nodes = [
                list(n)
                for n in node.get_node_names_and_namespaces()
                if n[0] != "mousedom_graph_watch"
            ]
            f.write(json.dumps({"t": time.time(), "nodes": nodes}) + "\n")
            f.flush()
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
