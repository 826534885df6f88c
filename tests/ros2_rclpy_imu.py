"""A ROS 2 IMU driver's stand-in for tests/test_ros2_interop.py: rclpy on Fast DDS.

    python ros2_rclpy_imu.py SECONDS OUT.jsonl [TOPIC]

Once a subscription has matched (at most 20 s), publishes sensor_msgs/msg/Imu on TOPIC
(/imu/data) at 200 Hz for SECONDS with the QoS IMU drivers use (rclpy's
qos_profile_sensor_data: best effort, keep last 5), stamped with the node's clock (ROS
time), frame imu_link, a turn rate about z that changes every message;
writes each message's stamp and angular velocity as a JSON line to OUT.jsonl, then a last
line {"nodes": [[name, namespace], ...], "subscriptions": {node: [[topic, [types]]]}}
for the nodes it saw (mousedom's gyro among them).
"""

import json
import math
import sys
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu


def main() -> None:
    seconds, out_path = float(sys.argv[1]), sys.argv[2]
    topic = sys.argv[3] if len(sys.argv) > 3 else "/imu/data"
    rclpy.init()
    node = Node("imu_driver")
    pub = node.create_publisher(Imu, topic, qos_profile_sensor_data)
    # from when the daemon's reader is matched: what discovery takes (a second or so between
    # Fast DDS and Cyclone on a loaded machine) is not what the test is about
    deadline = time.monotonic() + 20
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    with open(out_path, "w") as out:
        print("ready", flush=True)
        i = 0
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            msg = Imu()
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.header.frame_id = "imu_link"
            msg.orientation.w = 1.0
            msg.angular_velocity.x = 0.001 * i
            msg.angular_velocity.z = 0.3 * math.sin(i / 40.0) + 1e-9 * i  # each one its own
            msg.linear_acceleration.z = 9.81
            pub.publish(msg)
            st = msg.header.stamp
            out.write(
                json.dumps({"sec": st.sec, "nanosec": st.nanosec, "z": msg.angular_velocity.z})
                + "\n"
            )
            i += 1
            time.sleep(0.005)
        nodes = node.get_node_names_and_namespaces()
        subs = {name: node.get_subscriber_names_and_types_by_node(name, ns)
                for name, ns in nodes if name != "imu_driver"}  # fmt: skip
        out.write(json.dumps({"nodes": nodes, "subscriptions": subs}) + "\n")
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
