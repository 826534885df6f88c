"""A ROS 2 subscriber in its own process, for tests/test_ros2.py: not our types, ROS 2's.

    python tests/ros2_subscriber.py DISTRO DOMAIN TOPIC=TYPE [TOPIC=TYPE ...]

The message classes are made here from the ROS 2 message definitions rosbags ships for
DISTRO (humble, jazzy), named as rmw_cyclonedds names them on the wire
(``nav_msgs::msg::dds_::Odometry_`` on ``rt/odom``), and subscribed with rclcpp's default
QoS.  Every sample received is printed as one JSON line {"topic": ..., "msg": {...}} until
stdin closes; "ready" is printed once the readers exist.
"""

from __future__ import annotations

import dataclasses
import json
import select
import sys
import types as pytypes

from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from rosbags.typesys import Stores, get_typestore

STORES = {"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY}
PRIMITIVES = {
    "float64": t.float64, "float32": t.float32, "int8": t.int8, "uint8": t.uint8,
    "int16": t.int16, "uint16": t.uint16, "int32": t.int32, "uint32": t.uint32,
    "int64": t.int64, "uint64": t.uint64, "byte": t.byte, "octet": t.byte, "char": t.uint8,
    "bool": bool, "string": str,
}  # fmt: skip


def classes_for(store) -> dict:
    made: dict[str, type] = {}

    def field_type(node):
        kind, detail = node
        if kind == 1:  # BASE
            return PRIMITIVES[detail[0]]
        if kind == 2:  # NAME
            return make(detail)
        inner, size = detail
        if kind == 3:  # ARRAY
            return t.array[field_type(inner), size]
        return t.sequence[field_type(inner)]  # SEQUENCE

    def make(name: str) -> type:
        if name not in made:
            _, fields = store.fielddefs[name]
            ann = {fname: field_type(node) for fname, node in fields}
            pkg, _, short = name.split("/")
            cls = pytypes.new_class(
                short + "_", (IdlStruct,), {"typename": f"{pkg}::msg::dds_::{short}_"},
                lambda ns: ns.update({"__annotations__": ann}),
            )  # fmt: skip
            made[name] = dataclasses.dataclass(cls)
        return made[name]

    return {"make": make}


def plain(obj):
    if dataclasses.is_dataclass(obj):
        return {f.name: plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, bytes):
        return list(obj)
    return obj


def main() -> None:
    distro, domain = sys.argv[1], int(sys.argv[2])
    make = classes_for(get_typestore(STORES[distro]))["make"]
    dp = DomainParticipant(domain)
    readers = []
    for arg in sys.argv[3:]:
        topic, typename = arg.split("=")
        depth = 100 if topic.endswith("/tf") else 10
        # /tf_static as tf2's static listener: transient local, the samples sent before
        durability = (Policy.Durability.TransientLocal if topic.endswith("/tf_static")
                      else Policy.Durability.Volatile)  # fmt: skip
        qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)),
                  durability, Policy.History.KeepLast(depth))  # fmt: skip
        readers.append((topic, DataReader(dp, Topic(dp, "rt" + topic, make(typename), qos=qos),
                                          qos)))  # fmt: skip
    print("ready", flush=True)
    while True:
        ready, _, _ = select.select([sys.stdin], [], [], 0.01)
        if ready and not sys.stdin.readline():
            return
        for topic, reader in readers:
            for sample in reader.take(N=100):
                print(json.dumps({"topic": topic, "msg": plain(sample)}), flush=True)


if __name__ == "__main__":
    main()
