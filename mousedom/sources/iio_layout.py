"""The Linux IIO buffer's record layout, as data: type strings, offsets, decoding (no I/O).

A buffered IIO device delivers, on ``/dev/iio:deviceN``, a stream of records ("scans"), one
per trigger.  What a record holds is published in sysfs, per channel, under
``scan_elements/`` (Documentation/ABI/testing/sysfs-bus-iio; driver-api/iio/buffers.rst):

* ``<channel>_en``: 1 if the channel is in the record;
* ``<channel>_index``: its scan index, the order of the enabled channels in the record (not
  a byte offset; indices need not be contiguous);
* ``<channel>_type``: ``[be|le]:[s|u]bits/storagebits[Xrepeat][>>shift]``: byte order,
  signedness, the valid bits, the bits it occupies, how many times it repeats (omitted for
  0 or 1), and the right shift to apply before masking the valid bits.

The kernel places the enabled channels in scan-index order, each at the next offset that is a
multiple of its own storage size (storagebits / 8 times repeat), the timestamp last whatever
its index (``iio_push_to_buffers_with_timestamp`` writes it into the record's last 8-byte
slot; a driver may give it any scan index), and pads the record to a
multiple of the largest of those sizes (industrialio-buffer.c, ``iio_compute_scan_bytes``;
the padding of the whole record came with the fix of 2019 so that consecutive records stay
aligned).  So ``le:s16/16>>0`` followed by a ``le:s64/64>>0`` timestamp is 16 bytes: the
value at 0, six bytes of padding, the timestamp at 8.

Decoding is vectorised (one numpy pass per channel over a whole read), keeps the bytes of
an incomplete record for the next read (as the evdev reader keeps partial input_event
records), and cannot read outside the bytes it is given: any bytes decode, and a layout
the kernel would not produce is refused when it is built, with the file it came from.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

STORAGE_BITS = (8, 16, 32, 64)
MAX_REPEAT = 64  # quaternions repeat 4 times; nothing in the kernel comes near this
MAX_RECORD_BYTES = 4096  # a record of every channel of the largest IMU is a few dozen bytes

# [be|le]:[s|u]bits/storagebits[Xrepeat][>>shift]; bounded digit runs, so that a hostile
# file cannot make int() chew on thousands of digits.
_TYPE = re.compile(r"(be|le):([su])(\d{1,3})/(\d{1,3})(?:X(\d{1,4}))?(?:>>(\d{1,3}))?")


class LayoutError(ValueError):
    """A type string, an index or a set of channels that no kernel would publish; the
    message names the file (or channel) it came from."""


class ScanType(NamedTuple):
    """One channel's storage in a record, as its ``_type`` attribute says."""

    big_endian: bool
    signed: bool
    realbits: int  # the valid bits
    storagebits: int  # the bits one value occupies (8, 16, 32 or 64)
    shift: int  # applied before masking the valid bits
    repeat: int = 1  # values of this channel in a record (1 when the type omits it)

    @property
    def storage_bytes(self) -> int:
        """The bytes this channel takes in a record, which is also its alignment."""
        return self.storagebits // 8 * self.repeat

    @property
    def raw_range(self) -> tuple[int, int]:
        """The least and greatest value the valid bits hold (as decoded): a reading at
        either end is the converter's limit, where the sensor saturates (an MPU-6050's
        ``le:s16/16>>0`` clips at -32768 and 32767)."""
        if self.signed:
            return -(1 << (self.realbits - 1)), (1 << (self.realbits - 1)) - 1
        return 0, (1 << self.realbits) - 1


class Element(NamedTuple):
    """An enabled channel of the record: its name (``in_anglvel_z``), scan index, type."""

    name: str
    scan_index: int
    type: ScanType


class Placed(NamedTuple):
    """A channel at its byte offset in the record."""

    element: Element
    offset: int


class RecordLayout(NamedTuple):
    """Where each enabled channel sits in a record, and the record's size in bytes."""

    fields: tuple[Placed, ...]
    size: int

    def field(self, name: str) -> Placed:
        for f in self.fields:
            if f.element.name == name:
                return f
        raise KeyError(name)

    def names(self) -> tuple[str, ...]:
        return tuple(f.element.name for f in self.fields)


class Decoded(NamedTuple):
    """Whole records of one read, decoded: each channel's values (int64; uint64 for an
    unsigned channel of 64 valid bits), shape (n,) or (n, repeat); and the bytes of an
    incomplete record at the end, to be put in front of the next read."""

    records: int
    columns: dict[str, np.ndarray]
    rest: bytes


def parse_scan_type(text: str, where: str = "scan type") -> ScanType:
    """``"le:s16/16>>0"`` -> ScanType; LayoutError naming ``where`` (the file) otherwise."""
    s = text.strip()
    m = _TYPE.fullmatch(s)
    if m is None:
        shown = s if len(s) <= 40 else s[:37] + "..."
        raise LayoutError(
            f"{where}: {shown!r} is not a scan type ([be|le]:[s|u]bits/storagebits"
            "[Xrepeat][>>shift], e.g. le:s16/16>>0)"
        )
    order, sign, real_s, storage_s, repeat_s, shift_s = m.groups()
    realbits, storagebits = int(real_s), int(storage_s)
    repeat = int(repeat_s) if repeat_s else 1
    shift = int(shift_s) if shift_s else 0
    if storagebits not in STORAGE_BITS:
        raise LayoutError(f"{where}: {s!r}: storage of {storagebits} bits (8, 16, 32 or 64)")
    if not 1 <= realbits <= storagebits:
        raise LayoutError(f"{where}: {s!r}: {realbits} valid bits in {storagebits} of storage")
    if realbits + shift > storagebits:
        raise LayoutError(
            f"{where}: {s!r}: {realbits} bits shifted by {shift} overrun {storagebits} of storage"
        )
    repeat = max(repeat, 1)  # the ABI: a repeat of 0 or 1 is written as none
    if repeat > MAX_REPEAT:
        raise LayoutError(f"{where}: {s!r}: repeated {repeat} times (at most {MAX_REPEAT})")
    size = storagebits // 8 * repeat
    if size & (size - 1):
        # The kernel aligns with ALIGN(), defined for powers of two only: it publishes no
        # such channel, and a guess at where it would put one could be wrong.
        raise LayoutError(f"{where}: {s!r}: {size} bytes is not a power of two (no alignment)")
    return ScanType(order == "be", sign == "s", realbits, storagebits, shift, repeat)


# The timestamp's scan element: the kernel puts it after every other channel.
TIMESTAMP = "in_timestamp"


def record_layout(elements: Sequence[Element]) -> RecordLayout:
    """The offsets of the enabled channels in a record and its size, as the kernel lays
    them out: scan-index order, the timestamp last, each aligned to its storage bytes,
    the record padded to the largest alignment."""
    if not elements:
        raise LayoutError("no scan element is enabled: a record would be empty")
    by_index = sorted(elements, key=lambda e: e.scan_index)
    for a, b in zip(by_index, by_index[1:], strict=False):
        if a.scan_index == b.scan_index:
            raise LayoutError(f"{a.name} and {b.name} have the same scan index {a.scan_index}")
    ordered = sorted(by_index, key=lambda e: e.name == TIMESTAMP)  # (stable: index order)
    offset, largest, placed = 0, 1, []
    for e in ordered:
        n = e.type.storage_bytes
        offset = -(-offset // n) * n  # up to a multiple of n
        placed.append(Placed(e, offset))
        offset += n
        largest = max(largest, n)
    size = -(-offset // largest) * largest
    if size > MAX_RECORD_BYTES:
        raise LayoutError(f"a record of {size} bytes (at most {MAX_RECORD_BYTES})")
    return RecordLayout(tuple(placed), size)


def decode_records(data: bytes, layout: RecordLayout) -> Decoded:
    """The whole records at the start of ``data`` decoded; the bytes after them kept."""
    n = len(data) // layout.size
    rest = bytes(data[n * layout.size :])
    rows = np.frombuffer(data, dtype=np.uint8, count=n * layout.size).reshape(n, layout.size)
    columns = {f.element.name: _column(rows, f) for f in layout.fields}
    return Decoded(n, columns, rest)


def _column(rows: np.ndarray, placed: Placed) -> np.ndarray:
    """One channel of every record: its bytes read in their order, shifted, masked to the
    valid bits and sign-extended."""
    st, at = placed.element.type, placed.offset
    width = st.storagebits // 8
    order = ">" if st.big_endian else "<"
    raw = np.ascontiguousarray(rows[:, at : at + st.storage_bytes])
    values = raw.view(f"{order}u{width}").astype(np.uint64)  # (n, repeat)
    values = values >> np.uint64(st.shift)
    if st.realbits < 64:
        values &= np.uint64((1 << st.realbits) - 1)
    if st.signed and st.realbits < 64:
        top = np.uint64(1 << (st.realbits - 1))
        # two's complement of realbits bits: (v ^ top) - top, done in int64
        out = (values ^ top).astype(np.int64) - np.int64(1 << (st.realbits - 1))
    elif st.signed or st.realbits < 64:
        out = values.view(np.int64)
    else:
        out = values  # u64 with 64 valid bits: only uint64 holds it
    return out[:, 0] if st.repeat == 1 else out
