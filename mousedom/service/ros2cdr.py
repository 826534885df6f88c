"""CDR (XCDR1, little endian) of the messages sent every window, packed with ``struct``.

The generic path (``ros2msgs.build`` then cyclonedds' serializer, or mcap_ros2's) walks the
message's fields in Python: about 120 us for an Odometry, most of a window's cost on a
small board.  These messages have a fixed layout once their frame ids are known, so each is
a constant prefix (the strings) and one ``struct.pack`` of its numbers.  tests/test_ros2.py
holds them byte for byte equal to the generic path, and rosbags reads them.

XCDR1: a 4-byte encapsulation header (0x0001: CDR little endian), then each primitive
aligned to its size from the start of the payload, strings as a uint32 length (with the
terminating NUL) and the bytes.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

ENCAPSULATION = b"\x00\x01\x00\x00"
_STAMP = struct.Struct("<iI")


def _pad(buf: bytearray, n: int) -> None:
    buf += b"\0" * (-len(buf) % n)


def _string(buf: bytearray, s: str) -> None:
    _pad(buf, 4)
    data = s.encode() + b"\0"
    buf += struct.pack("<I", len(data)) + data


class Stamped:
    """A message that starts with a std_msgs/Header and then has fixed strings and doubles:
    ``encode(sec, nanosec, numbers)`` (the payload offset of the header is ``start``)."""

    def __init__(self, frame_id: str, strings: Sequence[str], n_doubles: int, start: int = 0):
        buf = bytearray(start + 8)  # what precedes, then the stamp (filled per message)
        _string(buf, frame_id)
        for s in strings:
            _string(buf, s)
        _pad(buf, 8)
        self.start = start
        self.tail = bytes(buf[start + 8 :])
        self.numbers = struct.Struct("<" + "d" * n_doubles)
        self.size = len(buf) - start + self.numbers.size

    def encode(self, sec: int, nanosec: int, numbers: Sequence[float]) -> bytes:
        return _STAMP.pack(sec, nanosec) + self.tail + self.numbers.pack(*numbers)


class OdometryCdr:
    """nav_msgs/msg/Odometry: header, child_frame_id, pose (7 + 36), twist (6 + 36)."""

    def __init__(self, frame_id: str, child_frame_id: str) -> None:
        self.body = Stamped(frame_id, [child_frame_id], 7 + 36 + 6 + 36)

    def encode(self, stamp: dict[str, int], msg: dict) -> bytes:
        pose, twist = msg["pose"], msg["twist"]
        p, q = pose["pose"]["position"], pose["pose"]["orientation"]
        lin, ang = twist["twist"]["linear"], twist["twist"]["angular"]
        numbers = [p["x"], p["y"], p["z"], q["x"], q["y"], q["z"], q["w"], *pose["covariance"],
                   lin["x"], lin["y"], lin["z"], ang["x"], ang["y"], ang["z"],
                   *twist["covariance"]]  # fmt: skip
        return ENCAPSULATION + self.body.encode(stamp["sec"], stamp["nanosec"], numbers)


class TfCdr:
    """tf2_msgs/msg/TFMessage of a fixed list of (parent, child) transforms."""

    def __init__(self, pairs: Sequence[tuple[str, str]]) -> None:
        self.parts = []
        offset = 4  # the sequence's length
        for parent, child in pairs:
            offset += -offset % 4
            part = Stamped(parent, [child], 7, start=offset)
            self.parts.append(part)
            offset += part.size

    def encode(self, stamp: dict[str, int], transforms: Sequence[dict]) -> bytes:
        out = [ENCAPSULATION, struct.pack("<I", len(self.parts))]
        pos = 4
        for part, tf in zip(self.parts, transforms, strict=True):
            if pos % 4:
                out.append(b"\0" * (-pos % 4))
                pos += -pos % 4
            t, r = tf["transform"]["translation"], tf["transform"]["rotation"]
            data = part.encode(
                stamp["sec"],
                stamp["nanosec"],
                (t["x"], t["y"], t["z"], r["x"], r["y"], r["z"], r["w"]),
            )
            out.append(data)
            pos += len(data)
        return b"".join(out)


class Vector3StampedCdr:
    def __init__(self, frame_id: str) -> None:
        self.body = Stamped(frame_id, [], 3)

    def encode(self, stamp: dict[str, int], msg: dict) -> bytes:
        v = msg["vector"]
        return ENCAPSULATION + self.body.encode(stamp["sec"], stamp["nanosec"],
                                                (v["x"], v["y"], v["z"]))  # fmt: skip


def diagnostics(stamp: dict[str, int], msg: dict) -> bytes:
    """diagnostic_msgs/msg/DiagnosticArray (once a second: built field by field)."""
    buf = bytearray()
    buf += _STAMP.pack(stamp["sec"], stamp["nanosec"])
    _string(buf, msg["header"]["frame_id"])
    _pad(buf, 4)
    buf += struct.pack("<I", len(msg["status"]))
    for st in msg["status"]:
        buf += struct.pack("<B", st["level"])  # an octet: no alignment
        for key in ("name", "message", "hardware_id"):
            _string(buf, st[key])
        _pad(buf, 4)
        buf += struct.pack("<I", len(st["values"]))
        for kv in st["values"]:
            _string(buf, kv["key"])
            _string(buf, kv["value"])
    return ENCAPSULATION + bytes(buf)
