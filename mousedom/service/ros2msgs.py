"""The ROS 2 message types mousedom publishes: their fields once, as data, from which both
the MCAP schemas (``ros2msg`` text) and the DDS types (cyclonedds ``IdlStruct`` classes
with ROS 2's DDS names, ``nav_msgs::msg::dds_::Odometry_``) are made.

The field lists are those of ROS 2's interface packages (Humble and Jazzy agree on all of
these); tests/test_ros2.py checks them against the definitions rosbags ships for both.
ROS 2's ``byte`` is IDL's ``octet``.
"""

from __future__ import annotations

import dataclasses
import functools
import types as pytypes
from typing import Any

# type -> ((field type, field name), ...); a field type is a primitive, "T[]" (a sequence),
# "T[N]" (a fixed array) or another message type.
FIELDS: dict[str, tuple[tuple[str, str], ...]] = {
    "builtin_interfaces/Time": (("int32", "sec"), ("uint32", "nanosec")),
    "std_msgs/Header": (("builtin_interfaces/Time", "stamp"), ("string", "frame_id")),
    "geometry_msgs/Point": (("float64", "x"), ("float64", "y"), ("float64", "z")),
    "geometry_msgs/Quaternion": (
        ("float64", "x"), ("float64", "y"), ("float64", "z"), ("float64", "w"),
    ),
    "geometry_msgs/Vector3": (("float64", "x"), ("float64", "y"), ("float64", "z")),
    "geometry_msgs/Pose": (
        ("geometry_msgs/Point", "position"), ("geometry_msgs/Quaternion", "orientation"),
    ),
    "geometry_msgs/PoseWithCovariance": (
        ("geometry_msgs/Pose", "pose"), ("float64[36]", "covariance"),
    ),
    "geometry_msgs/Twist": (
        ("geometry_msgs/Vector3", "linear"), ("geometry_msgs/Vector3", "angular"),
    ),
    "geometry_msgs/TwistWithCovariance": (
        ("geometry_msgs/Twist", "twist"), ("float64[36]", "covariance"),
    ),
    "nav_msgs/Odometry": (
        ("std_msgs/Header", "header"), ("string", "child_frame_id"),
        ("geometry_msgs/PoseWithCovariance", "pose"),
        ("geometry_msgs/TwistWithCovariance", "twist"),
    ),
    "geometry_msgs/Transform": (
        ("geometry_msgs/Vector3", "translation"), ("geometry_msgs/Quaternion", "rotation"),
    ),
    "geometry_msgs/TransformStamped": (
        ("std_msgs/Header", "header"), ("string", "child_frame_id"),
        ("geometry_msgs/Transform", "transform"),
    ),
    "tf2_msgs/TFMessage": (("geometry_msgs/TransformStamped[]", "transforms"),),
    "diagnostic_msgs/KeyValue": (("string", "key"), ("string", "value")),
    "diagnostic_msgs/DiagnosticStatus": (
        ("byte", "level"), ("string", "name"), ("string", "message"),
        ("string", "hardware_id"), ("diagnostic_msgs/KeyValue[]", "values"),
    ),
    "diagnostic_msgs/DiagnosticArray": (
        ("std_msgs/Header", "header"), ("diagnostic_msgs/DiagnosticStatus[]", "status"),
    ),
    "geometry_msgs/PoseWithCovarianceStamped": (
        ("std_msgs/Header", "header"), ("geometry_msgs/PoseWithCovariance", "pose"),
    ),
    "geometry_msgs/Vector3Stamped": (
        ("std_msgs/Header", "header"), ("geometry_msgs/Vector3", "vector"),
    ),
    "sensor_msgs/Imu": (
        ("std_msgs/Header", "header"), ("geometry_msgs/Quaternion", "orientation"),
        ("float64[9]", "orientation_covariance"), ("geometry_msgs/Vector3", "angular_velocity"),
        ("float64[9]", "angular_velocity_covariance"),
        ("geometry_msgs/Vector3", "linear_acceleration"),
        ("float64[9]", "linear_acceleration_covariance"),
    ),
}  # fmt: skip

# type -> ((constant type, name, value), ...): the constants of a type's definition, which
# the ros2msg schema text carries (a viewer names a level by them) and the wire does not.
CONSTANTS: dict[str, tuple[tuple[str, str, int], ...]] = {
    "diagnostic_msgs/DiagnosticStatus": (
        ("byte", "OK", 0), ("byte", "WARN", 1), ("byte", "ERROR", 2), ("byte", "STALE", 3),
    ),
}  # fmt: skip

# REP-2011 type hashes of the published types (the same in Humble and Jazzy; tests check
# them against rosbags' computation from ROS 2's definitions).  ROS 2 since Iron announces
# its own in each endpoint's USER_DATA as "typehash=RIHS01_...;" (rmw_dds_common), shown
# by `ros2 topic info -v`; an endpoint without one still matches.
TYPE_HASHES = {
    "nav_msgs/Odometry": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "tf2_msgs/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "diagnostic_msgs/DiagnosticArray":
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
    "geometry_msgs/Vector3Stamped":
        "RIHS01_d4829622288cbb443886e7ea94ea5671a3b1be6bab4ad04224432a65f7d7887a",
}  # fmt: skip

ODOMETRY = "nav_msgs/Odometry"
TF = "tf2_msgs/TFMessage"
DIAGNOSTICS = "diagnostic_msgs/DiagnosticArray"
COUNTS = "geometry_msgs/Vector3Stamped"
INITIALPOSE = "geometry_msgs/PoseWithCovarianceStamped"  # read, not published
IMU = "sensor_msgs/Imu"  # read (gyro: ros2:), not published


def _base(ftype: str) -> str:
    return ftype.split("[", 1)[0]


def dependencies(name: str) -> list[str]:
    """Every message type ``name`` uses, depth first, each once, ``name`` excluded."""
    out: list[str] = []

    def walk(t: str) -> None:
        for ftype, _ in FIELDS[t]:
            b = _base(ftype)
            if b in FIELDS and b not in out:
                walk(b)
                out.append(b)

    walk(name)
    return out


def msgdef(name: str) -> str:
    """The ``ros2msg`` schema text of an MCAP channel: the type's constants and fields, then
    each type it uses after a line of '=' and ``MSG: pkg/Type`` (the rosbag2 and Foxglove
    layout)."""

    def body(t: str) -> str:
        consts = "".join(f"{c} {n}={v}\n" for c, n, v in CONSTANTS.get(t, ()))
        return consts + "".join(f"{ftype} {fname}\n" for ftype, fname in FIELDS[t])

    parts = [body(name)]
    for dep in dependencies(name):
        parts.append("=" * 80 + f"\nMSG: {dep}\n" + body(dep))
    return "".join(parts)


def ros2_name(name: str) -> str:
    """nav_msgs/Odometry -> nav_msgs/msg/Odometry (as rosbag2 and ros2 topic name it)."""
    pkg, t = name.split("/")
    return f"{pkg}/msg/{t}"


def dds_name(name: str) -> str:
    """nav_msgs/Odometry -> nav_msgs::msg::dds_::Odometry_ (the name on the DDS wire)."""
    pkg, t = name.split("/")
    return f"{pkg}::msg::dds_::{t}_"


@functools.lru_cache(maxsize=1)
def idl_types() -> dict[str, type]:
    """The cyclonedds classes of every type in FIELDS (imports cyclonedds: the ros2 extra)."""
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl import types as t

    prim: dict[str, Any] = {
        "float64": t.float64, "float32": t.float32, "int32": t.int32, "uint32": t.uint32,
        "int64": t.int64, "uint64": t.uint64, "int16": t.int16, "uint16": t.uint16,
        "int8": t.int8, "uint8": t.uint8, "byte": t.byte, "bool": bool, "string": str,
    }  # fmt: skip
    classes: dict[str, type] = {}

    def resolve(ftype: str) -> Any:
        b = _base(ftype)
        inner = prim[b] if b in prim else make(b)
        if ftype.endswith("[]"):
            return t.sequence[inner]
        if "[" in ftype:
            return t.array[inner, int(ftype[ftype.index("[") + 1 : -1])]
        return inner

    def make(name: str) -> type:
        if name in classes:
            return classes[name]
        annotations = {fname: resolve(ftype) for ftype, fname in FIELDS[name]}

        def body(ns: dict[str, Any]) -> None:
            ns["__annotations__"] = annotations
            ns["__module__"] = __name__

        # types.new_class, not type(): the metaclass must see the typename keyword
        cls = pytypes.new_class(
            name.split("/")[1] + "_", (IdlStruct,), {"typename": dds_name(name)}, body
        )
        classes[name] = dataclasses.dataclass(cls)
        return classes[name]

    for name in FIELDS:
        make(name)
    return classes


def build(name: str, value: dict[str, Any]) -> Any:
    """A cyclonedds object of type ``name`` from nested dicts (ros2conv's messages)."""
    cls = idl_types()[name]
    kwargs = {}
    for ftype, fname in FIELDS[name]:
        v = value[fname]
        b = _base(ftype)
        if b in FIELDS:
            v = [build(b, x) for x in v] if "[" in ftype else build(b, v)
        kwargs[fname] = v
    return cls(**kwargs)
