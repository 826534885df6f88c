"""The daemon: one selectors loop over the sources, the tracker, the server and the signals.

Data flows one way: sources -> ``Sensors.read`` -> ``Tracker.push`` -> ``Tracker.poll`` ->
``Publisher.publish`` -> the outputs (the socket's clients first).  The sources are read
when the next window can close (``plan_wake``), not at every report; a window still open
then waits for the mice it waits for (``holding``), not for any report.  There is no thread:
signal handlers only set a flag and wake the loop through ``signal.set_wakeup_fd``; timers
(window wake-ups, SOURCE status, watchdog, reattaching vanished sensors) are deadlines
checked after each wait.  The clock and the source factory are injected (gpiozero style)
so tests can swap them.

The daemon is the composition root: it owns the loop, the lifecycle and the signals, and
wires parts that own their state (docs/architecture.md): the running config and tracker
(running.Running, which a reload swaps), the sensors (slots.Sensors), what is sent
(publish.Publisher, to output.Output destinations), what clients may ask
(control.ClientCommands) and SIGHUP (reload.Reloader).

Degraded operation: a source that raises SourceGone (ENODEV, EOF, serial error) is marked
not live in the tracker, which then fuses the rest if the model keeps its rank and says
``ok = False`` (no motion invented) when it does not; the daemon tries to reopen it once a
second and marks it live again when it is back.
"""

from __future__ import annotations

import gc
import logging
import math
import os
import select
import selectors
import signal
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from mousedom import core, invocation
from mousedom.config import Config
from mousedom.service.control import ClientCommands
from mousedom.service.factory import make_source
from mousedom.service.output import Output
from mousedom.service.publish import Outputs, Publisher, SocketOutput
from mousedom.service.reload import Reloader
from mousedom.service.running import Running
from mousedom.service.sdnotify import Notifier, watchdog_interval
from mousedom.service.server import Client, Command, Server
from mousedom.service.slots import Sensors, Slot
from mousedom.service.socketfile import default_socket_path
from mousedom.service.wake import WAKE_SLACK_S, holding, plan_wake
from mousedom.sources.base import Source

if TYPE_CHECKING:
    from mousedom.fusion.tracker import Tracker
    from mousedom.service.live_record import Recording
    from mousedom.service.metrics import MetricsExporter, WindowCpu

__all__ = ["WAKE_SLACK_S", "Daemon", "Slot", "make_source", "plan_wake"]

log = logging.getLogger(__name__)

Clock = Callable[[], float]
SourceFactory = Callable[[Any, Clock], Source]  # (a mouse's or the gyro's config, clock)

STATUS_S = 1.0  # SOURCE broadcast period
# The most a wake spends on clients' events before the sources get their turn: at 50 Hz a
# window is 20 ms, and a healthy client's POSE may be late by at most this much per wake.
CLIENT_BUDGET_S = 0.004
FD_SETSIZE = 1024  # select() takes no descriptor numbered beyond


def freeze_heap() -> None:
    """Collect, then keep every object alive out of the collector's sight (``gc.freeze``).

    What the daemon builds at start (some 30,000 objects: modules, the config, the
    tracker's tables) stays alive.  A full collection scans all of it, 6-10 ms here, and
    Python runs one on its own now and then (3 in 200 s of 4 mice at 1 kHz), between some
    window's last report and its POSE.  Frozen, those objects are not scanned again.
    Unfrozen first: what a reload replaced is collected with the rest, not kept for good.
    """
    gc.unfreeze()
    gc.collect()
    gc.freeze()


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
        outputs: list[Output] | None = None,
        freeze_heap: bool = False,
        pending_reload: Callable[[], bool] | None = None,
    ) -> None:
        """``freeze_heap``: the process is the daemon's own (``mousedom run``): its heap is
        frozen at start and after each reload (``freeze_heap``, above)."""
        # late: the numeric core loads when a daemon is made, not with the CLI
        from mousedom.fusion.tracker import Tracker

        self.clock = clock
        self.source_factory = source_factory
        self.notifier = notifier or Notifier()
        self.handle_signals = handle_signals
        self.freeze_heap = freeze_heap
        # a SIGHUP that came before our handlers (mousedom.hangup): reloaded once they are in
        self.pending_reload = pending_reload
        self.selector = selectors.DefaultSelector()
        self.server = Server(
            socket_path, config.server, self.selector, self._on_command, self._on_connect
        )
        # The clients' share of a wake ends at this time (CLIENT_BUDGET_S after the wake;
        # no end outside the loop's handling of client events), checked by the server
        # before each line it answers.
        self._budget_end = math.inf
        self.server.over_budget = self._over_budget
        self.record_path = record
        self._recording: Recording | None = None
        # Where else each window goes (ROS 2 over DDS, an MCAP file, Foxglove); the
        # recording and the metrics join them when run() starts them.
        self.outputs = Outputs(outputs or ())
        # outputs.metrics: the Prometheus endpoint (metrics.py), started by run(), and the
        # CPU clock around each window's work (None: metrics off, nothing is timed)
        self.metrics: MetricsExporter | None = None
        self.window_cpu: WindowCpu | None = None
        # The parts, around the running config and its tracker (whose windows start
        # again when run() starts the loop)
        self.running = Running(config, Tracker(config, t0=clock()))
        self.sensors = Sensors(
            self.running, clock, source_factory, self.outputs, self._sources_changed
        )
        self.publisher = Publisher(
            self.running,
            self.sensors,
            SocketOutput(self.server, self.sensors, self.running),
            self.outputs,
            clock,
        )
        self.commands = ClientCommands(self.running, clock, self.publisher, self)
        self.reloader = Reloader(
            self.running,
            clock,
            self.notifier,
            self.sensors,
            self.publisher,
            self.server,
            Tracker,
            self._restart_only,
            self.commands.version,
        )
        self.started = clock()
        self.wakes = 0  # loop iterations: what the reading policy costs (see _plan)
        self._stop = False
        self._reload = False
        # While a window is due and not closed yet, what the loop also waits for (_plan):
        # any source readable (the sources' epoll, ``_watch``), or each of the mice the
        # window waits for readable or final by time (``_waited``: descriptor, final)
        self._watch: list[int] = []
        self._waited: list[tuple[int, float]] = []
        self._read_at = -math.inf  # the last read of every source (_window)
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        # Another thread's request_stop writes to _wake_w while the loop may be closing it:
        # without the lock the write can hit a closed descriptor (EBADF), or one the number
        # was given to since.  Reentrant: a signal handler in the loop's thread may ask too.
        self._wake_lock = threading.RLock()
        self._status_text = ""
        self._ready = False
        self._old_handlers: dict[int, Any] = {}
        self._old_wakeup: int | None = None

    # ------------------------------------------------------------------ what others read

    @property
    def config(self) -> Config:
        return self.running.config

    @property
    def tracker(self) -> Tracker:
        return self.running.tracker

    @property
    def poses(self) -> int:
        return self.publisher.poses

    @property
    def not_updated(self) -> int:
        return self.publisher.not_updated

    @property
    def source_reads(self) -> int:
        return self.sensors.reads

    @property
    def recording(self) -> Recording | None:
        """The live recording (--record) while it runs: a failure or a reload with other
        mice stops it."""
        rec = self._recording
        return rec if rec is not None and rec in self.outputs.items else None

    @property
    def clients(self) -> int:
        return len(self.server.clients)

    @property
    def dropped_clients(self) -> int:
        return self.server.dropped

    # ------------------------------------------------------------------ control from outside

    def request_stop(self) -> None:
        """Ask the loop to exit (thread- and signal-safe: sets a flag, wakes the loop)."""
        self._stop = True
        self._wake()

    def request_reload(self) -> None:
        self._reload = True
        self._wake()

    def _wake(self) -> None:
        with self._wake_lock:
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
        if self.pending_reload is not None and self.pending_reload():
            self._reload = True  # (after ours are in: no SIGHUP falls between)

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
            self._start()
            self._loop()
        finally:
            self._shutdown()
        return 0

    def _start(self) -> None:
        """The windows start now; the sensors open; the recording, the metrics and the
        socket start (in that order: a taken port or socket stops us before clients come)."""
        now = self.clock()
        config = self.config
        self.running.replace(config, self.reloader.tracker_class(config, t0=now))
        self.sensors.start(now)
        # Nothing stamped before the start is still to come; this also gives the
        # tracker a finite frontier before the first report (its poll needs one).
        self.tracker.complete_until(now - self.sensors.max_latency())
        if self.record_path:
            from mousedom.service.live_record import Recording

            # (every sensor's: the mice's, then the gyro's, whose samples it keeps too)
            kinds = [s.source.kind for s in self.sensors.slots]
            self._recording = Recording(self.record_path, config, kinds, self.tracker.t0)
            self.outputs.add(self._recording)
            log.info("recording the sensors' reports to %s", self.record_path)
        if config.metrics is not None:
            from mousedom.service.metrics import MetricsExporter

            self.metrics = MetricsExporter(config.metrics, self)
            self.window_cpu = self.metrics.window_cpu
            self.outputs.add(self.metrics)
        if self.freeze_heap:
            freeze_heap()  # (before the socket opens: a client finds it done)
        self.server.open()
        log.info("core: %s", core.NAME)
        log.info(
            "listening on %s; watch it with: %s",
            self.server.path,
            invocation.command("watch", "--socket", self.server.path),
        )
        self._status_text = self._status_line()
        self.notifier.ready(self._status_text)
        self._ready = True

    def _loop(self) -> None:
        now = self.clock()
        next_status = now + STATUS_S
        wd_interval = watchdog_interval()
        next_watchdog = now if wd_interval else math.inf
        sensors, publisher, server = self.sensors, self.publisher, self.server
        while not self._stop:
            now = self.clock()
            wake_at, give_up = self._plan(now)
            watching = now >= wake_at  # (see _select)
            # a sensor to look for again, or none (inf)
            retry = sensors.next_retry() if sensors.missing_names else math.inf
            deadline = min(give_up if watching else wake_at, next_status, next_watchdog, retry)
            if server.backlog and server.backlog_ready():
                deadline = now  # lines read and not yet answered: their turn comes now
            events = self._select(deadline)
            self.wakes += 1
            server.tick(self.clock())
            if len(events) == 1 and not server.backlog:
                # The usual wake: one event, nothing owed. Its budget too: one client's
                # read of 16 status lines took up to 5.7 ms without it.
                self._budget_end = self.clock() + CLIENT_BUDGET_S
                try:
                    events[0][0].data(events[0][1])
                finally:
                    self._budget_end = math.inf
            elif events or server.backlog:
                self._dispatch(events)
            if self._stop:
                break
            if self._reload:
                self._reload = False
                self.reloader.reload()
                if self.freeze_heap:
                    freeze_heap()
                sensors, publisher = self.sensors, self.publisher
                continue
            now = self.clock()
            if now >= wake_at:
                self._window(now)
            if now >= retry:
                sensors.retry(now)
            if now >= next_status:
                next_status = max(next_status + STATUS_S, now)
                publisher.every_second(now)
                self._update_status()
            if now >= next_watchdog:
                self.notifier.watchdog()
                next_watchdog = now + (wd_interval or math.inf)

    def _window(self, now: float) -> None:
        """Read the sensors, close the windows due, send them (timed for the metrics)."""
        timing = self.window_cpu
        if timing is not None:
            timing.start(self.publisher.poses)
        self.sensors.read_due(now)
        self._read_at = now
        tracker = self.running.tracker
        self.publisher.publish(tracker.poll(defer_learning=True, one_by_one=True))
        tracker.settle()  # a learners' block end: after the POSE is out (Tracker.settle)
        self.publisher.log_scales()  # (what that learning renewed)
        if timing is not None:
            timing.stop(self.publisher.poses)

    def _dispatch(self, events: list[tuple[selectors.SelectorKey, int]]) -> None:
        """Handle a wake's events within CLIENT_BUDGET_S, starting at a place that turns
        with each wake, so that no client (or flood of connections) can keep the loop from
        the next window nor always be served before another.  What is left is still ready
        (epoll is level-triggered) and comes back at the next wake."""
        end = self._budget_end = self.clock() + CLIENT_BUDGET_S
        clock, server = self.clock, self.server
        # (checked before each line a client's turn answers: the answers to one client's
        # 16 status lines took 5 ms, sixteen such clients 90 ms in one wake)
        try:
            # Lines read earlier and not yet answered first: their sockets may not wake us
            # again.
            server.serve_backlog()
            n = len(events)
            start = self.wakes % n if n else 0
            for k in range(n):
                if clock() > end:
                    return
                key, mask = events[(start + k) % n]
                key.data(mask)
        finally:
            self._budget_end = math.inf

    def _over_budget(self) -> bool:
        return self.clock() > self._budget_end

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
            # While a window waits for reports, the sources' own epoll descriptor (or the
            # descriptors of the mice it waits for) is waited on too: one select on
            # both, no epoll_ctl per window to add and remove it from the main one.
            if self._waited:
                ready = [main] if self._wait_each(main, deadline) else []
            else:
                ready, _, _ = select.select([main, *self._watch], [], [], remaining)
            if main not in ready:
                return []  # timed out, or a source is readable: nothing to dispatch
        return self.selector.select(0)

    def _wait_each(self, main: int, deadline: float) -> bool:
        """Wait until each mouse in ``_waited`` is readable or final by time, or until
        ``deadline``: no read can close the window before (``holding``), and a descriptor
        stays readable until it is read.  Whether ``main`` (the loop's own descriptors)
        is ready."""
        waited = self._waited
        while True:
            now = self.clock()
            waited = [(fd, final) for fd, final in waited if now < final]
            if not waited or now >= deadline:
                return False
            until = min(deadline, *(final for _, final in waited))
            ready, _, _ = select.select([main, *(fd for fd, _ in waited)], [], [], until - now)
            if main in ready:
                return True
            waited = [(fd, final) for fd, final in waited if fd not in ready]

    def _plan(self, now: float) -> tuple[float, float]:
        """When to wake for the next window and when to give up on its reports
        (``plan_wake``); where the wake is due, what to watch meanwhile: each of the
        mice the window waits for (``_waited``, ``holding``: their next reports, for a
        bounded time), else any source (``_watch``)."""
        running, planned = self.running, self.sensors.plan
        end = running.tracker.frontier_time + 1.0 / running.config.rate_hz
        mice = [
            (p, lat, None, None) if h is None else (p, lat, h.last_t, h.last_gap)
            for p, lat, h, _ in planned
        ]  # fmt: skip
        bridge = running.config.late_report_s
        wake_at, give_up = plan_wake(end, mice, bridge)
        self._watch, self._waited = [], []
        if now < wake_at:
            return wake_at, give_up
        waited, alone_until = holding(end, mice, bridge, now, self._read_at)
        each = [(fd, w.final) for w in waited if (fd := planned[w.mouse].fd) is not None]
        # none paced or probed, and none select() cannot take (a mouse reopened while many
        # clients are connected may get a descriptor past FD_SETSIZE)
        usable = len(each) == len(waited) and all(fd < FD_SETSIZE for fd, _ in each)
        if waited and now < alone_until and usable:
            self._waited = each
            return wake_at, min(give_up, alone_until)
        self._watch = [self.sensors.fileno()]
        return wake_at, give_up

    # ------------------------------------------------------------------ the parts' callbacks

    def _on_connect(self, client: Client) -> list[dict[str, Any]]:
        return self.commands.on_connect(client)

    def _on_command(self, client: Client, cmd: Command) -> list[dict[str, Any]]:
        return self.commands.on_command(client, cmd)

    def _sources_changed(self, now: float) -> None:
        """A sensor came or went: the clients hear of it now, and systemd's status."""
        if self.server.clients:
            self.publisher.send_sources(now)
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
        return self.sensors.status_line(len(self.server.clients))

    def _restart_only(self, old: Config, new: Config) -> list[str]:
        """What of a reloaded config takes effect only at a restart, where it changed from
        the config it replaces (``old``)."""
        changed = []
        # The config's own value against its previous one: the path in use may be
        # `run --socket`'s, which no config names.  A change to the path in use (written
        # into the config now, say) changes nothing at a restart either.
        socket = new.server.socket
        if socket != old.server.socket and (socket or default_socket_path()) != self.server.path:
            changed.append("server.socket")
        # (not warned when the file has none: `run --metrics` may have turned it on)
        running = self.metrics.cfg if self.metrics is not None else None
        if new.metrics is not None and new.metrics != running:
            changed.append("outputs.metrics")
        # the ROS 2 output and the Foxglove view are made at start, as the metrics are
        # (`run --ros2` / `--foxglove` may have turned them on: compared where the file
        # has them, against the file's before)
        for key in ("ros2", "foxglove"):
            if getattr(new, key) is not None and getattr(new, key) != getattr(old, key):
                changed.append(f"outputs.{key}")
        return changed

    # ------------------------------------------------------------------ the end

    def _shutdown(self) -> None:
        self.notifier.stopping()
        try:
            self.reloader.finish_windows()
            # The outputs' last checkpoint (the recording's sync): every window published is
            # in it, the idle ones after the last report too, which the last second's
            # checkpoint had not reached (replay of the recording lacked them).
            if self.outputs:
                self.outputs.checkpoint(self.running.tracker.frontier_time)
        except Exception:  # noqa: BLE001 - shutting down: log, do not mask the exit
            log.exception("flushing the last poses failed")
        # The outputs the daemon started (the recording, the metrics); the caller's own
        # (DDS, MCAP, Foxglove) are the caller's to close.
        for out in list(self.outputs.items):
            if out is self.metrics or out is self._recording:
                self._close_output(out)
        self.metrics = self.window_cpu = None
        self.server.close()
        self.sensors.close()
        if self.handle_signals:
            self._restore_signals()
        self.selector.close()
        with self._wake_lock:  # the write end first: a write after it is skipped, not EPIPE
            wake_w, self._wake_w = self._wake_w, -1
            os.close(wake_w)
        os.close(self._wake_r)
        self.notifier.close()
        log.info("stopped after %d poses", self.publisher.poses)

    def _close_output(self, out: Output) -> None:
        try:
            self.outputs.remove(out)
        except Exception as e:  # noqa: BLE001 - as any output: logged, the stop goes on
            log.error("%s: %s", out, getattr(e, "strerror", None) or e)

    def _drain_wake(self, mask: int) -> None:
        try:
            while os.read(self._wake_r, 4096):
                pass
        except BlockingIOError:
            pass
