"""``mousedom record``: every configured source of a rig into one native capture file.

Evdev mice are recorded as their decoded motion reports (t on CLOCK_MONOTONIC, summed
REL_X/REL_Y per SYN_REPORT frame) plus a NOTE per mouse with what was skipped or dropped;
serial sources (the ADNS-3080 downsampler) as the raw bytes read from the port, each read
stamped with its host arrival time, so that replay can parse them with the same code as
the live daemon.  The file is append-only and flushed to the OS at least every
``FLUSH_S`` seconds: a crash or ``kill -9`` loses at most that much, and the reader reports
the torn tail.  SIGINT and SIGTERM only set a flag; the loop then drains, writes the notes
and closes the file.
"""

from __future__ import annotations

import argparse
import math
import selectors
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from mousedom.config import Config, MouseConfig, load_config
from mousedom.errors import UserError
from mousedom.sources.base import SourceGone, SourceUnavailable

FLUSH_S = 0.25  # bound on what a kill -9 can lose
RETRY_S = 0.5  # how often to look for an unplugged device
TICK_S = 0.05  # longest sleep in select: signals and deadlines are noticed this fast


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "record",
        help="record every configured source into a native capture file",
        description="Record the mice (evdev) and serial sensors of a rig config into one "
        "native capture file, showing events and rates per source on stderr. Stop with "
        "Ctrl-C (SIGINT) or SIGTERM, or give --duration.",
    )
    p.add_argument("--config", "-c", required=True, metavar="RIG.yaml")
    p.add_argument("-o", "--output", required=True, metavar="FILE")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--status-interval",
        type=float,
        default=1.0,
        metavar="S",
        help="seconds between status lines on stderr (0: none)",
    )
    p.add_argument("--fsync", action="store_true", help="fsync every chunk (power-loss safe)")
    p.set_defaults(func=run)


# --------------------------------------------------------------------------- serial, raw


class RawSerial:
    """A serial port read as raw bytes (any pyserial URL), for recording only.

    The daemon parses the downsampler's packets (mousedom/sources/adns.py); recording
    keeps the bytes as they came, so a parser bug can be fixed and the run replayed.
    """

    kind = "serial"

    def __init__(self, mouse: MouseConfig) -> None:
        assert mouse.serial is not None
        self.name = mouse.name
        self.port = mouse.serial.port
        self.baud = mouse.serial.baud
        self._ser = None
        self.bytes = 0
        self.reads = 0

    def open(self) -> None:
        import serial  # pyserial

        try:
            self._ser = serial.serial_for_url(self.port, baudrate=self.baud, timeout=0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise SourceUnavailable(f"{self.name}: serial port {self.port}: {e}") from None

    def fileno(self) -> int:
        try:
            return self._ser.fileno() if self._ser is not None else -1
        except (AttributeError, OSError, ValueError):
            return -1  # loop:// and friends: polled every tick instead

    def read(self) -> bytes:
        import serial

        if self._ser is None:
            raise SourceGone(f"{self.name}: not open")
        try:
            data = self._ser.read(65536)
        except (serial.SerialException, OSError) as e:
            self.close()
            raise SourceGone(f"{self.name}: serial port {self.port}: {e}") from None
        self.bytes += len(data)
        self.reads += bool(data)
        return data

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # closing a dead port may fail in many ways; it is gone
                pass
            self._ser = None


# --------------------------------------------------------------------------- recording


@dataclass
class Slot:
    """One configured source and its recording bookkeeping."""

    index: int
    mouse: MouseConfig
    source: object  # EvdevSource or RawSerial
    connected: bool = True
    next_retry: float = 0.0
    reports: int = 0
    last_reports: int = 0
    serial_t: list[float] = field(default_factory=list)
    serial_data: list[bytes] = field(default_factory=list)


def _make_source(cfg: Config, mouse: MouseConfig):
    where = f"{cfg.path}: mice.{mouse.name}"
    if mouse.evdev is not None:
        from mousedom.sources.evdev import EvdevSource

        return EvdevSource(mouse)
    if mouse.serial is not None:
        return RawSerial(mouse)
    raise UserError(f"{where}: a replay source cannot be recorded (it is a recording already)")


def _device_info(slot: Slot):
    from mousedom.capture.base import DeviceInfo as CaptureDevice

    m, src = slot.mouse, slot.source
    if isinstance(src, RawSerial):
        return CaptureDevice(
            name=src.port,
            kind="serial",
            mouse=m.name,
            extra={
                "port": src.port,
                "baud": src.baud,
                "k": m.serial.k,
                "sensor_cpi": m.serial.sensor_cpi,
            },
        )
    d = src.device
    return CaptureDevice(
        name=d.name,
        kind="evdev",
        bus=d.bustype or None,
        vendor=d.vendor or None,
        product=d.product or None,
        version=d.version or None,
        phys=d.phys or None,
        uniq=d.uniq or None,
        mouse=m.name,
        rel_xy=True,
        extra={
            "node": d.node,
            "by_id": list(d.by_id),
            "by_path": list(d.by_path),
            "mouse_dpi": d.mouse_dpi,
            "grabbed": src.grabbed,
        },
    )


class Recorder:
    """The selectors loop: sources in, native capture chunks out, status on stderr."""

    def __init__(
        self, cfg: Config, config_text: str, output: str, *, fsync: bool, stop: list[int]
    ) -> None:
        from mousedom.capture.native import NativeWriter

        self.slots = [Slot(i, m, _make_source(cfg, m)) for i, m in enumerate(cfg.mice)]
        for s in self.slots:
            try:
                s.source.open()
            except SourceUnavailable as e:
                self.close_sources()
                raise UserError(f"{cfg.path}: mice.{s.mouse.name}: {e}", exit_code=1) from None
        try:
            self.writer = NativeWriter(
                output,
                [_device_info(s) for s in self.slots],
                config_text=config_text,
                time_base="monotonic",
                fsync=fsync,
                meta={"recorder": "mousedom record", "config_path": cfg.path},
            )
        except OSError as e:
            self.close_sources()
            raise UserError(f"{output}: cannot write: {e.strerror}", exit_code=1) from None
        self.sel = selectors.DefaultSelector()
        for s in self.slots:
            self._register(s)
        self._stop = stop  # the signal handler appends to it

    def _register(self, s: Slot) -> None:
        fd = s.source.fileno()
        if fd >= 0:
            self.sel.register(fd, selectors.EVENT_READ, s)

    def _unregister(self, s: Slot) -> None:
        for key in list(self.sel.get_map().values()):
            if key.data is s:
                self.sel.unregister(key.fileobj)

    def _read(self, s: Slot, now: float) -> None:
        try:
            if isinstance(s.source, RawSerial):
                data = s.source.read()
                if data:
                    s.serial_t.append(now)
                    s.serial_data.append(data)
                return
            for batch in s.source.read(now):
                self.writer.motion(s.index, batch.t, batch.dx, batch.dy)
                s.reports += len(batch)
        except SourceGone as e:
            self._unregister(s)
            s.connected, s.next_retry = False, now + RETRY_S
            print(f"record: {s.mouse.name}: {e}; waiting for it to come back", file=sys.stderr)

    def _retry(self, s: Slot, now: float) -> None:
        s.next_retry = now + RETRY_S
        try:
            s.source.open()
        except (SourceUnavailable, UserError):
            return
        s.connected = True
        self._register(s)
        node = getattr(getattr(s.source, "device", None), "node", s.mouse.name)
        print(f"record: {s.mouse.name}: back ({node})", file=sys.stderr)

    def _flush(self) -> None:
        for s in self.slots:
            if s.serial_data:
                self.writer.serial_many(s.index, s.serial_t, s.serial_data)
                s.serial_t, s.serial_data = [], []
        self.writer.flush()

    def status(self, elapsed: float, dt: float) -> str:
        parts = []
        for s in self.slots:
            src = s.source
            if isinstance(src, RawSerial):
                parts.append(f"{s.mouse.name} {src.bytes} B in {src.reads} reads")
                continue
            st = src.assembler.stats
            rate = (s.reports - s.last_reports) / dt if dt > 0 else 0.0
            s.last_reports = s.reports
            state = "" if s.connected else " (gone)"
            extra = f" dropped {st.dropped_frames}" if st.dropped_frames else ""
            parts.append(
                f"{s.mouse.name} {st.events} events {s.reports} reports {rate:.0f} Hz{extra}{state}"
            )
        return f"record: {elapsed:6.1f} s  " + " | ".join(parts)

    def run(self, duration: float | None, status_every: float) -> None:
        t0 = time.monotonic()
        last_flush = last_status = t0
        polled = [s for s in self.slots if s.source.fileno() < 0]
        while not self._stop:
            now = time.monotonic()
            if duration is not None and now - t0 >= duration:
                break
            before = now
            timeout = TICK_S if not polled else 0.005
            for key, _ in self.sel.select(timeout):
                self._read(key.data, time.monotonic())
            now = time.monotonic()
            for s in self.slots:
                if not s.connected and now >= s.next_retry:
                    self._retry(s, now)
                elif s.connected and s.source.fileno() < 0:
                    self._read(s, now)
            if now - last_flush >= FLUSH_S:
                self._flush()
                # Every fd was drained up to `before`: reports stamped before it are in.
                self.writer.sync(before)
                last_flush = now
            if status_every > 0 and now - last_status >= status_every:
                print(self.status(now - t0, now - last_status), file=sys.stderr, flush=True)
                last_status = now
        self.finish(time.monotonic() - t0)

    def finish(self, elapsed: float) -> None:
        now = time.monotonic()
        for s in self.slots:  # one last drain: what arrived before the stop is kept
            if s.connected:
                self._read(s, now)
        self._flush()
        from mousedom.capture.base import DeviceStats

        for s in self.slots:
            if isinstance(s.source, RawSerial):
                continue
            a = s.source.assembler.stats
            self.writer.note(
                s.index,
                DeviceStats(
                    events=a.events,
                    frames=a.frames,
                    skipped=a.skipped,
                    dropped_frames=a.dropped_frames,
                    dropped_events=a.dropped_events,
                    lost_x=a.dropped_dx,
                    lost_y=a.dropped_dy,
                    unterminated=a.incomplete_events,
                ),
            )
        self.writer.close()
        self.close_sources()
        for s in self.slots:  # the last line gives average rates over the whole run
            s.last_reports = 0
        print(self.status(elapsed, elapsed).replace("record:", "record: done", 1), file=sys.stderr)

    def close_sources(self) -> None:
        for s in self.slots:
            s.source.close()


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    config_text = Path(args.config).read_text()
    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        raise UserError(f"--duration: must be a positive number of seconds, got {args.duration}")
    stop = []

    def on_signal(signum: int, frame: object) -> None:
        stop.append(signum)  # only a flag: the loop notices within TICK_S and closes cleanly

    # Installed before the sources open, so that an early Ctrl-C still closes cleanly.
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    rec = Recorder(cfg, config_text, args.output, fsync=args.fsync, stop=stop)
    names = ", ".join(f"{s.mouse.name} ({_describe(s)})" for s in rec.slots)
    print(f"record: {args.output}: recording {names}", file=sys.stderr, flush=True)
    rec.run(args.duration, args.status_interval)
    return 0


def _describe(s: Slot) -> str:
    if isinstance(s.source, RawSerial):
        return f"serial {s.source.port}"
    return s.source.device.node
