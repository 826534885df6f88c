"""The daemon: one selectors loop over the sources, the tracker, the server and the signals.

Data flows one way: a readable source fd -> ``Source.read`` -> ``Tracker.push`` -> after
every wake ``Tracker.poll`` -> POSE lines -> ``Server`` queues.  There is no thread: signal
handlers only set a flag and wake the loop through ``signal.set_wakeup_fd``; timers
(silence rule, SOURCE status, watchdog, reattaching vanished sensors) are deadlines checked
after each ``select``.  The clock is injected (gpiozero style) so tests can drive it.

Degraded operation: a source that raises SourceGone (ENODEV, EOF, serial error) is marked
not live in the tracker, which then fuses the rest if the model keeps its rank and says
``ok = False`` (no motion invented) when it does not; the daemon tries to reopen it once a
second and marks it live again when it is back.
"""

from __future__ import annotations

import logging
import os
import selectors
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mousedom.config import Config, MouseConfig, load_config
from mousedom.errors import UserError
from mousedom.protocol import (
    encode,
    error_message,
    ok_message,
    pose_message,
    source_message,
    version_message,
)
from mousedom.sdnotify import Notifier, watchdog_interval
from mousedom.server import Client, Command, Server
from mousedom.sources.base import Source, SourceGone, SourceUnavailable

log = logging.getLogger(__name__)

Clock = Callable[[], float]
SourceFactory = Callable[[MouseConfig, Clock], Source]

RETRY_S = 1.0  # how often a vanished sensor is looked for again
STATUS_S = 1.0  # SOURCE broadcast period
DEFAULT_LATENCY_S = 0.003  # how late a report may reach us after its stamp (silence rule)


def make_source(mouse: MouseConfig, clock: Clock = time.monotonic, loop: bool = False) -> Source:
    """The backend a mouse's config asks for: evdev, serial ADNS-3080 or replay.

    A replay is paced on ``clock`` (real time) and starts again at its end with ``loop``.
    """
    try:
        if mouse.evdev is not None:
            from mousedom.sources.evdev import EvdevSource

            return EvdevSource(mouse)
        if mouse.serial is not None:
            from mousedom.sources.adns import AdnsSource

            return AdnsSource(mouse)
        if mouse.replay is not None:
            from mousedom.sources.replay import ReplaySource

            return ReplaySource(
                mouse.name, mouse.replay, device=mouse.replay_device, loop=loop, clock=clock
            )
    except ImportError as e:
        raise UserError(f"mice.{mouse.name}: this build has no such source ({e})") from None
    raise UserError(f"mice.{mouse.name}: says nowhere where the mouse comes from")


def _source_key(mouse: MouseConfig) -> tuple[Any, ...]:
    """What identifies a mouse's device: when it changes on reload, the source is reopened."""
    return (mouse.evdev, mouse.serial, mouse.replay, mouse.replay_device)


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
        coalesce_s: float = 0.0,
        on_pose: Callable[[float, float], None] | None = None,
    ) -> None:
        from mousedom.tracker import Tracker  # late: the numeric core loads only when run

        self._tracker_class = Tracker
        self.config = config
        self.clock = clock
        self.source_factory = source_factory
        self.notifier = notifier or Notifier()
        self.handle_signals = handle_signals
        self.coalesce_s = coalesce_s
        self.on_pose = on_pose  # bench hook: (pose t, time its line was queued)
        self.selector = selectors.DefaultSelector()
        self.server = Server(
            socket_path, config.server, self.selector, self._on_command, self._on_connect
        )
        self.slots: list[Slot] = []
        self.tracker: Any = None
        self.started = clock()
        self.poses = 0
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
        tick = 1.0 / self.config.rate_hz
        now = self.clock()
        next_tick = now + tick
        next_status = now + STATUS_S
        wd_interval = watchdog_interval()
        next_watchdog = now if wd_interval else float("inf")
        polled = [s for s in self.slots if s.fd is None]
        last_wake = now
        while not self._stop:
            now = self.clock()
            deadline = min(next_tick, next_status, next_watchdog, self._next_due(polled))
            if self.coalesce_s:
                # Let a few reports pile up per wake: far fewer syscalls at 4 x 1000 Hz,
                # for at most coalesce_s of extra latency.
                gap = last_wake + self.coalesce_s - now
                if gap > 0:
                    time.sleep(gap)
            events = self.selector.select(max(0.0, deadline - self.clock()))
            now = last_wake = self.clock()
            for key, mask in events:
                key.data(mask)
            if self._stop:
                break
            if self._reload:
                self._reload = False
                self._do_reload()
                tick = 1.0 / self.config.rate_hz
                polled = [s for s in self.slots if s.fd is None]
            now = self.clock()
            for slot in polled:
                if slot.live and slot.fd is None:
                    self._read_slot(slot)
            if now >= next_tick:
                next_tick = max(next_tick + tick, now)
                for slot in self.slots:
                    if slot.live:
                        self.tracker.complete_until(now - slot.latency, mouse=slot.index)
                    elif now >= slot.retry_at:
                        self._try_open(slot, now)
                        polled = [s for s in self.slots if s.fd is None]
            self._publish(self.tracker.poll())
            if now >= next_status:
                next_status = max(next_status + STATUS_S, now)
                self._broadcast_sources(now)
            if now >= next_watchdog:
                self.notifier.watchdog()
                next_watchdog = now + (wd_interval or float("inf"))

    @staticmethod
    def _next_due(polled: list[Slot]) -> float:
        """When the next report of a paced (fd-less) source is due."""
        due = float("inf")
        for slot in polled:
            if slot.live and slot.paced:
                nxt = slot.source.next_due()  # type: ignore[attr-defined]
                if nxt is not None:
                    due = min(due, nxt)
        return due

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
        self.server.close()
        for slot in self.slots:
            self._close_slot(slot)
        if self.handle_signals:
            self._restore_signals()
        self.selector.close()
        os.close(self._wake_r)
        os.close(self._wake_w)
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
        except SourceUnavailable as e:
            if slot.retry_at == 0.0 or slot.source.health.error != slot.announced.get("error"):
                log.warning("%s: not available: %s (retrying every %gs)", slot.name, e, RETRY_S)
            slot.announced["error"] = slot.source.health.error
            slot.retry_at = now + RETRY_S
            self.tracker.set_live(slot.index, False, now)
            return
        slot.fd = fd if fd is not None and fd >= 0 and not slot.paced else None
        if slot.fd is not None:
            self.selector.register(slot.fd, selectors.EVENT_READ, self._reader(slot))
        slot.live = True
        slot.announced.pop("error", None)
        self.tracker.set_live(slot.index, True, now)
        log.info("%s: open (%s)", slot.name, slot.source.kind)
        self._sources_changed(now)

    def _reader(self, slot: Slot) -> Callable[[int], None]:
        return lambda mask: self._read_slot(slot)

    def _read_slot(self, slot: Slot) -> None:
        now = self.clock()
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
                self.tracker.push(slot.index, batch.t, batch.dx, batch.dy)

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
                self.selector.unregister(slot.fd)
            except (KeyError, ValueError):
                pass
            slot.fd = None
        slot.live = False
        slot.source.close()

    def _sources_changed(self, now: float) -> None:
        self._broadcast_sources(now)
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

    def _publish(self, batch: Any) -> None:
        n = len(batch)
        if not n:
            return
        missing = [s.name for s in self.slots if not s.live]
        tolerance = 0.5 / self.config.rate_hz
        res = np.asarray(batch.residual, dtype=float)
        if res.size:
            sq = np.nansum(res**2, axis=2)  # (n, N): squared norm per window per mouse
            valid = np.isfinite(res).all(axis=2) & np.asarray(batch.ok)[:, None]
            for slot in self.slots:
                if slot.index < sq.shape[1]:
                    slot.residual_sq += float(sq[valid[:, slot.index], slot.index].sum())
                    slot.residual_n += int(valid[:, slot.index].sum())
        for i in range(n):
            ok = bool(batch.ok[i])
            msg = pose_message(
                batch.t[i],
                (batch.x[i], batch.y[i], batch.theta[i]),
                (batch.vx[i], batch.vy[i], batch.omega[i]),
                batch.cov[i],
                batch.used[i],
                ok,
                missing,
            )
            self.poses += 1
            self.not_updated += not ok
            self.server.broadcast_pose(float(batch.t[i]), encode(msg), tolerance)
            if self.on_pose is not None:
                self.on_pose(float(batch.t[i]), time.monotonic())

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
        except UserError as e:
            log.error("reload failed, keeping the running config: %s", e)
            self.notifier.notify(READY=1, STATUS=f"reload failed: {e}")
            return
        now = self.clock()
        for slot in self.slots:  # what is already readable belongs to the old windows
            if slot.live:
                self._read_slot(slot)
        self._publish(self.tracker.finish())
        pose = self._pose_now()
        tracker = self._tracker_class(new, t0=now)
        tracker.reset(**pose)
        tracker.complete_until(now)  # what came before now went to the old tracker
        old = {s.name: s for s in self.slots}
        slots = []
        for i, mouse in enumerate(new.mice):
            prev = old.pop(mouse.name, None)
            if prev is not None and _source_key(prev.mouse) == _source_key(mouse):
                prev.index, prev.mouse = i, mouse
                slots.append(prev)
            else:
                if prev is not None:
                    self._close_slot(prev)
                slots.append(self._new_slot(i, mouse))
        for gone in old.values():
            self._close_slot(gone)
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
