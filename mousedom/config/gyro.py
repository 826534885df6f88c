"""The ``gyro:`` section: which IIO gyro, how it is mounted, and what the heading uses.

    gyro:
      name: mpu6050        # or path: /sys/bus/iio/devices/iio:device0
      axis: z              # the sensor axis along body z (up)
      sign: 1              # -1: that axis points down (mounted upside down)
      sample_hz: 200       # optional: written to sampling_frequency
      noise: 8.7e-5        # optional: rad/s/sqrt(Hz)
      use: both            # both | gyro | mice
      replay: run.mdcap    # instead of name or path: a capture's gyro, paced in real time
      ros2: /imu/data      # instead: an IMU's sensor_msgs/Imu topic over DDS, or
                           # {topic: /imu/data, domain_id: 0, stamps: system}

The defaults are those of ``GyroConfig``'s fields; docs/gyro.md says what each means.
"""

from __future__ import annotations

import os
from pathlib import Path

from mousedom.config.mice import read_replay
from mousedom.config.outputs import ROS_TOPIC, ROS_TOPIC_MAX
from mousedom.config.rig import GyroConfig, GyroRos2, default
from mousedom.fusion.choices import GYRO_USES
from mousedom.yamldoc import Reader

GYRO_KEYS = ("name", "path", "axis", "sign", "sample_hz", "noise", "use", "replay", "ros2")
AXES = ("x", "y", "z")
SOURCES = ("name", "path", "replay", "ros2")  # a gyro has one
IMU_STAMPS = ("system", "monotonic")


def read_ros2(g: Reader) -> GyroRos2:
    """``ros2:``: a topic, or ``{topic, domain_id, stamps}``."""
    v = g.raw("ros2")
    if isinstance(v, dict):
        s = g.sub("ros2", ("topic", "domain_id", "stamps"))
        topic = s.string("topic")
        domain = s.integer("domain_id", minimum=0) if s.has("domain_id") else None
        if domain is not None and domain > 232:
            raise s.err("domain_id", f"must be between 0 and 232 (ROS 2's range), got {domain}")
        stamps = s.choice("stamps", IMU_STAMPS, "system")
        where = s
        key = "topic"
    else:
        topic, domain, stamps, where, key = g.string("ros2"), None, "system", g, "ros2"
    # an absolute topic name: /imu or /robot1/imu/data (ROS 2's name rules)
    if (not topic or not topic.startswith("/") or not ROS_TOPIC.fullmatch(topic)
            or len(topic) > ROS_TOPIC_MAX):  # fmt: skip
        raise where.err(key, "must be an absolute ROS 2 topic name of a sensor_msgs/Imu "
                             f"(e.g. /imu/data), got {topic!r}")  # fmt: skip
    return GyroRos2(topic=topic, domain_id=domain, stamps=stamps)


def read_gyro(r: Reader, *, need_sources: bool = True, base_dir: Path = Path(".")) -> GyroConfig:
    """The top level's ``gyro:`` mapping; ConfigError naming file, line and key.

    ``need_sources=False`` (replay, calibration) lets it leave out name and path, as the
    mice may leave out where they come from.  ``replay:`` (a capture's gyro, resolved
    against ``base_dir`` as the mice's are) stands instead of name and path: the capture
    holds the rates with the recorded mount's axis and sign applied already."""
    g = r.sub("gyro", GYRO_KEYS)
    name = g.string("name")
    path = g.string("path")
    if path is not None and not os.path.isabs(path):
        raise g.err("path", f"must be an absolute path (/sys/bus/iio/devices/iio:deviceN or "
                            f"/dev/iio:deviceN), got {path!r}")  # fmt: skip
    if name == "":
        raise g.err("name", "must not be empty (the IIO device's name attribute, e.g. mpu6050)")
    axis = g.choice("axis", AXES, default(GyroConfig, "axis", str))
    sign = g.integer("sign", default(GyroConfig, "sign", int))
    if sign not in (1, -1):
        raise g.err("sign", f"must be 1 or -1 (-1: the axis points down), got {sign}")
    sample_hz = g.number("sample_hz", within=(0.1, 100000.0)) if g.has("sample_hz") else None
    noise = g.number("noise", default(GyroConfig, "noise", float), positive=True,
                     within=(0.0, 1.0))  # fmt: skip
    use = g.choice("use", GYRO_USES, default(GyroConfig, "use", str))
    given = [k for k in SOURCES if g.has(k)]
    if not set(given) <= {"name", "path"} and len(given) > 1:  # (name and path: one device)
        raise g.err(given[-1], f"a gyro has one source: {given[0]} is given already")
    ros2 = read_ros2(g) if g.has("ros2") else None
    replay, replay_device = None, None
    if g.has("replay"):
        mounted = [k for k in ("axis", "sign", "sample_hz") if g.has(k)]
        if mounted:
            raise g.err(mounted[0], "does not apply to a replayed gyro: the capture holds its "
                                    "rates with the mount's axis and sign applied")  # fmt: skip
        file, replay_device = read_replay(g, base_dir)
        replay = str(base_dir / file)
    # "needs name" is noise next to "nmae: unknown key (did you mean name?)"
    if (need_sources and name is None and path is None and replay is None and ros2 is None
            and not {"name", "path"} & g.suggested):  # fmt: skip
        raise r.err("gyro", "needs name (the IIO device's name, e.g. mpu6050), path "
                            "(/sys/bus/iio/devices/iio:deviceN), replay (a capture) or ros2 "
                            "(a sensor_msgs/Imu topic)")  # fmt: skip
    return GyroConfig(
        name=name, path=path, axis=axis, sign=sign, sample_hz=sample_hz, noise=noise, use=use,
        replay=replay, replay_device=replay_device, ros2=ros2,
    )  # fmt: skip
