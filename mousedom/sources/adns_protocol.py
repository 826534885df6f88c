"""The ADNS-3080 downsampler's serial protocol: bytes in, packets out, no I/O.

Wire format (docs/adns-protocol.md has the tables; firmware/src/proto.h is the other
side): each frame is ``COBS(body) 0x00`` where ``body = type, payload, crc16`` with
little-endian fields and CRC-16/CCITT-FALSE over type and payload.  Every type has one
fixed length.  A receiver that meets garbage drops bytes up to the next 0x00, so the
stream resynchronises after at most one damaged frame.

``Parser.feed(data, host_t)`` returns the packets completed by ``data``, each stamped
with the host time of the chunk that completed it, and keeps counts of what it refused
(``ParserStats``): CRC errors, malformed frames, bytes thrown away while resyncing, and
sequence numbers that never arrived.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass, field, fields

from mousedom.sources.clocksync import WRAP, went_back

PROTO_VERSION = 1

PKT_MOTION = 0x01
PKT_STATUS = 0x02
PKT_VERSION = 0x03
PKT_NAK = 0x04

CMD_SET_K = 0x81
CMD_SET_CPI = 0x82
CMD_GET_STATUS = 0x83
CMD_GET_VERSION = 0x84

# MOTION flags
FLAG_OVERFLOW = 0x01  # the sensor's OVF bit: counts were lost inside the sensor
FLAG_FAULT = 0x02  # the sensor stopped answering during this packet
FLAG_BOOT = 0x04  # first MOTION packet since the firmware started
FLAG_DELAYED = 0x08  # frames > K: UART busy, K lowered, or a poll overran its period
FLAG_RES1600 = 0x10  # the sensor said 1600 CPI in its last Motion read
FLAG_SATURATED = 0x20  # a delta came back at full scale and was drained by re-reading
FLAGS_KNOWN = 0x3F

STATE_STARTING, STATE_OK, STATE_NO_SENSOR = 0, 1, 2
STATE_NAMES = {STATE_STARTING: "starting", STATE_OK: "ok", STATE_NO_SENSOR: "no-sensor"}
REASON_BOOT, REASON_REQUEST, REASON_ACK, REASON_FAULT, REASON_RECOVERED = range(5)
REASON_NAMES = ("boot", "request", "ack", "fault", "recovered")
NAK_NAMES = {1: "unknown command", 2: "bad length", 3: "bad value", 4: "bad CRC"}

DRAIN_MAX_READS = 8  # motion reads per frame at most (firmware accum.h)
MAX_FRAME = 64  # longer runs without a 0x00 are garbage (the longest frame is 26 bytes)
SEQ_MOD = 1 << 16

_MOTION = struct.Struct("<HIiiHBB")
_STATUS = struct.Struct("<HIBBBBBHHHHH")
_VERSION = struct.Struct("<HIBBBHI")
_NAK = struct.Struct("<HIBB")


@dataclass(frozen=True)
class Motion:
    """K frames of summed sensor deltas (sensor axes: +dx right, +dy forward)."""

    seq: int
    t_us: int  # firmware clock (32-bit microseconds, wraps) at the last motion read
    dx: int
    dy: int
    frames: int
    squal_min: int
    flags: int
    host_t: float | None = None


@dataclass(frozen=True)
class Status:
    seq: int
    t_us: int
    state: int
    reason: int
    product_id: int
    config_bits: int
    k: int
    cpi: int
    poll_us: int
    overflows: int
    rx_errors: int
    retries: int
    host_t: float | None = None


@dataclass(frozen=True)
class Version:
    seq: int
    t_us: int
    proto: int
    fw_major: int
    fw_minor: int
    poll_us: int
    f_cpu: int
    host_t: float | None = None


@dataclass(frozen=True)
class Nak:
    seq: int
    t_us: int
    cmd: int
    error: int
    host_t: float | None = None


Packet = Motion | Status | Version | Nak
_LAYOUT: dict[int, tuple[struct.Struct, type]] = {
    PKT_MOTION: (_MOTION, Motion),
    PKT_STATUS: (_STATUS, Status),
    PKT_VERSION: (_VERSION, Version),
    PKT_NAK: (_NAK, Nak),
}


# --------------------------------------------------------------------------- CRC and COBS


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF; crc16(b"123456789") == 0x29B1.

    binascii.crc_hqx is this very CRC (poly 0x1021, no reflection) with the initial value
    as an argument, in C: replay parses millions of packets."""
    return binascii.crc_hqx(data, crc)


def crc16_bitwise(data: bytes, crc: int = 0xFFFF) -> int:
    """The same CRC the way the firmware computes it (a reference for the tests)."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (no delimiter); the result holds no zero byte."""
    out = bytearray([0])
    code_at, code = 0, 1
    for byte in data:
        if byte == 0:
            out[code_at] = code
            code_at, code = len(out), 1
            out.append(0)
        else:
            out.append(byte)
            code += 1
            if code == 0xFF:
                out[code_at] = code
                code_at, code = len(out), 1
                out.append(0)
    out[code_at] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Decode one COBS frame (without its delimiter); ValueError when it is malformed."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise ValueError("zero byte inside a COBS frame")
        end = i + code
        if end > n:
            raise ValueError("COBS group runs past the end of the frame")
        block = data[i + 1 : end]
        if 0 in block:
            raise ValueError("zero byte inside a COBS frame")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def frame(body: bytes) -> bytes:
    """Append the CRC to ``body`` and frame it for the wire."""
    crc = crc16(body)
    return cobs_encode(body + bytes((crc & 0xFF, crc >> 8))) + b"\0"


# --------------------------------------------------------------------------- building


def encode_command(cmd: int, arg: int | None = None) -> bytes:
    """A host -> device frame.  SET_K takes k (1..255), SET_CPI takes 400 or 1600."""
    if cmd == CMD_SET_K:
        if arg is None or not 1 <= arg <= 255:
            raise ValueError(f"K must be 1..255, got {arg}")
        body = bytes((cmd, arg))
    elif cmd == CMD_SET_CPI:
        if arg not in (400, 1600):
            raise ValueError(f"sensor CPI must be 400 or 1600, got {arg}")
        body = bytes((cmd,)) + struct.pack("<H", arg)
    elif cmd in (CMD_GET_STATUS, CMD_GET_VERSION):
        body = bytes((cmd,))
    else:
        raise ValueError(f"unknown command 0x{cmd:02x}")
    return frame(body)


def encode_packet(packet: Packet) -> bytes:
    """A device -> host frame (for emulators and tests; the firmware builds its own)."""
    for ptype, (layout, cls) in _LAYOUT.items():
        if isinstance(packet, cls):
            values = [getattr(packet, f.name) for f in fields(packet) if f.name != "host_t"]
            return frame(bytes((ptype,)) + layout.pack(*values))
    raise TypeError(f"not a packet: {packet!r}")


# --------------------------------------------------------------------------- parsing


def decode_body(body: bytes, host_t: float | None = None) -> Packet:
    """Check and unpack one decoded body; ValueError (with the reason) when it is bad."""
    if len(body) < 3:
        raise ValueError("frame too short")
    if not _crc_ok(body):
        raise _CrcError("CRC mismatch")
    ptype, payload = body[0], body[1:-2]
    if ptype not in _LAYOUT:
        raise ValueError(f"unknown packet type 0x{ptype:02x}")
    layout, cls = _LAYOUT[ptype]
    if len(payload) != layout.size:
        raise ValueError(f"type 0x{ptype:02x} has {len(payload)} bytes, not {layout.size}")
    packet = cls(*layout.unpack(payload), host_t)
    _check_values(packet)
    return packet


class _CrcError(ValueError):
    pass


def _crc_ok(body: bytes) -> bool:
    """The last two bytes of a decoded body are the CRC of the rest, little-endian."""
    return crc16(body[:-2]) == body[-2] | (body[-1] << 8)


def _check_values(p: Packet) -> None:
    """Values the firmware can never send: refuse them (a CRC collision, or a bug)."""
    if isinstance(p, Motion):
        limit = 128 * DRAIN_MAX_READS * p.frames
        if p.frames == 0 or abs(p.dx) > limit or abs(p.dy) > limit:
            raise ValueError("implausible motion packet")
        if p.flags & ~FLAGS_KNOWN:
            raise ValueError(f"unknown motion flags 0x{p.flags:02x}")
    elif isinstance(p, Status):
        if p.state not in STATE_NAMES or p.reason >= len(REASON_NAMES):
            raise ValueError("unknown status state or reason")
        if p.k == 0 or p.cpi not in (400, 1600) or p.poll_us == 0:
            raise ValueError("implausible status settings")
    elif isinstance(p, Version):
        if p.poll_us == 0 or p.f_cpu == 0:
            raise ValueError("implausible version packet")
    elif isinstance(p, Nak):
        if p.error not in NAK_NAMES:
            raise ValueError("unknown NAK error")


@dataclass
class ParserStats:
    packets: int = 0
    bytes: int = 0
    crc_errors: int = 0  # frames whose CRC did not match
    bad_frames: int = 0  # malformed COBS, wrong length, unknown type, impossible values
    resyncs: int = 0  # times bytes were thrown away to find the next frame boundary
    discarded_bytes: int = 0
    # Packets the device sent that never arrived, by sequence number: each lost packet
    # once, whatever lost it (a refused frame, an overrun, an unplugged adapter).  The
    # counters above are the reasons, not more losses.
    lost_seq: int = 0
    reboots: int = 0  # the device restarted (its clock and its sequence began again)
    duplicates: int = 0  # the last packet received again, field for field: dropped
    reopens: int = 0  # the port was opened again (``Parser.reopen``)

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


# How a restart of the device is told from a sequence gap or a clock wrap (``Parser``).
MIN_PACKET_US = 500  # the device sends at most one packet per 0.5 ms (115200 baud: ~1.1 ms)
MIN_JUMP = 256  # smaller sequence gaps are losses whatever the clock says
CLOCK_SLACK_S = 10.0  # the firmware clock may run ahead of the host's by this much, and
MAX_DRIFT = 1e-3  # by this fraction of the host's elapsed time (crystals, clocksync)


@dataclass
class Parser:
    """Incremental frame parser; one per serial port.  Never raises on any input.

    Sequence accounting (``stats.lost_seq``) counts every packet that never arrived once,
    from the sequence numbers alone.  A restart of the device (its ``seq`` and ``t_us``
    both begin again from 0) is recognised from the packet that first arrives after it:

    * its firmware clock is earlier than the last packet's (and not a 32-bit wrap);
    * or its clock is further ahead than the host's own clock went (plus 10 s) since
      the last packet was sent: a "wrap" that the host saw take seconds is a new clock.
      When the last packet was sent is its firmware time on the clock's earliest arrival
      (the least read time less firmware time so far, allowed to rise at ``MAX_DRIFT``):
      packets that waited in the port's buffer are read milliseconds apart however far
      apart they were sent, and after a stall in which the kernel dropped bytes, a
      normal gap (seq and clock both carrying on) read so was taken for a restart
      (44,000 packets counted lost, for 1,000);
    * or its sequence number jumped by ``MIN_JUMP`` or more (a jump back is one of nearly
      the whole range) sooner than the device could have sent that many packets (a loss
      across the wrap, 65535 then 1, is a gap of one);
    * or it is the first MOTION of a boot (BOOT flag) with a lower sequence number than
      expected.

    After a restart the packets of the new boot before it (``seq`` of them) are lost;
    what the old boot sent after the last packet that arrived cannot be known.  A packet
    that repeats the last one (every field the same) is dropped and counted in
    ``duplicates``.  ``reopen()`` drops a partial frame but keeps the sequence."""

    stats: ParserStats = field(default_factory=ParserStats)
    _buf: bytearray = field(default_factory=bytearray)
    _skipping: bool = False  # inside an overlong run: drop until the next 0x00
    _last: Packet | None = None  # the last packet taken
    # This boot's clock: its firmware seconds since the boot's first packet taken
    # (unwrapped), and the least of read time less that so far (None: no host times)
    _fw_s: float = 0.0
    _offset: float | None = None

    def feed(self, data: bytes, host_t: float | None = None) -> list[Packet]:
        """Parse ``data``; return the packets it completed, stamped with ``host_t``."""
        return self.feed_marked(data, host_t)[0]

    def feed_marked(
        self, data: bytes, host_t: float | None = None
    ) -> tuple[list[Packet], list[bool]]:
        """As ``feed``, and for each packet whether it is the first seen after a restart
        of the device (its clock began again: the decoder's clock mapping must too)."""
        packets, restarts, _ = self.feed_accounted(data, host_t)
        return packets, restarts

    def feed_accounted(
        self, data: bytes, host_t: float | None = None
    ) -> tuple[list[Packet], list[bool], list[int]]:
        """As ``feed_marked``, and for each packet how many were lost just before it
        (``stats.lost_seq``'s share: what they held, counts included, is unknown)."""
        out: list[Packet] = []
        restarts: list[bool] = []
        losses: list[int] = []
        self.stats.bytes += len(data)
        start = 0
        while True:
            end = data.find(b"\0", start)
            if end < 0:
                self._append(data[start:])
                return out, restarts, losses
            self._append(data[start:end])
            start = end + 1
            if self._skipping:
                self._skipping = False
                continue
            chunk, self._buf = bytes(self._buf), bytearray()
            if not chunk:
                continue  # 0x00 0x00: an empty frame is just idle line
            packet = self._frame(chunk, host_t)
            if packet is None:
                continue
            lost = self.stats.lost_seq
            restarted = self._sequence(packet, host_t)
            if restarted is None:
                continue  # a duplicate
            self.stats.packets += 1
            out.append(packet)
            restarts.append(restarted)
            losses.append(self.stats.lost_seq - lost)

    def reopen(self) -> None:
        """The port was closed and opened again (live, or a capture's reopen marker).

        The bytes of a frame begun before are dropped: they cannot be the start of the
        frame that comes next.  The sequence carries on, so that the packets sent while
        the port was closed count as lost (unless the device restarted meanwhile)."""
        if self._buf:
            self.stats.discarded_bytes += len(self._buf)
        self._buf = bytearray()
        self._skipping = False
        self.stats.reopens += 1

    def _append(self, part: bytes) -> None:
        if self._skipping:
            self.stats.discarded_bytes += len(part)
            return
        self._buf += part
        if len(self._buf) > MAX_FRAME:
            self.stats.resyncs += 1
            self.stats.discarded_bytes += len(self._buf)
            self._buf = bytearray()
            self._skipping = True

    def _frame(self, chunk: bytes, host_t: float | None) -> Packet | None:
        try:
            packet = decode_body(cobs_decode(chunk), host_t)
        except _CrcError:
            self.stats.crc_errors += 1
        except ValueError:
            self.stats.bad_frames += 1
        else:
            return packet
        self.stats.resyncs += 1
        self.stats.discarded_bytes += len(chunk) + 1
        return None

    def _sequence(self, p: Packet, host_t: float | None) -> bool | None:
        """Count what the sequence says was lost; True when ``p`` is the first packet seen
        after a restart of the device, None when it repeats the last one."""
        last = self._last
        if last is not None and p.seq == last.seq and _same(p, last):
            self.stats.duplicates += 1
            return None
        self._last = p
        if last is None:
            self._clock(host_t)
            return False
        expect = (last.seq + 1) % SEQ_MOD
        gap = (p.seq - expect) % SEQ_MOD
        sent = last.host_t
        if sent is not None and self._offset is not None:
            sent = min(sent, self._fw_s + self._offset)  # when the last was sent, at most
        ahead = (p.t_us - last.t_us) % WRAP  # microseconds, a wrap taken as such
        if self._restarted(p, last.t_us, ahead, sent, host_t, expect, gap):
            self.stats.reboots += 1
            self.stats.lost_seq += p.seq  # the new boot's packets before this one
            self._clock(host_t)
            return True
        self.stats.lost_seq += gap
        step = ahead * 1e-6
        self._fw_s += step
        if host_t is not None:
            arrived = host_t - self._fw_s
            self._offset = (
                arrived if self._offset is None else min(self._offset + MAX_DRIFT * step, arrived)
            )
        return False

    def _clock(self, host_t: float | None) -> None:
        """A boot's first packet taken: its clock begins (``_restarted``)."""
        self._fw_s, self._offset = 0.0, host_t

    @staticmethod
    def _restarted(
        p: Packet, t0: int, ahead: int, host0: float | None, host_t: float | None,
        expect: int, gap: int,
    ) -> bool:  # fmt: skip
        if went_back(t0, p.t_us):
            return True  # the clock went back
        if host0 is not None and host_t is not None:
            host = max(host_t - host0, 0.0)
            if ahead * 1e-6 > host * (1 + MAX_DRIFT) + CLOCK_SLACK_S:
                return True  # a "wrap" the host saw take far less time: a new clock
        if gap >= MIN_JUMP and ahead < gap * MIN_PACKET_US:
            return True  # the sequence jumped further than the clock let it (went back)
        boot = isinstance(p, Motion) and bool(p.flags & FLAG_BOOT)
        return boot and p.seq < expect


def _same(a: Packet, b: Packet) -> bool:
    """The same packet, but for the host time of its arrival."""
    return type(a) is type(b) and {**a.__dict__, "host_t": None} == {**b.__dict__, "host_t": None}


def parse_commands(data: bytes) -> list[tuple[int, int | None]]:
    """Host -> device frames in ``data`` as ``(cmd, arg)``; damaged frames are skipped.

    The device side of the protocol, for emulators and tests (the firmware has its own).
    """
    out: list[tuple[int, int | None]] = []
    for chunk in data.split(b"\0"):
        if not chunk:
            continue
        try:
            body = cobs_decode(chunk)
        except ValueError:
            continue
        if len(body) < 3 or not _crc_ok(body):
            continue
        cmd, args = body[0], body[1:-2]
        if cmd == CMD_SET_K and len(args) == 1:
            out.append((cmd, args[0]))
        elif cmd == CMD_SET_CPI and len(args) == 2:
            out.append((cmd, args[0] | (args[1] << 8)))
        elif cmd in (CMD_GET_STATUS, CMD_GET_VERSION) and not args:
            out.append((cmd, None))
    return out
