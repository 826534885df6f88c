"""The ADNS-3080 downsampler on a serial port (any pyserial URL: a device, a pty,
``socket://host:port``).

On open it flushes the line, asks for the firmware version, sets the sensor resolution
and K from the config and asks for a status.  Whenever a STATUS packet shows settings
other than the config's (the firmware restarted, or a command was lost) it sends them
again.  Decoding, clock mapping and the axis convention live in ``adns_decode``; this
module only moves bytes.

One decoder serves every open of the port, so that its counters add up over reconnects
and the packets sent while the port was closed count as lost.  A reopen drops the
partial frame the decoder held (``AdnsDecoder.reopen``) and hands ``on_raw`` an empty
chunk, which marks the reopen in a capture so that replay drops it at the same place.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import serial

from mousedom.config import MouseConfig
from mousedom.sources import adns_protocol as P
from mousedom.sources.adns_decode import AdnsDecoder
from mousedom.sources.base import Reports, Source, SourceGone, SourceUnavailable

# A downsampler answers the open's GET_VERSION and GET_STATUS within milliseconds, and sends
# MOTION every K polls (at most 0.32 s at K = 255): a port without a packet this long after
# its open is something else (docs/adns-protocol.md).
ANSWER_S = 2.0


class AdnsSource(Source):
    """One downsampler; yields ``Reports`` on host monotonic time in evdev convention."""

    kind = "adns"

    def __init__(
        self,
        mouse: MouseConfig,
        *,
        serial_for_url: Callable[..., Any] = serial.serial_for_url,
        on_raw: Callable[[float, bytes], None] | None = None,
    ) -> None:
        """``on_raw(host_t, chunk)`` sees every chunk read, before decoding, and an empty
        chunk at each reopen of the port: the native capture writer records these, and
        ``adns_decode.packets_to_reports`` replays them."""
        if mouse.serial is None:
            raise ValueError(f"mouse {mouse.name} has no serial section")
        super().__init__(mouse.name)
        self.settings = mouse.serial
        self._serial_for_url = serial_for_url
        self._port: Any = None
        self.decoder = AdnsDecoder(name=mouse.name)
        self._resent_for: int | None = None
        self._opened = False  # opened before: the next open is a reopen
        self._answer_by: float | None = None  # no packet yet: gone if none by then
        self.on_raw = on_raw

    # ------------------------------------------------------------------ hooks

    def _open(self) -> None:
        s = self.settings
        try:
            self._port = self._serial_for_url(s.port, baudrate=s.baud, timeout=0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise SourceUnavailable(f"{s.port}: {e}") from None
        if self._opened:
            # Same decoder: its counters and sequence carry on; the frame it held is gone.
            self.decoder.reopen()
            if self.on_raw is not None:
                self.on_raw(time.monotonic(), b"")  # the reopen marker (a capture's too)
        self._opened = True
        self._resent_for = None
        # Until a first packet decodes, the port may be no downsampler at all (another
        # device, a wrong baud rate, nothing plugged into the adapter): it is read at
        # every wake, and after ANSWER_S without one it is gone (``_read``).
        self._answer_by = None
        self.probe = True
        self.answered = False
        # A lone 0x00 first ends whatever noise the device's receiver holds.
        try:
            self._send(b"\0" + P.encode_command(P.CMD_GET_VERSION) + self._settings_frames())
        except SourceGone as e:
            self.close()
            raise SourceUnavailable(str(e)) from None
        self._update_health()

    def fileno(self) -> int:
        if self._port is None:
            raise SourceGone("not open")
        return self._port.fileno()

    def identity(self) -> str | None:
        if self._port is None:
            return None
        port = self.settings.port
        return port if "://" in port else os.path.realpath(port)

    def _read(self, now: float) -> list[Reports]:
        if self._port is None:
            raise SourceGone("not open")
        try:
            waiting = self._port.in_waiting
            data = self._port.read(waiting or 1)
        except (serial.SerialException, OSError) as e:
            raise SourceGone(f"{self.settings.port}: {e}") from None
        if not data:
            if self.probe:
                self._check_answered(now)
            return []
        if self.on_raw is not None:
            self.on_raw(now, data)
        reports, packets = self.decoder.feed(data, now)
        if self.probe:
            if packets:
                self.probe = False  # a downsampler: its port's readiness wakes the daemon
                self.answered = True  # (and its reports are fused from now on)
                self._answer_by = None
                if self.health.error and self.health.error.startswith("no packet"):
                    self.health.error = None
                    self._update_health()
            else:
                self._check_answered(now)
        for p in packets:
            if isinstance(p, P.Status):
                self._check_settings(p)
        self._update_health()
        return [reports] if len(reports) else []

    def _check_answered(self, now: float) -> None:
        """SourceGone where no packet has decoded within ANSWER_S of the open: a port that
        is not a downsampler was a connected, tracking, motionless mouse for good (the
        robot read as standing still, doctor said all was well)."""
        if self._answer_by is None:
            self._answer_by = now + ANSWER_S
            self.health.error = "no packet from the downsampler yet (not fused until one)"
        elif now > self._answer_by:
            noise = self.decoder.stats().get("discarded_bytes", 0)
            heard = f"{noise} bytes that are no packet" if noise else "nothing"
            raise SourceGone(
                f"{self.settings.port}: no ADNS-3080 downsampler answers ({heard} in "
                f"{ANSWER_S:g} s since the port opened): another device, or a baud rate "
                f"other than the firmware's ({self.settings.baud})?"
            )

    def close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None

    # ------------------------------------------------------------------ commands

    def request_status(self) -> None:
        self._send(P.encode_command(P.CMD_GET_STATUS))

    def _settings_frames(self) -> bytes:
        s = self.settings
        return (
            P.encode_command(P.CMD_SET_CPI, s.sensor_cpi)
            + P.encode_command(P.CMD_SET_K, s.k)
            + P.encode_command(P.CMD_GET_STATUS)
        )

    def _check_settings(self, p: P.Status) -> None:
        s = self.settings
        if p.k == s.k and p.cpi == s.sensor_cpi:
            return
        # Send once per status packet that disagrees: after a firmware restart, or if a
        # command was lost on the line.  The next status shows whether it took.
        if self._resent_for != p.seq:
            self._resent_for = p.seq
            self._send(
                P.encode_command(P.CMD_SET_CPI, s.sensor_cpi) + P.encode_command(P.CMD_SET_K, s.k)
            )

    def _send(self, data: bytes) -> None:
        try:
            self._port.write(data)
        except (serial.SerialException, OSError) as e:
            raise SourceGone(f"{self.settings.port}: {e}") from None

    def _update_health(self) -> None:
        h = self.health
        h.extra = self.decoder.stats()
        h.dropped = self.decoder.lost
        status = self.decoder.last_status
        if status is not None and status.state == P.STATE_NO_SENSOR:
            h.error = f"no ADNS-3080 answers (Product_ID read 0x{status.product_id:02x})"
        elif status is not None and status.state == P.STATE_OK:
            h.error = None


def replay_decoder(mouse: MouseConfig) -> AdnsDecoder:
    """A fresh decoder for one recorded serial port of ``mouse`` (the replay engine's
    hook): ``decoder.feed_many(serial.t, serial.data) -> Reports`` for each batch, in
    order.  Same parser and clock mapping as the live source."""
    return AdnsDecoder(name=mouse.name)
