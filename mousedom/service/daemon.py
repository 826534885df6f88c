"""The daemon: one selectors loop over the sources, the tracker, the server and the signals.

Data flows one way: sources -> ``Source.read`` -> ``Tracker.push`` -> ``Tracker.poll`` ->
POSE lines -> ``Server`` queues.  The sources are read when the next window can close
(``plan_wake``), not at every report.  There is no thread: signal handlers only set a flag
and wake the loop through ``signal.set_wakeup_fd``; timers (window wake-ups, SOURCE status,
watchdog, reattaching vanished sensors) are deadlines checked after each wait.  The clock
and the source factory are injected (gpiozero style) so tests can swap them.

One idea per file: this one holds the loop and the lifecycle; the sensors are
``slots.SensorSlots``, what is sent ``publish.Publisher``, what clients may ask
``control.ClientCommands``, SIGHUP ``reload.Reloader``, and when to read ``wake.plan_wake``.

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
from typing import Any

from mousedom import invocation
from mousedom.config import Config, MouseConfig
from mousedom.service.control import ClientCommands
from mousedom.service.factory import make_source
from mousedom.service.publish import Publisher
from mousedom.service.reload import Reloader
from mousedom.service.scales import ScaleLog
from mousedom.service.sdnotify import Notifier, watchdog_interval
from mousedom.service.server import Server
from mousedom.service.slots import SensorSlots, Slot
from mousedom.service.wake import WAKE_SLACK_S, plan_wake
from mousedom.sources.base import Source

__all__ = ["WAKE_SLACK_S", "Daemon", "Slot", "make_source", "plan_wake"]

log = logging.getLogger(__name__)

Clock = Callable[[], float]
SourceFactory = Callable[[MouseConfig, Clock], Source]

STATUS_S = 1.0  # SOURCE broadcast period
# The most a wake spends on clients' events before the sources get their turn: at 50 Hz a
# window is 20 ms, and a healthy client's POSE may be late by at most this much per wake.
CLIENT_BUDGET_S = 0.004


class Daemon(SensorSlots, Publisher, ClientCommands, Reloader):
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
        outputs: list | None = None,
    ) -> None:
        from mousedom.fusion.tracker import Tracker  # late: the numeric core loads only when run

        self._tracker_class = Tracker
        self.config = config
        self.clock = clock
        self.source_factory = source_factory
        self.notifier = notifier or Notifier()
        self.handle_signals = handle_signals
        self.selector = selectors.DefaultSelector()
        # The sources have an epoll of their own, waited on with the main one only while a
        # window waits for reports (see _select).  A bare epoll, not a selector: it is
        # asked once per window, and selectors' Python layer cost more than the syscall.
        self.src_poll = select.epoll()
        self.slot_by_fd: dict[int, Slot] = {}
        self._watching = False  # wake on readable sources (a window is due, not closed yet)
        self.server = Server(
            socket_path, config.server, self.selector, self._on_command, self._on_connect
        )
        self.slots: list[Slot] = []
        self.missing_names: tuple[str, ...] = ()  # see _live_changed
        self.plan_slots: list[tuple] = []
        self._names_by_state: dict[tuple, tuple] = {}
        # Each window's residuals and the last window's health, folded into the slots
        # when a SOURCE message is made (see Publisher._fold_window_health).
        self._window_residuals: list = []
        self._last_health: tuple | None = None
        # The learnt scales' warnings, logged when they appear, persist or end (scales.py)
        self.scale_log = ScaleLog()
        self.record_path = record
        self.recording: Any = None  # live_record.Recording while --record is on
        # Where else each window goes (ROS 2 over DDS, an MCAP file): publish(row),
        # moved(before, after), sources(messages, t), close() (see publish.py)
        self.outputs: list[Any] = list(outputs or ())
        # outputs.metrics: the Prometheus endpoint (metrics.py), started by run(), and the
        # CPU clock around each window's work (None: metrics off, nothing is timed)
        self.metrics: Any = None
        self.window_cpu: Any = None
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
            self.server.refuse_if_taken()  # before any sensor is opened (and grabbed)
            now = self.clock()
            self.tracker = self._tracker_class(self.config, t0=now)
            self.slots = [self._new_slot(i, m) for i, m in enumerate(self.config.mice)]
            self._live_changed()
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
            if self.config.metrics is not None:  # before the socket: a taken port stops us
                from mousedom.service.metrics import MetricsExporter

                self.metrics = MetricsExporter(self.config.metrics, self)
                self.window_cpu = self.metrics.window_cpu
            self.server.open()
            log.info(
                "listening on %s; watch it with: %s",
                self.server.path,
                invocation.command("watch", "--socket", self.server.path),
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
            watching = self._watching = now >= wake_at  # (see _select)
            retry = math.inf
            if self.missing_names:  # a sensor to look for again
                retry = min(s.retry_at for s in self.slots if not s.live)
            deadline = min(give_up if watching else wake_at, next_status, next_watchdog, retry)
            events = self._select(deadline)
            self.wakes += 1
            server = self.server
            server.tick(self.clock())
            if len(events) == 1 and not server.backlog:
                events[0][0].data(events[0][1])  # the usual wake: one event, nothing owed
            elif events or server.backlog:
                self._dispatch(events)
            if self._stop:
                break
            if self._reload:
                self._reload = False
                self._do_reload()
                continue
            now = self.clock()
            if now >= wake_at:
                timing = self.window_cpu
                if timing is not None:
                    timing.start(self.poses)
                self._read_sources(now)
                self._publish(self.tracker.poll())
                if timing is not None:
                    timing.stop(self.poses)
            if now >= retry:
                for slot in self.slots:
                    if not slot.live and now >= slot.retry_at:
                        self._try_open(slot, now)
            if now >= next_status:
                next_status = max(next_status + STATUS_S, now)
                self._broadcast_sources(now)
                self._output_sources(now)
                self._update_status()
                if self.recording is not None:
                    self._record(self.recording.sync, self.tracker.frontier_time)
            if now >= next_watchdog:
                self.notifier.watchdog()
                next_watchdog = now + (wd_interval or math.inf)

    def _dispatch(self, events: list[tuple[selectors.SelectorKey, int]]) -> None:
        """Handle a wake's events within CLIENT_BUDGET_S, starting at a place that turns
        with each wake, so that no client (or flood of connections) can keep the loop from
        the next window nor always be served before another.  What is left is still ready
        (epoll is level-triggered) and comes back at the next wake."""
        end = self.clock() + CLIENT_BUDGET_S
        # Lines read earlier and not yet answered first: their sockets may not wake us again.
        self.server.serve_backlog()
        n = len(events)
        start = self.wakes % n if n else 0
        for k in range(n):
            key, mask = events[(start + k) % n]
            key.data(mask)
            if self.clock() > end:
                return

    def _select(self, deadline: float) -> list[tuple[selectors.SelectorKey, int]]:
        """Wait for events until ``deadline``, to within tens of microseconds.

        epoll's timeout is in whole milliseconds (and selectors rounds it up, sometimes by a
        millisecond more than asked): waiting for a report due in 1.3 ms would wake up to
        1.7 ms late.  The epoll descriptor is itself readable when any of its descriptors
        is, so the wait is a select() on it, whose timeout has microseconds; the events are
        then collected without waiting.
        """
        remaining = deadline - self.clock()
        main = self.selector.fileno()
        if remaining > 0:
            # While a window waits for reports, the sources' own epoll descriptor is
            # waited on too: one select on both, no epoll_ctl per window to add and
            # remove it from the main one.
            fds = [main, self.src_poll.fileno()] if self._watching else [main]
            ready, _, _ = select.select(fds, [], [], remaining)
            if main not in ready:
                return []  # timed out, or a source is readable: nothing to dispatch
        return self.selector.select(0)

    def _plan(self) -> tuple[float, float]:
        end = self.tracker.frontier_time + 1.0 / self.config.rate_hz
        return plan_wake(
            end, [(period, latency, h and h.last_t) for period, latency, h in self.plan_slots]
        )

    def _read_sources(self, now: float) -> None:
        for fd, _ in self.src_poll.poll(0):
            slot = self.slot_by_fd.get(fd)
            if slot is not None:
                self._read_slot(slot, now)
        completes = []
        for slot in self.slots:
            if slot.live and slot.paced:
                self._read_slot(slot, now)
            if slot.live:  # (a paced read may have lost it)
                completes.append((slot.index, now - slot.latency))
        if completes:
            self.tracker.complete_each(completes)
        else:
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
        if self.metrics is not None:
            self.metrics.close()
            self.metrics = self.window_cpu = None
        self.server.close()
        for slot in self.slots:
            self._close_slot(slot)
        if self.handle_signals:
            self._restore_signals()
        self.selector.close()
        self.src_poll.close()
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
