"""``mousedom record``: every configured source of a rig into one native capture file.

Evdev mice are recorded as their decoded motion reports (t on CLOCK_MONOTONIC, summed
REL_X/REL_Y per SYN_REPORT frame) plus a NOTE per mouse with what was skipped or dropped;
the rig's gyro (``gyro:``) as its samples (t, yaw rate in rad/s: what the daemon fuses);
serial sources (the ADNS-3080 downsampler) as the raw bytes read from the port, each read
stamped with its host arrival time, so that replay can parse them with the same code as
the live daemon (the port is driven by ``AdnsSource``, which also sets K and CPI, through
its ``on_raw`` hook).  The file is append-only and flushed to the OS at least every
``FLUSH_S`` seconds: a crash or ``kill -9`` loses at most that much, and the reader reports
the torn tail.  SIGINT and SIGTERM only set a flag; the loop then drains, writes the notes
and closes the file.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import selectors
import signal
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from mousedom import saferead
from mousedom.capture.base import SOURCE_COUNTERS, DeviceStats
from mousedom.commands import _options as options
from mousedom.commands._recordslots import (
    GyroSlot,
    Slot,
    describe,
    device_info,
    fileno_of,
    gyro_device_info,
    make_gyro_slot,
    make_slot,
    node_of,
)
from mousedom.config import Config, load_config
from mousedom.errors import UserError
from mousedom.safewrite import same_file
from mousedom.sources.base import SourceGone, SourceUnavailable
from mousedom.sources.discovery import SystemPaths, paths_for_root

if TYPE_CHECKING:
    from mousedom.sources.iio_sysfs import IioPaths

Sensor = Slot | GyroSlot  # what the loop reads: a mouse's slot, or the gyro's

log = logging.getLogger(__name__)

FLUSH_S = 0.25  # bound on what a kill -9 can lose
# The counters whose change is written at the next flush (the rest at the end): what a
# replay must say was lost
LOSS_COUNTERS = ("dropped_frames", "dropped_events", "lost_x", "lost_y", "skipped")
RETRY_S = 0.5  # how often to look for an unplugged device
TICK_S = 0.05  # longest sleep in select: signals and deadlines are noticed this fast


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "record",
        help="record every configured source into a native capture file",
        description="Record the mice (evdev) and serial sensors of a rig config into one "
        "native capture file, showing events and rates per source on stderr. Stop with "
        "Ctrl-C (SIGINT), SIGTERM or a hangup (SIGHUP; not under nohup), or give --duration.",
    )
    options.add_config(p, "the rig config whose sources to record", required=True)
    options.add_output(
        p,
        "the native capture to write (refused if it exists, unless --force); - for stdout",
        required=True,
    )
    p.add_argument("--duration", type=options.number, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--status-interval",
        type=options.number,
        default=1.0,
        metavar="S",
        help="seconds between status lines on stderr (0: none)",
    )
    p.add_argument("--fsync", action="store_true", help="fsync every chunk (power-loss safe)")
    p.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    p.add_argument(
        "--root",
        metavar="DIR",
        help="look for evdev mice under DIR/dev/input, DIR/sys/class/input and "
        "DIR/run/udev/data, and for the gyro under DIR/sys/bus/iio/devices and DIR/dev "
        "(as `mousedom list --root`: containers, tests)",
    )
    p.set_defaults(func=run)


# --------------------------------------------------------------------------- recording


class Recorder:
    """The selectors loop: sources in, native capture chunks out, status on stderr."""

    def __init__(
        self,
        cfg: Config,
        config_text: str,
        output: str,
        *,
        fsync: bool,
        stop: list[int],
        paths: SystemPaths | None = None,
        iio: IioPaths | None = None,
    ) -> None:
        from mousedom.capture.native import NativeWriter

        self.slots = [make_slot(cfg, i, m, paths) for i, m in enumerate(cfg.mice)]
        self.gyro = make_gyro_slot(cfg, len(self.slots), iio)
        self.sensors: list[Sensor] = [*self.slots, *([self.gyro] if self.gyro else [])]
        for s in self.sensors:
            try:
                s.source.open()
            except SourceUnavailable as e:
                self.close_sources()
                where = "gyro" if isinstance(s, GyroSlot) else f"mice.{s.name}"
                raise UserError(f"{cfg.path}: {where}: {e}", exit_code=1) from None
        try:
            _check_distinct(cfg, self.slots, output)
        except UserError:
            self.close_sources()
            raise
        from mousedom.capture.assignment import config_inputs

        try:
            self.writer = NativeWriter(
                sys.stdout.buffer if output == "-" else output,
                [device_info(s) for s in self.slots]
                + ([gyro_device_info(self.gyro)] if self.gyro else []),
                config_text=config_text,
                time_base="monotonic",
                fsync=fsync,
                meta={"recorder": "mousedom record", "config_path": cfg.path},
                inputs=config_inputs(cfg),
            )
        except UserError as e:  # the output refused (a link, an input) or unwritable
            self.close_sources()
            raise UserError(str(e), exit_code=1) from None
        except OSError as e:
            self.close_sources()
            raise UserError(f"{output}: cannot write: {e.strerror}", exit_code=1) from None
        self.sel = selectors.DefaultSelector()
        for s in self.sensors:
            self._register(s)
        self._stop = stop  # the signal handler appends to it
        self.output = "<stdout>" if output == "-" else output
        self._quiet = False  # stderr went away: no more status lines
        self._noted: dict[int, DeviceStats] = {}  # each mouse's counters in NOTEs so far

    def _register(self, s: Sensor) -> None:
        fd = fileno_of(s.source)
        s.polled = fd < 0
        if not s.polled:
            self.sel.register(fd, selectors.EVENT_READ, s)

    def _unregister(self, s: Sensor) -> None:
        for key in list(self.sel.get_map().values()):
            if key.data is s:
                self.sel.unregister(key.fileobj)

    def _read(self, s: Sensor, now: float) -> None:
        try:
            if isinstance(s, GyroSlot):
                for samples in s.source.read(now):
                    with self._writing():
                        self.writer.gyro(s.index, samples.t, samples.rate, samples.saturated)
                    s.reports += len(samples)
                return
            for batch in s.source.read(now):  # a serial source's bytes went to on_raw
                if not s.serial:
                    self._write_motion(s, batch.t, batch.dx, batch.dy)
                s.reports += len(batch)
        except SourceGone as e:
            self._unregister(s)
            s.connected, s.next_retry = False, now + RETRY_S
            self.say(f"record: {_without_name(s, e)}; waiting for it to come back")

    def _write_motion(self, s: Slot, t, dx, dy) -> None:
        """A mouse's reports into the file.  One whose summed frame is beyond the native
        format's 32 bits (no mouse sends one; a FIFO may) stops the recording with a line
        naming the mouse and its device, the reports before it written (the whole read was
        refused, and the file could hold nothing of it)."""
        from mousedom.capture.base import CaptureError
        from mousedom.capture.native_writer import beyond_i4

        try:
            with self._writing():
                self.writer.motion(s.index, t, dx, dy)
            return
        except CaptureError:  # (checked once, by the writer; which report, only here)
            k = beyond_i4(dx, dy)
            if k is None:
                raise
        if k:
            with self._writing():
                self.writer.motion(s.index, t[:k], dx[:k], dy[:k])
        raise UserError(
            f"record: {s.name} ({node_of(s)}): a frame at t={float(t[k]):.6f} sums "
            f"({int(dx[k])}, {int(dy[k])}) counts, beyond the native format's signed 32 "
            f"bits; the recording stops here ({self.output} holds everything before it)",
            exit_code=1,
        )

    def _retry(self, s: Sensor, now: float) -> None:
        s.next_retry = now + RETRY_S
        try:
            s.source.open()
        except (SourceUnavailable, UserError):
            return
        s.connected = True
        self._register(s)
        node = getattr(getattr(s.source, "device", None), "node", s.name)
        self.say(f"record: {s.name}: back ({node})")

    def say(self, line: str) -> None:
        """A status line on stderr.  The recording is the job, the status is decoration: a
        closed stderr (``record ... 2>&1 | head``, a dropped ssh session) silences it and
        the recording goes on."""
        if self._quiet:
            return
        try:
            print(line, file=sys.stderr, flush=True)
        except OSError:
            self._quiet = True
            # Nothing more goes to the dead stream, not even Python's flush at exit.
            sys.stderr = open(os.devnull, "w")  # noqa: SIM115 (lives until exit)

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """Errors writing the capture (disk full, quota, file size limit, I/O error) stop
        the recording with one line that says so; the sources turn their own errors into
        SourceGone, so any OSError here is the file's."""
        try:
            yield
        except OSError as e:
            n = sum(s.reports for s in self.slots)
            raise UserError(
                f"{self.output}: cannot write: {e.strerror or e}; recording stopped after "
                f"{n} reports; the file holds what was written before (a reader skips its "
                "torn tail)",
                exit_code=1,
            ) from None

    def _flush(self) -> None:
        with self._writing():
            for s in self.slots:
                if s.raw is not None and s.raw.data:
                    self.writer.serial_many(s.index, s.raw.t, s.raw.data)
                    s.raw.t, s.raw.data = [], []
            self._note_counters(final=False)
            self.writer.flush()

    def _note_counters(self, final: bool) -> None:
        """Each evdev mouse's counters since its last NOTE (a reader adds NOTE chunks up):
        at each flush where frames were dropped, skipped or cut since, so that a kill -9
        loses at most FLUSH_S of them (one NOTE at the end lost them all: a replay of the
        torn file said nothing of the counts lost in dropped frames); at the end, the rest."""
        for s in self.slots:
            if s.serial:
                continue
            now = DeviceStats()
            now.take_assembler(s.evdev.assembler.stats)
            before = self._noted.get(s.index, DeviceStats())
            delta = {k: getattr(now, k) - getattr(before, k) for k in SOURCE_COUNTERS}
            if any(delta[k] for k in (SOURCE_COUNTERS if final else LOSS_COUNTERS)):
                self.writer.note(s.index, DeviceStats(**delta))
                self._noted[s.index] = now

    def status(self, elapsed: float, dt: float) -> str:
        parts = []
        for s in self.sensors:
            rate = (s.reports - s.last_reports) / dt if dt > 0 else 0.0
            s.last_reports = s.reports
            state = "" if s.connected else " (gone)"
            if isinstance(s, GyroSlot):
                parts.append(f"gyro {s.reports} samples {rate:.0f} Hz{state}")
                continue
            if s.raw is not None:
                parts.append(
                    f"{s.mouse.name} {s.raw.total} B {s.reports} reports {rate:.0f} Hz{state}"
                )
                continue
            src = s.evdev
            st = src.assembler.stats
            extra = f" dropped {st.dropped_frames}" if st.dropped_frames else ""
            if src.time_backwards:
                extra += f" stamped-backwards {src.time_backwards}"
            parts.append(
                f"{s.mouse.name} {st.events} events {s.reports} reports {rate:.0f} Hz{extra}{state}"
            )
        return f"record: {elapsed:6.1f} s  " + " | ".join(parts)

    def run(self, duration: float | None, status_every: float) -> None:
        try:
            self._loop(duration, status_every)
        finally:
            # Whatever happened, what was recorded stays readable and the devices are
            # released (both are idempotent after a normal finish).
            self._close_writer()
            self.close_sources()

    def _close_writer(self) -> None:
        try:
            self.writer.close()
        except OSError:
            # The file cannot take the last buffered data (the error that stopped us was
            # reported already).  NativeWriter.close flushes before closing, so close the
            # file itself: otherwise Python retries the flush at exit and prints a trace.
            f = getattr(self.writer, "_f", None)
            if f is not None:
                try:
                    f.close()
                except OSError:
                    pass

    def _loop(self, duration: float | None, status_every: float) -> None:
        t0 = time.monotonic()
        last_flush = last_status = t0
        polled = any(s.polled for s in self.sensors)
        while not self._stop:
            now = time.monotonic()
            if duration is not None and now - t0 >= duration:
                break
            before = now
            timeout = TICK_S if not polled else 0.005
            for key, _ in self.sel.select(timeout):
                self._read(key.data, time.monotonic())
            now = time.monotonic()
            for s in self.sensors:
                if not s.connected and now >= s.next_retry:
                    self._retry(s, now)
                elif s.connected and s.polled:
                    self._read(s, now)
            if now - last_flush >= FLUSH_S:
                self._flush()
                # Every fd was drained up to `before`: reports stamped before it are in.
                with self._writing():
                    self.writer.sync(before)
                last_flush = now
            if status_every > 0 and now - last_status >= status_every:
                self.say(self.status(now - t0, now - last_status))
                last_status = now
        self.finish(time.monotonic() - t0)

    def finish(self, elapsed: float) -> None:
        now = time.monotonic()
        for s in self.sensors:  # one last drain: what arrived before the stop is kept
            if s.connected:
                self._read(s, now)
        for slot in self.slots:  # and a frame still open (Ctrl-C mid-frame): its counts
            if not slot.serial and slot.connected:
                for batch in slot.evdev.end_frame(now):
                    self._write_motion(slot, batch.t, batch.dx, batch.dy)
                    slot.reports += len(batch)
        self._flush()
        self._note_counters(final=True)
        with self._writing():
            self.writer.close()
        self.close_sources()
        for s in self.sensors:  # the last line gives average rates over the whole run
            s.last_reports = 0
        self.say(self.status(elapsed, elapsed).replace("record:", "record: done", 1))
        self.say(f"record: wrote {self.output}")

    def close_sources(self) -> None:
        for s in self.sensors:
            s.source.close()


def _check_output(args: argparse.Namespace) -> None:
    """-o: stdout (``-``, as convert's and replay's -o -: the capture chunk by chunk to a
    pipe such as ssh or gzip; a file named "-" was written before), or a file that is not
    the config and is not overwritten without --force."""
    if args.output == "-":
        # As convert's and replay's -o -: the capture goes to stdout (a pipe to ssh, gzip),
        # chunk by chunk as it is recorded.  (A file named "-" was written before.)
        options.binary_stdout()  # (refused early where it cannot be a pipe)
        if args.fsync:
            raise UserError("--fsync: -o - writes to a pipe, which cannot be fsync'ed")
    else:
        if same_file(args.output, args.config):
            raise UserError(f"{args.output}: is the config file {args.config}; not overwriting it")
        if os.path.exists(args.output) and not args.force:
            raise UserError(f"{args.output}: exists; not overwriting a recording (use --force)")


def run(args: argparse.Namespace) -> int:
    if not args.output:
        raise UserError("-o/--output: empty file name")
    cfg = load_config(args.config)
    _check_output(args)
    config_text = saferead.read_text(args.config)
    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        raise UserError(f"--duration: must be a positive number of seconds, got {args.duration}")
    if not (args.status_interval >= 0 and math.isfinite(args.status_interval)):
        raise UserError(
            f"--status-interval: must be 0 (no status) or a number of seconds, "
            f"got {args.status_interval}"
        )
    stop = []

    def on_signal(signum: int, frame: object) -> None:
        stop.append(signum)  # only a flag: the loop notices within TICK_S and closes cleanly

    # Installed before the sources open, so that an early Ctrl-C still closes cleanly.
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    # A hangup (the terminal closed, the ssh session dropped) stops the recording as
    # SIGTERM does, with the file closed whole: killed by it, the last quarter second and
    # the counters of dropped frames were lost.  Unless started under nohup, which means
    # "go on": an ignored SIGHUP stays ignored.
    if signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN:
        signal.signal(signal.SIGHUP, on_signal)
    # A file size limit (ulimit -f) would kill us with SIGXFSZ and no word; ignored, the
    # write fails with EFBIG and the user is told (the file stays readable either way).
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    paths = paths_for_root(args.root)
    iio = None
    if args.root is not None:
        from mousedom.sources.iio_sysfs import IioPaths

        iio = IioPaths.under(args.root)
    rec = Recorder(cfg, config_text, args.output, fsync=args.fsync, stop=stop, paths=paths,
                   iio=iio)  # fmt: skip
    names = ", ".join(f"{s.name} ({describe(s)})" for s in rec.slots)
    if rec.gyro is not None:
        names += f", gyro ({rec.gyro.source.kind} {rec.gyro.node})"
    rec.say(f"record: {rec.output}: recording {names}")
    try:
        rec.run(args.duration, args.status_interval)
    except UserError:
        raise
    except Exception as e:  # a bug must not end in a traceback; the file is closed already
        log.debug("record failed", exc_info=True)
        raise UserError(
            f"{rec.output}: recording stopped by an internal error ({type(e).__name__}: {e}); "
            "the file holds everything recorded until then. Run with -v for details.",
            exit_code=1,
        ) from None
    return 0


def _check_distinct(cfg: Config, slots: list[Slot], output: str) -> None:
    """Two mice reading one device would split its reports between them (a FIFO) or
    record it twice; the output being a source would record its own bytes."""
    for i, a in enumerate(slots):
        for b in slots[i + 1 :]:
            if same_file(node_of(a), node_of(b)):
                raise UserError(
                    f"{cfg.path}: mice.{a.mouse.name} and mice.{b.mouse.name} both read "
                    f"{node_of(a)}: give each mouse its own device",
                    exit_code=1,
                )
        if same_file(output, node_of(a)):
            raise UserError(
                f"{output}: is the device of mice.{a.mouse.name}; not recording into it",
                exit_code=1,
            )


def _without_name(s: Sensor, e: Exception) -> str:
    """'left: device gone' (sources put their name first already; don't say it twice)."""
    text = str(e)
    return text if text.startswith(f"{s.name}: ") else f"{s.name}: {text}"
