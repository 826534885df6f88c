"""Helpers (no tests here): an IIO gyro described as a directory tree, and its records.

The tree has the layout the kernel publishes (Documentation/ABI/testing/sysfs-bus-iio),
here for an MPU-6050 as the inv_mpu6050 driver presents it: ``sys/bus/iio/devices/
iio:deviceN/{name, dev, in_anglvel_scale, in_anglvel_{x,y,z}_raw, sampling_frequency,
current_timestamp_clock, scan_elements/*_{en,index,type}, buffer/{enable,length},
trigger/current_trigger}``, scan indices accel 0-2, gyro 4-6 (3 is the temperature, not
buffered: indices need not be contiguous), timestamp 7; and ``dev/iio:deviceN``, a FIFO
standing for the character device.

``pack_records`` packs records as the kernel documents them, written here independently of
``mousedom.sources.iio_layout`` (one value at a time with ``struct``): channels in scan-index
order, each at a multiple of its storage bytes, the record padded to the largest.  Bits
outside a value's field may be filled with ones (``junk``): a reader must mask them off.
"""

from __future__ import annotations

import os
import re
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

MPU6050_SCALE = "0.001064724"  # rad/s per LSB at +-2000 deg/s, as the driver prints it
GYRO_TYPE = "be:s16/16>>0"  # the MPU-6050's registers are big-endian
TIMESTAMP_TYPE = "le:s64/64>>0"
INDEX = {"in_accel_x": 0, "in_accel_y": 1, "in_accel_z": 2, "in_anglvel_x": 4,
         "in_anglvel_y": 5, "in_anglvel_z": 6, "in_timestamp": 7}  # fmt: skip
_TYPE = re.compile(r"(be|le):([su])(\d+)/(\d+)(?:X(\d+))?(?:>>(\d+))?")


def add_gyro(
    root: Path,
    n: int = 0,
    name: str = "mpu6050",
    *,
    scale: str | None = MPU6050_SCALE,
    axis_scale: dict[str, str] | None = None,
    offset: str | None = None,
    axis_offset: dict[str, str] | None = None,
    types: dict[str, str] | None = None,
    clock: str | None = "realtime",
    trigger: str | None = "mpu6050-dev0",
    buffered: bool = True,
    node: bool = True,
    raw: dict[str, str] | None = None,
) -> Path:
    """An IIO gyro at ``root``; returns its sysfs directory.  ``types`` overrides channels'
    ``_type``; ``clock=None`` leaves out current_timestamp_clock (kernels before 4.5),
    ``trigger=""`` is a device with no trigger set, ``buffered=False`` one without a
    buffer, ``node=False`` one without its character device."""
    sysdir = root / "sys" / "bus" / "iio" / "devices" / f"iio:device{n}"
    sysdir.mkdir(parents=True)
    attrs = {"name": name, "dev": f"236:{n}", "sampling_frequency": "50"}
    if scale is not None:
        attrs["in_anglvel_scale"] = scale
    if offset is not None:
        attrs["in_anglvel_offset"] = offset
    for a in "xyz":
        attrs[f"in_anglvel_{a}_raw"] = (raw or {}).get(a, "0")
        attrs[f"in_accel_{a}_raw"] = "0"
        if axis_scale and a in axis_scale:
            attrs[f"in_anglvel_{a}_scale"] = axis_scale[a]
        if axis_offset and a in axis_offset:
            attrs[f"in_anglvel_{a}_offset"] = axis_offset[a]
    if clock is not None:
        attrs["current_timestamp_clock"] = clock
    for key, value in attrs.items():
        (sysdir / key).write_text(value + "\n")
    if buffered:
        scan = sysdir / "scan_elements"
        scan.mkdir()
        for channel, index in INDEX.items():
            kind = TIMESTAMP_TYPE if channel == "in_timestamp" else GYRO_TYPE
            kind = (types or {}).get(channel, kind)
            (scan / f"{channel}_en").write_text("0\n")
            (scan / f"{channel}_index").write_text(f"{index}\n")
            (scan / f"{channel}_type").write_text(kind + "\n")
        (sysdir / "buffer").mkdir()
        (sysdir / "buffer" / "enable").write_text("0\n")
        (sysdir / "buffer" / "length").write_text("1\n")
        (sysdir / "buffer" / "watermark").write_text("1\n")
    if trigger is not None:
        (sysdir / "trigger").mkdir()
        (sysdir / "trigger" / "current_trigger").write_text(trigger + "\n")
    if node:
        (root / "dev").mkdir(exist_ok=True)
        os.mkfifo(root / "dev" / f"iio:device{n}")
    return sysdir


def attr(sysdir: Path, name: str) -> str:
    return (sysdir / name).read_text().strip()


def enabled(sysdir: Path) -> set[str]:
    scan = sysdir / "scan_elements"
    return {p.name[:-3] for p in scan.glob("*_en") if p.read_text().strip() == "1"}


def _field(kind: str) -> tuple[str, bool, int, int, int, int]:
    """(struct byte order, signed, realbits, storage bytes, repeat, shift) of a type."""
    m = _TYPE.fullmatch(kind)
    assert m, kind
    order, sign, real, storage, repeat, shift = m.groups()
    return (">" if order == "be" else "<", sign == "s", int(real), int(storage) // 8,
            int(repeat or 1), int(shift or 0))  # fmt: skip


_CODES = {1: "B", 2: "H", 4: "I", 8: "Q"}


def pack_value(kind: str, value: int, junk: bool = False) -> bytes:
    """One value in its storage: two's complement in ``realbits``, shifted; the bits
    outside the field ones when ``junk``."""
    order, signed, real, nbytes, _, shift = _field(kind)
    value = int(value)  # numpy integers overflow in the masking below
    mask = (1 << real) - 1
    lo, hi = (-(1 << (real - 1)), (1 << (real - 1)) - 1) if signed else (0, mask)
    assert lo <= value <= hi, (kind, value)
    word = (value & mask) << shift
    if junk:
        word |= ((1 << (8 * nbytes)) - 1) & ~(mask << shift)
    return struct.pack(order + _CODES[nbytes], word)


def pack_records(
    channels: Sequence[tuple[int, str]],
    rows: Sequence[Sequence[int]],
    junk: bool = False,
    timestamp: int | None = None,
) -> bytes:
    """Records of ``channels`` ((scan index, type) each, in any order; one value per
    repeat) holding ``rows`` (per record, the values in the order of ``channels``).
    ``timestamp``: the position in ``channels`` of the timestamp, which the kernel packs
    after every other channel whatever its scan index (iio_push_to_buffers_with_timestamp
    fills the record's last 8 bytes)."""
    order = sorted(range(len(channels)), key=lambda i: (i == timestamp, channels[i][0]))
    out = bytearray()
    for row in rows:
        record = bytearray()
        largest = 1
        k = 0
        values: dict[int, list[int]] = {}
        for i, (_, kind) in enumerate(channels):
            repeat = _field(kind)[4]
            values[i] = list(row[k : k + repeat])
            k += repeat
        for i in order:
            kind = channels[i][1]
            _, _, _, nbytes, repeat, _ = _field(kind)
            size = nbytes * repeat
            largest = max(largest, size)
            record += b"\0" * (-len(record) % size)
            for v in values[i]:
                record += pack_value(kind, v, junk)
        record += b"\0" * (-len(record) % largest)
        out += record
    return bytes(out)


def gyro_records(raw: Sequence[int], t_ns: Sequence[int], kind: str = GYRO_TYPE,
                 axis: str = "z", junk: bool = False) -> bytes:  # fmt: skip
    """Records of one gyro axis and the timestamp, as the source enables them."""
    channels = [(INDEX[f"in_anglvel_{axis}"], kind), (INDEX["in_timestamp"], TIMESTAMP_TYPE)]
    return pack_records(channels, list(zip(raw, t_ns, strict=True)), junk, timestamp=1)


def stamps_ns(t0: float, n: int, hz: float = 200.0) -> np.ndarray:
    """``n`` timestamps in ns from ``t0`` seconds, ``1/hz`` apart."""
    return (np.int64(round(t0 * 1e9)) + np.arange(n, dtype=np.int64) * int(1e9 / hz)).astype(
        np.int64
    )


class Writer:
    """The kernel's side of the FIFO: write records, then close (the unplug)."""

    def __init__(self, node: Path) -> None:
        self.fd = os.open(node, os.O_WRONLY | os.O_NONBLOCK)

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self.fd, view) :]

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
