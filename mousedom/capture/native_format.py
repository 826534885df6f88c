"""The native capture format's layout: the file header, the chunk header and its CRC,
and the checks on each chunk's columns that writer and reader share.

Layout (all integers little-endian; full description in docs/captures.md)::

    file   = magic header chunk*
    magic  = b"MDCAP\\r\\n\\x1a"                      (8 bytes; catches text-mode mangling)
    header = u16 major, u16 minor, u32 n, n bytes of JSON, u32 crc32(JSON)
    chunk  = b"MDCK", u8 kind, u8 flags, u16 source, u32 count, u32 size, u32 crc,
             size bytes of payload                  (crc32 over the 16 bytes before it
                                                     and the payload as stored)

Chunk kinds: MOTION (count reports as columns: f8 t[count], i4 dx[count], i4 dy[count]),
SERIAL (count pieces of raw serial bytes: f8 t[count], u4 len[count], then the bytes; an
empty piece marks a reopen of the port, where the decoder drops a partial frame),
NOTE (JSON counters of what a converted source skipped or dropped), SYNC (one f8: every
report of every source stamped at or before it is in the file by now; readers use it to
close windows while streaming), RATE (count samples of a gyro, an "iio" device, as
columns: f8 t[count], f8 rate[count], rad/s), RATE_SATURATED (the same with a third
column u1 saturated[count], 1 where the sample was read at its converter's limit, else 0;
written instead of RATE for a chunk that holds such a sample).  Flag bit 0: the payload is
zlib-compressed.

Versions: a file is written as the oldest version that holds its devices: 1.0 without a
gyro (what every reader of this format reads), 2.0 with one.  A gyro's samples are not
something an older reader may skip (it would take the RATE chunk for corruption, or read
the rig without the gyro its config names), so they take a new major version, which
readers of 1.x refuse by name.  2.1 added RATE_SATURATED: a reader of 2.0 reads a 2.1
file up to the first chunk holding a saturated sample, which it takes for a malformed one
(an error naming its offset where good chunks follow, a torn tail where it is the last):
it never reads a clipped rate as a turn.

Why this shape: a crash can only tear the chunk being written, and each chunk is checked
by its CRC, so a reader keeps every whole chunk and reports the torn tail with its size.
A bad chunk followed by good ones is corruption, not a crash: that is an error, because
the counts in it would be silently lost.  Fixed-size columns load with numpy.frombuffer,
which is what makes the replay fast.
"""

from __future__ import annotations

import json
import struct
import zlib
from typing import Any, BinaryIO

import numpy as np

from mousedom.capture.base import GYRO_KIND, MAX_TIME_S, SOURCE_COUNTERS, CaptureError
from mousedom.errors import located
from mousedom.sources.base import MAX_RATE

MAGIC = b"MDCAP\r\n\x1a"
VERSION = (1, 0)  # a file without a gyro: readable by every reader of the format
GYRO_VERSION = (2, 1)  # a file with a gyro (an "iio" device and its RATE chunks)
KNOWN_MAJORS = (VERSION[0], GYRO_VERSION[0])
CHUNK_MAGIC = b"MDCK"
CHUNK = struct.Struct("<4sBBHIII")
MOTION, SERIAL, NOTE, SYNC, RATE, RATE_SATURATED = 1, 2, 3, 4, 5, 6
KINDS = (MOTION, SERIAL, NOTE, SYNC, RATE, RATE_SATURATED)
GYRO_KINDS = (RATE, RATE_SATURATED)  # a gyro's chunks, and only a gyro's
# Chunks of fixed columns, so many bytes per report or sample: what count states is their
# size.
RECORD_BYTES = {MOTION: 16, RATE: 16, RATE_SATURATED: 17}
FIXED_KINDS = tuple(RECORD_BYTES)
# A larger rate, or one that is not finite, is corruption (sources.base.MAX_RATE).
ZLIB = 1
MAX_CHUNK = 64 << 20  # larger payloads are corruption, not data
# A compressed chunk may inflate to at most this many times its stored size (and never past
# MAX_CHUNK).  What the writer stores inflates about 2:1 (motion columns) to 5:1 (serial
# bytes of an idle sensor); zlib itself reaches 1032:1, which is how a 1 MB file could
# claim a gigabyte of reports.  The bound makes what a file can cost follow its size.
MAX_INFLATE_RATIO = 100
INFLATE_SLACK = 4096  # tiny chunks (a NOTE, a SYNC) are not held to the ratio
NOTE_FIELDS = SOURCE_COUNTERS
# Counts inside dropped frames are sums of REL values: they carry a sign (a dropped frame
# of REL_X -7 is lost_x -7).  Every other counter counts things and is never negative.
SIGNED_NOTE_FIELDS = frozenset({"lost_x", "lost_y"})


def is_native(prefix: bytes) -> bool:
    return prefix.startswith(MAGIC)


def chunk_crc(head: bytes, payload: bytes | memoryview) -> int:
    """CRC-32 over the first 16 bytes of the chunk header and the payload as stored."""
    return zlib.crc32(payload, zlib.crc32(head[:16]))


def check_chunk_head(head: bytes) -> str | None:
    if len(head) < CHUNK.size:
        return "chunk header cut short"
    magic, kind, flags, source, count, size, crc = CHUNK.unpack(head)
    if magic != CHUNK_MAGIC:
        return "no chunk marker"
    if kind not in KINDS or flags & ~ZLIB or size > MAX_CHUNK:
        return "malformed chunk header"
    return None


HEADER_JSON_OFFSET = 16  # magic (8), u16 major, u16 minor, u32 n: then the header's JSON


def read_header(path: str, f: BinaryIO) -> tuple[dict[str, Any], int, int]:
    """The header's JSON, the file's major version and where the chunks start."""
    magic = f.read(len(MAGIC))
    if magic != MAGIC:
        raise CaptureError(located(path, None, "byte offset 0: not a mousedom native capture"))
    fixed = f.read(8)
    if len(fixed) < 8:
        raise CaptureError(located(path, None, "byte offset 8: header cut short"))
    major, minor, n = struct.unpack("<HHI", fixed)
    if major not in KNOWN_MAJORS:
        known = " and ".join(f"{k}.x" for k in KNOWN_MAJORS)
        raise CaptureError(
            located(
                path,
                None,
                f"byte offset 8: unknown native capture version {major}.{minor} "
                f"(this reader knows {known})",
            )
        )
    if n > MAX_CHUNK:
        raise CaptureError(located(path, None, "byte offset 12: header length is implausible"))
    body = f.read(n)
    crc = f.read(4)
    if len(body) < n or len(crc) < 4:
        raise CaptureError(located(path, None, "byte offset 16: header cut short"))
    if zlib.crc32(body) != struct.unpack("<I", crc)[0]:
        raise CaptureError(located(path, None, "byte offset 16: header CRC mismatch"))
    try:
        header = json.loads(body)
        if not isinstance(header, dict) or not isinstance(header.get("devices"), list):
            raise ValueError("no device list")
    except RecursionError:  # (json's decoder recurses: a header nested 100,000 deep)
        raise CaptureError(located(path, None, "byte offset 16: bad header: nested too "
                                   "deep")) from None  # fmt: skip
    except ValueError as e:
        raise CaptureError(located(path, None, f"byte offset 16: bad header: {e}")) from None
    return header, major, len(MAGIC) + 8 + n + 4


def version_for(kinds: list[str]) -> tuple[int, int]:
    """The version a file of devices of these kinds is written as (module docstring)."""
    return GYRO_VERSION if GYRO_KIND in kinds else VERSION


def motion_columns(
    path: str, payload: bytes, count: int, offset: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A MOTION chunk's columns (t, dx, dy), checked."""
    if len(payload) != 16 * count:
        raise CaptureError(
            located(path, None, f"byte offset {offset}: motion chunk of {count} reports holds "
                    f"{len(payload)} bytes, not {16 * count}")
        )  # fmt: skip
    t = np.frombuffer(payload, "<f8", count)
    dx = np.frombuffer(payload, "<i4", count, 8 * count).astype(np.int64)
    dy = np.frombuffer(payload, "<i4", count, 12 * count).astype(np.int64)
    if not (np.abs(t) < MAX_TIME_S).all():  # NaN fails this too
        raise CaptureError(located(path, None, f"byte offset {offset}: time out of range"))
    return t, dx, dy


def rate_columns(
    path: str, payload: bytes, count: int, offset: int, kind: int = RATE
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A RATE or RATE_SATURATED chunk's columns (t, rate, saturated or None), checked: bit
    for bit what the writer was given."""
    size = RECORD_BYTES[kind] * count
    if len(payload) != size:
        raise CaptureError(
            located(path, None, f"byte offset {offset}: gyro chunk of {count} samples holds "
                    f"{len(payload)} bytes, not {size}")
        )  # fmt: skip
    t = np.frombuffer(payload, "<f8", count)
    rate = np.frombuffer(payload, "<f8", count, 8 * count)
    saturated = None
    if kind == RATE_SATURATED:
        flags = np.frombuffer(payload, "u1", count, 16 * count)
        if (flags > 1).any():
            k = int(np.argmax(flags > 1))
            raise CaptureError(
                located(path, None, f"byte offset {offset}: gyro sample {k} is marked "
                        f"saturated {int(flags[k])}: 0 or 1")
            )  # fmt: skip
        saturated = flags.astype(bool)
    if not (np.abs(t) < MAX_TIME_S).all():  # NaN fails this too
        raise CaptureError(located(path, None, f"byte offset {offset}: time out of range"))
    if not (np.abs(rate) < MAX_RATE).all():
        k = int(np.argmin(np.abs(rate) < MAX_RATE))
        raise CaptureError(
            located(path, None, f"byte offset {offset}: gyro sample {k} has rate "
                    f"{float(rate[k])!r}: not a rate (finite, below {MAX_RATE:g} rad/s)")
        )  # fmt: skip
    return t, rate, saturated


def plausible_time(t: float) -> bool:
    return bool(abs(t) < MAX_TIME_S)  # False for NaN and inf


def note_counters(note: object) -> dict[str, int]:
    """A NOTE's counters, checked (ValueError naming the first bad one): the one rule that
    the writer applies before writing and the reader when reading.

    Each is an integer that floats hold exactly (below 2**53 in size); the counts lost in
    dropped frames may be negative, every other counter may not.  A missing key is 0."""
    if not isinstance(note, dict):
        raise ValueError("not a JSON object")
    out = {}
    for k in NOTE_FIELDS:
        v = note.get(k, 0)
        low = -(2**53) if k in SIGNED_NOTE_FIELDS else 0
        if isinstance(v, bool) or not isinstance(v, int) or not low <= v < 2**53:
            raise ValueError(f"{k}: not a counter: {v!r}")
        out[k] = v
    return out


def serial_pieces(
    path: str, payload: bytes, count: int, offset: int
) -> tuple[np.ndarray, list[bytes]]:
    """A SERIAL chunk's read times and the bytes of each read, checked."""
    if len(payload) < 12 * count:
        raise CaptureError(located(path, None, f"byte offset {offset}: serial chunk too short"))
    t = np.frombuffer(payload, "<f8", count)
    if not (np.abs(t) < MAX_TIME_S).all():  # NaN fails this too
        raise CaptureError(located(path, None, f"byte offset {offset}: serial time out of range"))
    lens = np.frombuffer(payload, "<u4", count, 8 * count).astype(np.int64)
    if 12 * count + int(lens.sum()) != len(payload):
        raise CaptureError(
            located(path, None, f"byte offset {offset}: serial chunk lengths do not add up")
        )
    ends = 12 * count + np.cumsum(lens)
    starts = ends - lens
    pieces = [payload[s:e] for s, e in zip(starts.tolist(), ends.tolist(), strict=False)]
    return t, pieces
