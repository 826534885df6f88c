"""The daemon: one selectors loop over the sources, the tracker, the server and the signals.

Data flows one way: sources -> ``Source.read`` -> ``Tracker.push`` -> ``Tracker.poll`` ->
POSE lines -> ``Server`` queues.  The sources are read when the next window can close
(``plan_wake``), not at every report.  There is no thread: signal handlers only set a flag
and wake the loop through ``signal.set_wakeup_fd``; timers (window wake-ups, SOURCE status,
watchdog, reattaching vanished sensors) are deadlines checked after each wait.  The clock
and the source factory are injected (gpiozero style) so tests can swap them.

Degraded operation: a source that raises SourceGone (ENODEV, EOF, serial error) is marked
not live in the tracker, which then fuses the rest if the model keeps its rank and says
``ok = False`` (no motion invented) when it does not; the daemon tries to reopen it once a
second and marks it live again when it is back.
"""

from __future__ import annotations

import logging
import math
import os
import select
import selectors
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mousedom.config import Config, MouseConfig, load_config
from mousedom.errors import UserError
from mousedom.fusion.posebatch import PoseBatch
from mousedom.service.factory import make_source, source_key
from mousedom.service.protocol import (
    encode,
    encode_pose,
    error_message,
    ok_message,
    source_message,
    version_message,
)
from mousedom.service.sdnotify import Notifier, watchdog_interval
from mousedom.service.server import Client, Command, Server
from mousedom.sources.base import Source, SourceGone, SourceUnavailable

__all__ = ["Daemon", "make_source", "plan_wake"]

log = logging.getLogger(__name__)

Clock = Callable[[], float]
SourceFactory = Callable[[MouseConfig, Clock], Source]

RETRY_S = 1.0  # how often a vanished sensor is looked for again
STATUS_S = 1.0  # SOURCE broadcast period
DEFAULT_LATENCY_S = 0.003  # how late a report may reach us after its stamp (silence rule)
WAKE_SLACK_S = 0.0001  # after a report's predicted time: pipe and scheduler delays


def plan_wake(end: float, mice: list[tuple[float, float, float | None]]) -> tuple[float, float]:
    """When to read the sources for the window ending at ``end``, and when to give up.

    ``mice`` holds (report period, latency, stamp of the last report read or None) of each
    live mouse.  Reading every report as it arrives (4 mice at 1000 Hz: 4000 wakes a
    second) costs far more than the fusion.  A window can close only once every live mouse
    has reported past its end, and mice report on a steady clock (USB polling), so each
    one's first report after ``end`` is predictable from its last one: the loop sleeps until
    the latest prediction (plus a little slack) and reads everything at once.  If a mouse
    is late it waits on the descriptors, at most until ``give_up``, when the silence rule
    (no report for a period plus the latency: the mouse did not move) closes the window.
    """
    wake = give_up = end
    for period, latency, last in mice:
        give_up = max(give_up, end + latency + period)
        if last is None or last > end:
            continue
        # the first report slot strictly after ``end`` on this mouse's own clock
        wake = max(wake, last + (math.floor((end - last) / period) + 1) * period)
    return min(wake, give_up) + WAKE_SLACK_S, give_up


def _ignore(mask: int) -> None:
    """Selector callback for the sources' selector: the loop reads them itself."""


@dataclass
class Slot:
    """One configured sensor as the loop sees it."""

    index: int
    mouse: MouseConfig
    source: Source
    live: bool = False
    fd: int | None = None
    retry_at: float = 0.0
    latency: float = DEFAULT_LATENCY_S
    paced: bool = False  # no readable fd: read on the loop's own schedule (replay)
    residual_sq: float = 0.0
    residual_n: int = 0
    residual_rms: float | None = None
    announced: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.mouse.name


class Daemon:
    """Runs until stopped; ``run()`` returns the exit code."""

    def __init__(
        self,
        config: Config,
        socket_path: str,
        *,
        clock: Clock = time.monotonic,
        source_factory: SourceFactory = make_source,
        notifier: Notifier | None = None,
        handle_signals: bool = True,
        record: str | None = None,
    ) -> None:
        from mousedom.fusion.tracker import Tracker  # late: the numeric core loads only when run

        self._tracker_class = Tracker
        self.config = config
        self.clock = clock
        self.source_factory = source_factory
        self.notifier = notifier or Notifier()
        self.handle_signals = handle_signals
        self.selector = selectors.DefaultSelector()
        # The sources have a selector of their own, watched through the main one only
        # while a window waits for reports (see _plan).
        self.src_sel = selectors.DefaultSelector()
        self._watching = False
        self.server = Server(
            socket_path, config.server, self.selector, self._on_command, self._on_connect
        )
        self.slots: list[Slot] = []
        self.record_path = record
        self.recording: Any = None  # live_record.Recording while --record is on
        self.tracker: Any = None
        self.started = clock()
        self.poses = 0
        self.last_pose_t = -math.inf  # POSE times never step back, across reloads too
        self.wakes = 0  # loop iterations: what the reading policy costs (see _plan)
        self.source_reads = 0
        self.not_updated = 0
        self._stop = False
        self._reload = False
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._status_text = ""
        self._ready = False
        self._old_handlers: dict[int, Any] = {}
        self._old_wakeup: int | None = None

    # ------------------------------------------------------------------ control from outside

    def request_stop(self) -> None:
        """Ask the loop to exit (thread- and signal-safe: sets a flag, wakes the loop)."""
        self._stop = True
        self._wake()

    def request_reload(self) -> None:
        self._reload = True
        self._wake()

    def _wake(self) -> None:
        if self._wake_w < 0:
            return  # stopped already
        try:
            os.write(self._wake_w, b"\0")
        except BlockingIOError:
            pass  # the pipe is full, so the loop is going to wake anyway

    def _on_signal(self, signum: int, frame: Any) -> None:
        # Only flags here: the work happens in the loop (gpsd's rule).
        if signum == signal.SIGHUP:
            self._reload = True
        else:
            self._stop = True

    def _install_signals(self) -> None:
        self._old_wakeup = signal.set_wakeup_fd(self._wake_w, warn_on_full_buffer=False)
        for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
            self._old_handlers[sig] = signal.signal(sig, self._on_signal)

    def _restore_signals(self) -> None:
        for sig, handler in self._old_handlers.items():
            signal.signal(sig, handler)
        self._old_handlers.clear()
        if self._old_wakeup is not None:
            signal.set_wakeup_fd(self._old_wakeup)
            self._old_wakeup = None

    # ------------------------------------------------------------------ lifecycle

    def run(self) -> int:
        if self.handle_signals:
            self._install_signals()
        self.selector.register(self._wake_r, selectors.EVENT_READ, self._drain_wake)
        try:
            now = self.clock()
            self.tracker = self._tracker_class(self.config, t0=now)
            self.slots = [self._new_slot(i, m) for i, m in enumerate(self.config.mice)]
            for slot in self.slots:
                self._try_open(slot, now)
            # Nothing stamped before the start is still to come; this also gives the
            # tracker a finite frontier before the first report (its poll needs one).
            self.tracker.complete_until(now - max(s.latency for s in self.slots))
            if self.record_path:
                from mousedom.service.live_record import Recording

                kinds = [s.source.kind for s in self.slots]
                self.recording = Recording(self.record_path, self.config, kinds)
                log.info("recording the sensors' reports to %s", self.record_path)
            self.server.open()
            log.info(
                "listening on %s; watch it with: mousedom watch --socket %s",
                self.server.path,
                self.server.path,
            )
            self._status_text = self._status_line()
            self.notifier.ready(self._status_text)
            self._ready = True
            self._loop()
        finally:
            self._shutdown()
        return 0

    def _loop(self) -> None:
        now = self.clock()
        next_status = now + STATUS_S
        wd_interval = watchdog_interval()
        next_watchdog = now if wd_interval else math.inf
        while not self._stop:
            now = self.clock()
            wake_at, give_up = self._plan()
            watching = now >= wake_at
            self._watch_sources(watching)
            retry = min((s.retry_at for s in self.slots if not s.live), default=math.inf)
            deadline = min(give_up if watching else wake_at, next_status, next_watchdog, retry)
            events = self._select(deadline)
            self.wakes += 1
            for key, mask in events:
                key.data(mask)
            if self._stop:
                break
            if self._reload:
                self._reload = False
                self._do_reload()
                continue
            now = self.clock()
            if now >= wake_at:
                self._read_sources(now)
                self._publish(self.tracker.poll())
            if now >= retry:
                for slot in self.slots:
                    if not slot.live and now >= slot.retry_at:
                        self._try_open(slot, now)
            if now >= next_status:
                next_status = max(next_status + STATUS_S, now)
                self._broadcast_sources(now)
                self._update_status()
                if self.recording is not None:
                    self._record(self.recording.sync, self.tracker.frontier_time)
            if now >= next_watchdog:
                self.notifier.watchdog()
                next_watchdog = now + (wd_interval or math.inf)

    def _select(self, deadline: float) -> list[tuple[selectors.SelectorKey, int]]:
        """Wait for events until ``deadline``, to within tens of microseconds.

        epoll's timeout is in whole milliseconds (and selectors rounds it up, sometimes by a
        millisecond more than asked): waiting for a report due in 1.3 ms would wake up to
        1.7 ms late.  The epoll descriptor is itself readable when any of its descriptors
        is, so the wait is a select() on it, whose timeout has microseconds; the events are
        then collected without waiting.
        """
        remaining = deadline - self.clock()
        if remaining > 0:
            ready, _, _ = select.select([self.selector.fileno()], [], [], remaining)
            if not ready:
                return []  # timed out (the usual wake-up): nothing to collect
        return self.selector.select(0)

    def _plan(self) -> tuple[float, float]:
        end = self.tracker.frontier_time + 1.0 / self.config.rate_hz
        return plan_wake(
            end,
            [
                (1.0 / s.mouse.report_hz, s.latency, None if s.paced else s.source.health.last_t)
                for s in self.slots
                if s.live
            ],
        )

    def _watch_sources(self, on: bool) -> None:
        """Wake on readable sources only while a window is due but not closed yet."""
        if on == self._watching:
            return
        if on:
            self.selector.register(self.src_sel, selectors.EVENT_READ, _ignore)
        else:
            self.selector.unregister(self.src_sel)
        self._watching = on

    def _read_sources(self, now: float) -> None:
        for key, _ in self.src_sel.select(0):
            self._read_slot(key.data)
        for slot in self.slots:
            if slot.live and slot.paced:
                self._read_slot(slot)
        live = [slot for slot in self.slots if slot.live]
        for slot in live:
            self.tracker.complete_until(now - slot.latency, mouse=slot.index)
        if not live:
            # Nothing can report: windows close on time, as "not updated" (the pose holds).
            self.tracker.complete_until(now)

    def _shutdown(self) -> None:
        self.notifier.stopping()
        if self.tracker is not None:
            try:
                for slot in self.slots:
                    if slot.live:
                        self._read_slot(slot)
                self._publish(self.tracker.finish())
            except Exception:  # noqa: BLE001 - shutting down: log, do not mask the exit
                log.exception("flushing the last poses failed")
        if self.recording is not None:
            self._record(self.recording.close)
            self.recording = None
        self.server.close()
        for slot in self.slots:
            self._close_slot(slot)
        if self.handle_signals:
            self._restore_signals()
        self.selector.close()
        self.src_sel.close()
        os.close(self._wake_r)
        wake_w, self._wake_w = self._wake_w, -1
        os.close(wake_w)
        self.notifier.close()
        log.info("stopped after %d poses", self.poses)

    def _drain_wake(self, mask: int) -> None:
        try:
            while os.read(self._wake_r, 4096):
                pass
        except BlockingIOError:
            pass

    # ------------------------------------------------------------------ sources

    def _new_slot(self, index: int, mouse: MouseConfig) -> Slot:
        source = self.source_factory(mouse, self.clock)
        latency = float(getattr(source, "latency", DEFAULT_LATENCY_S))
        paced = callable(getattr(source, "next_due", None))
        if paced:
            latency = 0.0  # a paced source hands over every report due by ``now``
        return Slot(index=index, mouse=mouse, source=source, latency=latency, paced=paced)

    def _try_open(self, slot: Slot, now: float) -> None:
        try:
            slot.source.open()
            fd = slot.source.fileno()
            self._refuse_shared_device(slot)
        except SourceUnavailable as e:
            if slot.retry_at == 0.0 or slot.source.health.error != slot.announced.get("error"):
                log.warning("%s: not available: %s (retrying every %gs)", slot.name, e, RETRY_S)
            slot.announced["error"] = slot.source.health.error
            slot.retry_at = now + RETRY_S
            self.tracker.set_live(slot.index, False, now)
            return
        slot.fd = fd if fd is not None and fd >= 0 and not slot.paced else None
        if slot.fd is not None:
            self.src_sel.register(slot.fd, selectors.EVENT_READ, slot)
        slot.live = True
        slot.announced.pop("error", None)
        self.tracker.set_live(slot.index, True, now)
        log.info("%s: open (%s)", slot.name, slot.source.kind)
        self._sources_changed(now)

    def _refuse_shared_device(self, slot: Slot) -> None:
        """Two mice whose rules resolve to one device would each read a share of its
        reports (or, FIFOs apart, count them twice): the later one is not opened."""
        device = slot.source.identity()
        if device is None:
            return
        for other in self.slots:
            if other is not slot and other.live and other.source.identity() == device:
                slot.source.close()
                why = (
                    f"{slot.name}: {device} is already open as {other.name}: one device "
                    "cannot be two mice (make the rules in the config narrower)"
                )
                slot.source.health.connected = False
                slot.source.health.error = why
                raise SourceUnavailable(why)

    def _read_slot(self, slot: Slot) -> None:
        now = self.clock()
        self.source_reads += 1
        try:
            batches = slot.source.read(now)
        except SourceGone as e:
            self._gone(slot, now, str(e) or "device gone")
            return
        except Exception as e:  # noqa: BLE001 - one broken sensor must not stop the rest
            log.exception("%s: read failed", slot.name)
            slot.source.health.connected = False
            slot.source.health.error = f"read failed: {e}"
            self._gone(slot, now, f"read failed: {e}")
            return
        for batch in batches:
            if len(batch):
                # As the source holds them: a live read's lists go on without numpy.
                self.tracker.push(slot.index, *batch.columns())
                if self.recording is not None:
                    self._record(self.recording.motion, slot.index, batch.t, batch.dx, batch.dy)

    def _record(self, write: Callable[..., None], *args: Any) -> None:
        """A recording that cannot be written (full disk, file size limit) stops, logged;
        the fusion, which robots rely on, goes on."""
        try:
            write(*args)
        except (OSError, UserError) as e:
            log.error(
                "recording %s stopped: %s; the daemon goes on without it",
                self.recording.path,
                getattr(e, "strerror", None) or e,
            )
            try:
                self.recording.close()
            except (OSError, UserError):
                pass  # the file keeps what reached it (all but the torn last chunk)
            self.recording = None

    def _gone(self, slot: Slot, now: float, why: str) -> None:
        log.warning(
            "%s: lost (%s); going on without it, retrying every %gs", slot.name, why, RETRY_S
        )
        self._close_slot(slot)
        slot.retry_at = now + RETRY_S
        self.tracker.set_live(slot.index, False, now)
        self._sources_changed(now)

    def _close_slot(self, slot: Slot) -> None:
        if slot.fd is not None:
            try:
                self.src_sel.unregister(slot.fd)
            except (KeyError, ValueError):
                pass
            slot.fd = None
        slot.live = False
        slot.source.close()

    def _sources_changed(self, now: float) -> None:
        self._broadcast_sources(now)
        self._update_status()

    def _update_status(self) -> None:
        """systemd's STATUS= line, sent when it changes."""
        if not self._ready:
            return  # READY=1 carries the first STATUS
        status = self._status_line()
        if status != self._status_text:
            self._status_text = status
            self.notifier.status(status)

    def _status_line(self) -> str:
        live = [s.name for s in self.slots if s.live]
        gone = [s.name for s in self.slots if not s.live]
        text = f"{len(live)}/{len(self.slots)} sensors live"
        if gone:
            text += "; missing: " + ", ".join(gone)
        return text + f"; {len(self.server.clients)} clients"

    # ------------------------------------------------------------------ output

    def _publish(self, batch: PoseBatch) -> None:
        if not len(batch):
            return
        missing = tuple(s.name for s in self.slots if not s.live)
        tolerance = 0.5 / self.config.rate_hz
        # Rows of Python values (the one-window path makes them without numpy) and a POSE
        # line without a dict and json.dumps: the daemon publishes every window.
        for pose in batch.rows():
            if pose.ok:
                for slot, (rx, ry) in zip(self.slots, pose.residual, strict=False):
                    if rx - rx == 0.0 and ry - ry == 0.0:  # both finite
                        slot.residual_sq += rx * rx + ry * ry
                        slot.residual_n += 1
            line = encode_pose(
                pose.t,
                (pose.x, pose.y, pose.theta),
                (pose.vx, pose.vy, pose.omega),
                pose.cov,
                pose.used,
                pose.ok,
                missing,
            )
            self.poses += 1
            self.last_pose_t = pose.t
            self.not_updated += not pose.ok
            self.server.broadcast_pose(pose.t, line, tolerance)

    def _source_messages(self, now: float) -> list[dict[str, Any]]:
        out = []
        for slot in self.slots:
            h = slot.source.health
            if slot.residual_n:
                slot.residual_rms = (slot.residual_sq / slot.residual_n) ** 0.5
                slot.residual_sq, slot.residual_n = 0.0, 0
            out.append(
                source_message(
                    h.as_dict(),
                    live=slot.live,
                    age=None if h.last_t is None else round(now - h.last_t, 6),
                    residual=slot.residual_rms,
                    excluded=not slot.live,
                )
            )
        return out

    def _broadcast_sources(self, now: float) -> None:
        if not self.server.clients:
            return
        for msg in self._source_messages(now):
            self.server.broadcast(encode(msg))

    def _pose_now(self) -> dict[str, float]:
        x, y, theta = (float(v) for v in self.tracker.pose)
        return {"x": x, "y": y, "theta": theta}

    # ------------------------------------------------------------------ clients

    def _on_connect(self, client: Client) -> list[dict[str, Any]]:
        banner = version_message(
            self.config.rate_hz, self.config.names, client.control, self.config.model
        )
        return [banner, *self._source_messages(self.clock())]

    def _on_command(self, client: Client, cmd: Command) -> list[dict[str, Any]]:
        a = cmd.args
        if cmd.name == "reset":
            self.tracker.reset(x=a.get("x", 0.0), y=a.get("y", 0.0), theta=a.get("theta", 0.0))
            log.info("pose reset to %s by %r", self._pose_now(), client)
            return [ok_message("reset", cmd.id, pose=self._pose_now())]
        if cmd.name == "fix":
            self.tracker.fix(x=a.get("x"), y=a.get("y"), theta=a.get("theta"))
            log.info("pose fixed (%s) by %r", a, client)
            return [ok_message("fix", cmd.id, pose=self._pose_now())]
        if cmd.name == "rate":
            client.set_rate(a["hz"])
            return [ok_message("rate", cmd.id, hz=a["hz"])]
        if cmd.name == "status":
            now = self.clock()
            status = {
                "class": "STATUS",
                "uptime": round(now - self.started, 3),
                "config": self.config.path,
                "model": self.config.model,
                "integrator": self.config.integrator,
                "rate_hz": self.config.rate_hz,
                "clients": len(self.server.clients),
                "poses": self.poses,
                "not_updated": self.not_updated,
                "dropped_clients": self.server.dropped,
                "wakes": self.wakes,
                "source_reads": self.source_reads,
                "pose": self._pose_now(),
                "counts_in": np.asarray(self.tracker.counts_in).tolist(),
                "counts_out": np.asarray(self.tracker.counts_out).tolist(),
            }
            if cmd.id is not None:
                status["id"] = cmd.id
            return [status, *self._source_messages(now)]
        return [error_message(f"unhandled command {cmd.name!r}", cmd.id)]  # pragma: no cover

    # ------------------------------------------------------------------ reload

    def _do_reload(self) -> None:
        path = self.config.path
        self.notifier.reloading()
        try:
            if not path:
                raise UserError("the running config was not read from a file")
            new = load_config(path)
        except Exception as e:  # noqa: BLE001 - whatever a reload meets, the old config runs on
            if not isinstance(e, UserError):
                log.exception("reload of %s failed unexpectedly", path)
            log.error("reload failed, keeping the running config: %s", e)
            self.notifier.notify(READY=1, STATUS=f"reload failed: {e}")
            return
        now = self.clock()
        for slot in self.slots:  # what is already readable belongs to the old windows
            if slot.live:
                self._read_slot(slot)
        self._publish(self.tracker.finish())
        pose = self._pose_now()
        # finish() may have closed a window ending after now (the one holding the last
        # report): the new grid starts after it, or POSE t would step back once.
        tracker = self._tracker_class(new, t0=max(now, self.last_pose_t))
        tracker.reset(**pose)
        tracker.complete_until(now)  # what came before now went to the old tracker
        old = {s.name: s for s in self.slots}
        slots = []
        for i, mouse in enumerate(new.mice):
            prev = old.pop(mouse.name, None)
            if prev is not None and source_key(prev.mouse) == source_key(mouse):
                prev.index, prev.mouse = i, mouse
                slots.append(prev)
            else:
                if prev is not None:
                    self._close_slot(prev)
                slots.append(self._new_slot(i, mouse))
        for gone in old.values():
            self._close_slot(gone)
        if self.recording is not None and new.names != self.recording.names:
            log.warning("the mice changed: recording %s stops here", self.recording.path)
            self._record(self.recording.close)
            self.recording = None
        self.config, self.tracker, self.slots = new, tracker, slots
        for slot in slots:
            if slot.live:
                tracker.set_live(slot.index, True, now)
            else:
                self._try_open(slot, now)
        if new.server.socket and new.server.socket != self.server.path:
            log.warning("server.socket changed: takes effect at the next restart")
        self.server.apply_settings(new.server)
        log.info("reloaded %s: %d mice, model %s", path, len(new.mice), new.model)
        self.notifier.notify(READY=1, STATUS=self._status_line())
