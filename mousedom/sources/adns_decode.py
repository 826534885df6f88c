"""Raw serial bytes of the ADNS-3080 downsampler -> motion reports on host time.  Pure.

``AdnsDecoder`` chains the frame parser (adns_protocol), the firmware clock unwrapper and
the clock sync (clocksync), and turns MOTION packets into ``Reports`` in evdev
convention.  The live serial source (sources/adns.py) and replay of captured serial bytes
both go through it, so a replay gives exactly what the daemon saw.

Axes: the ADNS-3080 counts Delta_X positive when the sensor moves to its right and
Delta_Y positive when it moves forward (datasheet, figure 25: +Y toward the cable).
evdev's REL_X is positive to the right and REL_Y positive backwards, so
``REL_X = Delta_X`` and ``REL_Y = -Delta_Y``.  A board that mirrors the image (sensor
mounted upside down) is the config's ``flip``, handled with the other mount maths.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mousedom.sources import adns_protocol as P
from mousedom.sources.base import Reports
from mousedom.sources.clocksync import ClockSync, FirmwareClock

DEFAULT_POLL_US = 1250  # the firmware's poll period until it tells its own


def kim_lee_velocity(counts: float, cpi: float, k: float, fps: float) -> float:
    """Kim & Lee eq. (50): v = (sum of K counts / CPI) / (K / FPS), in inches per second.

    For the downsampler, K is the packet's frame count and FPS its poll rate
    (1e6 / poll_us): the sensor is read once per poll and sums its own frames between.
    """
    return (counts / cpi) / (k / fps)


@dataclass
class AdnsHealth:
    """What the decoder knows about the sensor and the line, for SOURCE status."""

    sensor: str = "unknown"  # starting / ok / no-sensor (from STATUS packets)
    squal: int | None = None  # minimum SQUAL of the last motion packet
    squal_min: int | None = None  # minimum SQUAL since the last status query
    fault_packets: int = 0
    overflow_packets: int = 0
    saturated_packets: int = 0
    sensor_retries: int = 0
    motion_packets: int = 0
    k: int | None = None
    cpi: int | None = None
    res1600: bool | None = None
    poll_us: int = DEFAULT_POLL_US
    firmware: str | None = None
    velocity_ips: tuple[float, float] = (0.0, 0.0)
    firmware_rx_errors: int = 0
    naks: int = 0
    last_nak: str | None = None
    # Times the firmware clock's mapping began again, at each restart of the device that
    # the parser recognised (its ``reboots``): named apart so that neither hides the other.
    clock_resets: int = 0

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class AdnsDecoder:
    """Feed raw chunks with their host arrival times; get reports and packets back."""

    name: str = "adns"
    parser: P.Parser = field(default_factory=P.Parser)
    clock: FirmwareClock = field(default_factory=FirmwareClock)
    sync: ClockSync = field(default_factory=ClockSync)
    health: AdnsHealth = field(default_factory=AdnsHealth)
    last_status: P.Status | None = None
    last_version: P.Version | None = None
    _last_t: float | None = None  # the last packet's mapped time
    _lost_from: float | None = None  # packets lost since then: the next motion report's

    def feed(self, data: bytes, host_t: float) -> tuple[Reports, list[P.Packet]]:
        packets, restarts, losses = self.parser.feed_accounted(data, host_t)
        t: list[float] = []
        dx: list[int] = []
        dy: list[int] = []
        squal: list[int | None] = []
        overflow: list[bool] = []
        lost_from: list[float | None] = []
        for p, restarted, lost in zip(packets, restarts, losses, strict=True):
            if restarted:
                self._restarted()
            mapped = self.sync.update(self.clock.unwrap(p.t_us), host_t)
            # (a restart after packets of an earlier boot: what that boot had summed and
            # not sent, and its last packets if they never arrived, are gone with it)
            if (lost or (restarted and self._last_t is not None)) and self._lost_from is None:
                # Packets never arrived since the last one that did: the counts they held
                # are unknown (not none, as a mouse that does not report did not move).
                # The next motion report says so for the span back to that packet
                # (fusion.evidence: the mouse is gated in the windows it touches).
                self._lost_from = self._last_t if self._last_t is not None else mapped
            self._last_t = mapped
            if isinstance(p, P.Motion):
                t.append(mapped)
                dx.append(p.dx)
                dy.append(-p.dy)
                squal.append(p.squal_min if p.squal_min != 0xFF else None)
                # counts lost in the sensor, or on the line before this packet
                overflow.append(bool(p.flags & P.FLAG_OVERFLOW) or self._lost_from is not None)
                lost_from.append(self._lost_from)
                self._lost_from = None
                self._motion(p)
            elif isinstance(p, P.Status):
                self._status(p)
            elif isinstance(p, P.Version):
                self.last_version = p
                self.health.poll_us = p.poll_us
                self.health.firmware = f"{p.fw_major}.{p.fw_minor} (protocol {p.proto})"
            elif isinstance(p, P.Nak):
                self.health.naks += 1
                name = P.NAK_NAMES.get(p.error, str(p.error))
                self.health.last_nak = f"command 0x{p.cmd:02x}: {name}"
        reports = Reports(self.name, np.array(t), np.array(dx), np.array(dy))
        if t:
            reports.quality = (t, squal, overflow)
            reports.lost_from = lost_from
        return reports, packets

    def feed_many(self, ts: Iterable[float], pieces: Iterable[bytes]) -> Reports:
        """Feed recorded pieces (a capture's serial batch: host times and raw bytes) and
        return all their motion reports at once.  An empty piece marks where the port was
        opened again (``AdnsSource`` records one at each reopen): ``reopen`` there, as
        the live source did."""
        parts = []
        for t, d in zip(ts, pieces, strict=True):
            if len(d):
                parts.append(self.feed(bytes(d), float(t))[0])
            else:
                self.reopen()
        parts = [r for r in parts if len(r)]
        if not parts:
            return Reports(self.name, np.zeros(0), np.zeros(0), np.zeros(0))
        out = Reports(
            self.name,
            np.concatenate([r.t for r in parts]),
            np.concatenate([r.dx for r in parts]),
            np.concatenate([r.dy for r in parts]),
        )
        # every part holds reports, so feed gave each its quality
        quality = [r.quality for r in parts if r.quality is not None]
        out.quality = (
            [v for q in quality for v in q[0]],
            [v for q in quality for v in q[1]],
            [v for q in quality for v in q[2]],
        )
        out.lost_from = [v for r in parts if r.lost_from is not None for v in r.lost_from]
        return out

    def reopen(self) -> None:
        """The port was opened again: drop a partial frame, keep every counter, the
        sequence and the clock mapping (the firmware may have run on; if it restarted,
        its next packet says so)."""
        self.parser.reopen()

    def _restarted(self) -> None:
        # The firmware rebooted (the parser saw its clock or sequence begin again).  Its
        # new clock has nothing to do with the old one.
        self.clock.reset()
        self.sync.reset()
        self.health.clock_resets += 1

    def _motion(self, p: P.Motion) -> None:
        h = self.health
        h.motion_packets += 1
        h.squal = p.squal_min if p.squal_min != 0xFF else None
        if h.squal is not None:
            h.squal_min = h.squal if h.squal_min is None else min(h.squal_min, h.squal)
        h.res1600 = bool(p.flags & P.FLAG_RES1600)
        if p.flags & P.FLAG_FAULT:
            h.fault_packets += 1
        if p.flags & P.FLAG_OVERFLOW:
            h.overflow_packets += 1
        if p.flags & P.FLAG_SATURATED:
            h.saturated_packets += 1
        fps = 1e6 / h.poll_us
        cpi = 1600 if h.res1600 else 400
        h.velocity_ips = (
            kim_lee_velocity(p.dx, cpi, p.frames, fps),
            kim_lee_velocity(p.dy, cpi, p.frames, fps),
        )

    def _status(self, p: P.Status) -> None:
        self.last_status = p
        h = self.health
        h.sensor = P.STATE_NAMES.get(p.state, str(p.state))
        h.k, h.cpi, h.poll_us = p.k, p.cpi, p.poll_us
        h.sensor_retries = p.retries
        h.firmware_rx_errors = p.rx_errors

    def stats(self) -> dict[str, Any]:
        """Everything for ``SourceHealth.extra``: sensor health and line counters (no
        name in both: one would hide the other)."""
        return {**self.health.as_dict(), **self.parser.stats.as_dict()}

    @property
    def lost(self) -> int:
        """Packets known lost, each once: those missing by sequence number.  Frames
        refused by CRC or framing (``crc_errors``, ``bad_frames``) are why, not more."""
        return self.parser.stats.lost_seq


def packets_to_reports(
    chunks: Iterable[tuple[float, bytes]], name: str = "adns"
) -> tuple[Reports, AdnsDecoder]:
    """Replay raw serial chunks ``(host_t, bytes)``, as a capture stores them.

    Returns all motion reports (host time, REL_X, REL_Y counts) in one ``Reports`` and the
    decoder, whose ``stats()`` and ``lost`` tell what was refused or missing.  Chunks must
    come in the order they were read; a chunk may hold any part of any frame.
    """
    dec = AdnsDecoder(name=name)
    pairs = list(chunks)
    reports = dec.feed_many([t for t, _ in pairs], [d for _, d in pairs])
    return reports, dec
