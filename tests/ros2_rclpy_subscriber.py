"""A real ROS 2 node for tests/test_ros2_interop.py: rclpy on ROS 2's default middleware.

    python ros2_rclpy_subscriber.py SECONDS OUT.jsonl TOPIC=pkg/msg/Type [...]

Runs in its own venv (the ROS 2 wheels from PyPI: ros-rclpy, ros-nav-msgs, ...), under
rmw_fastrtps_cpp unless RMW_IMPLEMENTATION says otherwise.  Subscribes with rclcpp's
default QoS (reliable, volatile, keep last 10) and writes every message received as one
JSON line {"topic", "t_recv", "msg"} to OUT.jsonl for SECONDS; then the node names it saw
and each one's publishers as a last line {"nodes": [[name, namespace], ...],
"publishers": {"/ns/name": [[topic, [types]], ...]}}.
"""

import importlib
import json
import math
import os
import sys
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def plain(m):
    if hasattr(m, "get_fields_and_field_types"):
        return {k: plain(getattr(m, k)) for k in m.get_fields_and_field_types()}
    if isinstance(m, (list, tuple)) or type(m).__name__ in ("ndarray", "array"):
        return [plain(v) for v in m]
    if isinstance(m, bytes):  # a ROS byte (DiagnosticStatus.level): its value
        return m[0] if len(m) == 1 else list(m)
    return m


def main() -> None:
    seconds, out_path, specs = float(sys.argv[1]), sys.argv[2], sys.argv[3:]
    rclpy.init()
    node = Node("mousedom_interop_test")
    out = open(out_path, "w")  # noqa: SIM115 - closed below
    for spec in specs:
        topic, typ = spec.split("=")
        pkg, _, name = typ.split("/")
        cls = getattr(importlib.import_module(f"{pkg}.msg"), name)
        qos = QoSProfile(
            depth=100 if topic.endswith("/tf") else 10,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.VOLATILE,
            history=HistoryPolicy.KEEP_LAST,
        )

        def callback(msg, topic=topic):
            line = {"topic": topic, "t_recv": time.monotonic(), "msg": plain(msg)}
            out.write(json.dumps(line) + "\n")

        node.create_subscription(cls, topic, callback, qos)
    # RViz's "2D Pose Estimate", when asked: $INITIALPOSE = "x,y,yaw,after_s"
    fix = os.environ.get("INITIALPOSE")
    pub = None
    if fix:
        from geometry_msgs.msg import PoseWithCovarianceStamped

        fx, fy, fyaw, after = (float(v) for v in fix.split(","))
        pub = node.create_publisher(PoseWithCovarianceStamped, "/initialpose", 10)
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = "map"
        msg.pose.pose.position.x, msg.pose.pose.position.y = fx, fy
        msg.pose.pose.orientation.z = math.sin(fyaw / 2)
        msg.pose.pose.orientation.w = math.cos(fyaw / 2)
        sent_at = time.monotonic() + after
    print("ready", flush=True)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
        if pub is not None and time.monotonic() >= sent_at:
            pub.publish(msg)
            out.write(json.dumps({"topic": "/initialpose", "t_sent": time.monotonic()}) + "\n")
            pub = None
    graph = {"nodes": node.get_node_names_and_namespaces()}
    graph["publishers"] = {
        f"{ns.rstrip('/')}/{name}": node.get_publisher_names_and_types_by_node(name, ns)
        for name, ns in graph["nodes"]
    }
    out.write(json.dumps(graph) + "\n")
    out.close()
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
