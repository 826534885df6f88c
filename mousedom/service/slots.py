"""The daemon's sensors: one slot per configured mouse, opened, read, lost and retried.

A mixin of ``Daemon`` (one idea per file; the state is the daemon's own): it uses
``self.slots``, ``self.src_poll``, ``self.slot_by_fd``, ``self.tracker``, ``self.recording``,
``self.clock``, ``self.source_factory`` and ``self.notifier``, and calls
``self._broadcast_sources``.
"""

from __future__ import annotations

import logging
import select
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from mousedom.config import MouseConfig
from mousedom.errors import UserError
from mousedom.sources.base import Source, SourceGone, SourceUnavailable

log = logging.getLogger(__name__)

RETRY_S = 1.0  # how often a vanished sensor is looked for again
DEFAULT_LATENCY_S = 0.003  # how late a report may reach us after its stamp (silence rule)


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
    health_state: int = 0  # robust.STATES index after the last window
    health_reason: int = 0  # robust.REASONS index
    announced: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.mouse.name


class SensorSlots:
    """Opening, reading and losing the configured sensors (see the module docstring)."""

    slots: list[Slot]

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
            self.src_poll.register(slot.fd, select.EPOLLIN)
            self.slot_by_fd[slot.fd] = slot
        slot.live = True
        self._live_changed()
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

    def _read_slot(self, slot: Slot, now: float | None = None) -> None:
        if now is None:
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
            t, dx, dy = batch.columns()
            if len(t):
                # As the source holds them: a live read's lists go on without numpy.
                self.tracker.push(slot.index, t, dx, dy)
                if batch.quality is not None:
                    self.tracker.push_quality(slot.index, *batch.quality)
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
            self.slot_by_fd.pop(slot.fd, None)
            try:
                self.src_poll.unregister(slot.fd)
            except (OSError, ValueError):
                pass  # not registered, or the epoll is closed already
            slot.fd = None
        slot.live = False
        self._live_changed()
        slot.source.close()

    def _live_changed(self) -> None:
        """What the POSE lines say of the sensors, kept here rather than made per window:
        the names of those not live, the health names per pattern of states (a new set
        of slots may name them differently) and what the wake planning reads."""
        self.missing_names = tuple(s.name for s in self.slots if not s.live)
        self._names_by_state = {}
        # What the wake planning needs of each live sensor: (report period, latency, the
        # health whose last_t is its last report, or None for a paced source).
        self.plan_slots = [
            (1.0 / s.mouse.report_hz, s.latency, None if s.paced else s.source.health)
            for s in self.slots
            if s.live
        ]

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
