"""The daemon's sensors: one slot per configured mouse, opened, read, lost and retried.

``Sensors`` owns the slots, the epoll of their descriptors and what the rest of the daemon
reads of them (the names of the missing ones, the health names per pattern of states, what
the wake planning needs).  It needs from outside only what it is given: the running config
and tracker (running.py), the clock, the source factory, where the reports go besides the
tracker (``ReportSink``: the outputs that keep them) and whom to tell when a sensor comes
or goes (``on_change``).
"""

from __future__ import annotations

import logging
import math
import re
import select
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np

from mousedom.config import Config, GyroConfig, MouseConfig
from mousedom.errors import UserError
from mousedom.fusion.choices import GYRO
from mousedom.fusion.robust import Health, Reason
from mousedom.service.factory import source_key
from mousedom.service.running import Running
from mousedom.sources.base import Source, SourceGone, SourceHealth, SourceUnavailable

log = logging.getLogger(__name__)

Clock = Callable[[], float]
SourceFactory = Callable[[Any, Clock], Source]  # (a Sensor, the clock): factory.make_source

RETRY_S = 1.0  # how often a vanished sensor is looked for again


def sensor_name(sensor: Sensor) -> str:
    """A mouse's name, or "gyro" (a gyro's ``name`` is its IIO device's)."""
    return GYRO if isinstance(sensor, GyroConfig) else sensor.name


def sensors_of(config: Config) -> list[Sensor]:
    """The config's sensors in the tracker's order: the mice, then the gyro if any."""
    return [*config.mice, *([config.gyro] if config.gyro is not None else [])]


class ReportSink(Protocol):
    """Where a sensor's reports go besides the tracker (the live recording)."""

    wants_reports: bool

    def reports(self, index: int, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None: ...

    def gyro(
        self, t: np.ndarray, rate: np.ndarray, saturated: np.ndarray | None = None
    ) -> None: ...


class PlannedSensor(NamedTuple):
    """What the wake planning reads of a live sensor: its report period, how late its
    reports may come (0 for a paced source, which hands over every report due), and the
    health whose ``last_t`` is its last report: a paced source's too, whose silence the
    window waits out as any mouse's (without it the plan gave up a period after the end
    and the loop spun until the silence rule closed the window)."""

    period: float
    latency: float
    health: SourceHealth | None
    # its descriptor, to wait on it alone (None: a paced source's, which has none to
    # wait on, and a probed one's, whose readiness does not say when it is gone)
    fd: int | None = None


Sensor = MouseConfig | GyroConfig  # what a slot reads: a mouse, or the rig's gyro
# A window's (missing, excluded, suspect) sensor names, as its POSE line says them
WindowNames = tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]


def window_names(names: Sequence[str], live: Sequence[bool], state: Sequence[int]) -> WindowNames:
    """(missing, excluded, suspect) sensor names of a window, from each mouse's state
    after it (``state``, the first ``len(state)`` sensors) and, for a sensor beyond the
    mice (the gyro), whether it is ``live`` now.

    Missing: the mice not live over the window (gone, or not yet used in the window they
    came back in or were opened in by a reload), and a sensor beyond the mice that is not
    live.  Excluded: the mice the fault-tolerant fusion left out of the window, for their
    readings or their sensor's word, or held out as late (their counts come later and are
    given back when they do).  So the sensors the window was solved with are the config's
    less the missing and the excluded (docs/protocol.md), but in the window a late mouse's
    counts are given back in: it is tracking again after it, its counts are in the pose,
    and it was not in that window's solve."""
    n = len(state)
    mi = tuple(name for i, name in enumerate(names)
               if (state[i] == Health.MISSING if i < n else not live[i]))  # fmt: skip
    ex = tuple(name for name, v in zip(names, state, strict=False)
               if v == Health.EXCLUDED or v == Health.LATE)  # fmt: skip
    su = tuple(name for name, v in zip(names, state, strict=False) if v == Health.SUSPECT)
    return mi, ex, su


@dataclass
class Slot:
    """One configured sensor as the loop sees it, and the figures its SOURCE says.  The
    mice's slots come first, in the config's order (their index is the tracker's); the
    gyro's, if the rig has one, last (the tracker's sensor N)."""

    index: int
    mouse: Sensor
    source: Source
    live: bool = False
    # Live to the tracker: open and answered (``Source.answered``; a serial port that has
    # not yet sent a packet is read, but not fused as a mouse standing still)
    fused: bool = False
    fd: int | None = None
    retry_at: float = 0.0
    latency: float = Source.latency
    paced: bool = False  # no readable fd: read on the loop's own schedule (replay)
    residual_sq: float = 0.0
    residual_n: int = 0
    residual_rms: float | None = None
    health_state: Health = Health.TRACKING  # after the last window folded in
    health_reason: Reason = Reason.NONE
    announced: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return sensor_name(self.mouse)

    @property
    def period(self) -> float:
        """The longest time between two of its reports while it reports."""
        if isinstance(self.mouse, GyroConfig):
            from mousedom.fusion.gyro import gyro_period

            return gyro_period(self.mouse)
        return 1.0 / self.mouse.report_hz

    def add_residual(self, rx: float, ry: float) -> None:
        """One window's residual of this mouse into its sums (non-finite ones skipped)."""
        if math.isfinite(rx) and math.isfinite(ry):
            self.residual_sq += rx * rx + ry * ry
            self.residual_n += 1

    def take_rms(self) -> float | None:
        """The RMS of the residuals since the last call (or the last one, if none came)."""
        if self.residual_n:
            self.residual_rms = (self.residual_sq / self.residual_n) ** 0.5
            self.residual_sq, self.residual_n = 0.0, 0
        return self.residual_rms


def _keeps(slot: Slot, sensor: Sensor | None) -> bool:
    """Whether a reload to ``sensor`` keeps ``slot``'s source open: the same device."""
    return sensor is not None and source_key(slot.mouse) == source_key(sensor)


class Sensors:
    """Opening, reading and losing the configured sensors (see the module docstring)."""

    def __init__(
        self,
        running: Running,
        clock: Clock,
        source_factory: SourceFactory,
        sink: ReportSink,
        on_change: Callable[[float], None],
    ) -> None:
        self.running = running
        self.clock = clock
        self.source_factory = source_factory
        self.sink = sink
        self.on_change = on_change
        # The sources have an epoll of their own, waited on with the main one only while a
        # window waits for reports (daemon._select).  A bare epoll, not a selector: it is
        # asked once per window, and selectors' Python layer cost more than the syscall.
        self.poll = select.epoll()
        self.slots: list[Slot] = []
        self.by_fd: dict[int, Slot] = {}
        self.missing_names: tuple[str, ...] = ()  # see _live_changed
        self.plan: list[PlannedSensor] = []
        self.names_by_state: dict[tuple[int, ...], WindowNames] = {}
        self.reads = 0  # source reads: what the reading policy costs
        self.started = False  # after start(): a sensor that fails to open is retried

    # ------------------------------------------------------------------ lifecycle

    def start(self, now: float) -> None:
        """A slot per configured sensor, each opened (or its retry planned)."""
        self.slots = [self._new_slot(i, m) for i, m in enumerate(sensors_of(self.running.config))]
        self._live_changed()
        for slot in self.slots:
            self.try_open(slot, now)
        self.started = True

    def max_latency(self) -> float:
        return max((s.latency for s in self.slots), default=0.0)

    def kept(self, mice: Sequence[Sensor]) -> list[tuple[int, int]]:
        """(index in ``mice``, index now) of each sensor a reload to ``mice`` keeps open
        (``replace``): the tracker's indices, whose count functions go on (Tracker.carry)."""
        old = {s.name: s for s in self.slots}
        pairs = []
        for i, mouse in enumerate(mice):
            prev = old.get(sensor_name(mouse))
            if prev is not None and _keeps(prev, mouse):
                pairs.append((i, prev.index))
        return pairs

    def replace(self, mice: Sequence[Sensor], now: float) -> None:
        """The slots of a reloaded config: a mouse whose device is unchanged keeps its open
        source (and its place in the epoll); the others are closed, or opened anew.  The
        running tracker is already the new one, carrying on with the sensors kept (``kept``):
        a sensor it did not have open is not live in it until it opens, as one that comes
        back (``Tracker.set_live``)."""
        old = {s.name: s for s in self.slots}
        slots = []
        for i, mouse in enumerate(mice):
            prev = old.pop(sensor_name(mouse), None)
            if prev is not None and _keeps(prev, mouse):
                prev.index, prev.mouse = i, mouse
                slots.append(prev)
            else:
                if prev is not None:
                    self._close_slot(prev)
                slots.append(self._new_slot(i, mouse))
        for gone in old.values():
            self._close_slot(gone)
        self.slots = slots
        self._live_changed()
        tracker = self.running.tracker
        for slot in slots:
            tracker.set_live(slot.index, slot.fused, now)
            if not slot.live:
                self.try_open(slot, now)

    def close(self) -> None:
        for slot in self.slots:
            self._close_slot(slot)
        self.poll.close()

    def fileno(self) -> int:
        """The epoll of the sources' descriptors: readable when any sensor is."""
        return self.poll.fileno()

    # ------------------------------------------------------------------ opening

    def _new_slot(self, index: int, mouse: Sensor) -> Slot:
        source = self.source_factory(mouse, self.clock)
        # A paced source hands over every report due by ``now``: none comes late.
        latency = 0.0 if source.paced else source.latency
        return Slot(index, mouse, source, latency=latency, paced=source.paced)

    def try_open(self, slot: Slot, now: float) -> None:
        try:
            slot.source.open()
            fd = slot.source.fileno()
            self._refuse_shared_device(slot)
        except SourceUnavailable as e:
            self._unavailable(slot, now, e)
            return
        except Exception as e:  # noqa: BLE001 - see below
            if not self.started:
                raise  # at start: the config's error, said once (a capture that does not read)
            # A reload's or a retry's: a capture that does not read (garbage, or a device it
            # cannot tell), a source that broke.  The daemon goes on without that sensor
            # and tries again, as for a device that is not there; it never exits for it.
            if not isinstance(e, UserError):
                log.exception("%s: open failed", slot.name)
            try:
                slot.source.close()
            except Exception:  # noqa: BLE001 - closing what did not open
                pass
            slot.source.health.connected = False
            slot.source.health.error = str(e)
            self._unavailable(slot, now, e)
            return
        # (a gyro knows only once open whether it reads a buffer or polls: paced)
        slot.paced = slot.source.paced
        slot.latency = 0.0 if slot.paced else slot.source.latency
        slot.fd = fd if fd is not None and fd >= 0 and not slot.paced else None
        if slot.fd is not None:
            self.poll.register(slot.fd, select.EPOLLIN)
            self.by_fd[slot.fd] = slot
        slot.live = True
        slot.fused = slot.source.answered
        if slot.fused:
            slot.announced.pop("gone", None)
        self._live_changed()
        slot.announced.pop("error", None)
        self.running.tracker.set_live(slot.index, slot.fused, now)
        log.info("%s: open (%s)", slot.name, slot.source.kind)
        self.on_change(now)

    def _unavailable(self, slot: Slot, now: float, why: Exception) -> None:
        """The slot's sensor did not open: said once per distinct reason, retried."""
        if slot.retry_at == 0.0 or slot.source.health.error != slot.announced.get("error"):
            log.warning("%s: not available: %s (retrying every %gs)", slot.name, why, RETRY_S)
        slot.announced["error"] = slot.source.health.error
        slot.retry_at = now + RETRY_S
        self.running.tracker.set_live(slot.index, False, now)

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

    def next_retry(self) -> float:
        """When a missing sensor is next looked for (inf: none is missing)."""
        if not self.missing_names:
            return math.inf
        # (missing may name an open port that has not answered yet: no retry for it)
        return min((s.retry_at for s in self.slots if not s.live), default=math.inf)

    def retry(self, now: float) -> None:
        for slot in self.slots:
            if not slot.live and now >= slot.retry_at:
                self.try_open(slot, now)

    # ------------------------------------------------------------------ reading

    def read_due(self, now: float) -> None:
        """Read what the sensors hold for the windows due at ``now``, and tell the tracker
        how far each live sensor's reports are complete."""
        for fd, _ in self.poll.poll(0):
            slot = self.by_fd.get(fd)
            if slot is not None and not slot.source.probe:  # (a probed one: read below)
                self.read(slot, now)
        completes = []
        for slot in self.slots:
            if slot.live and (slot.paced or slot.source.probe):  # read at every wake
                self.read(slot, now)
            if slot.fused:  # (a paced read may have lost it)
                completes.append((slot.index, now - slot.latency))
        tracker = self.running.tracker
        if completes:
            tracker.complete_each(completes)
        else:
            # Nothing can report: windows close on time, as "not updated" (the pose holds).
            tracker.complete_until(now)

    def read_live(self) -> None:
        """Everything the live sensors hold now (before a reload or a stop)."""
        for slot in self.slots:
            if slot.live:
                self.read(slot)

    def read(self, slot: Slot, now: float | None = None) -> None:
        if now is None:
            now = self.clock()
        self.reads += 1
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
        tracker = self.running.tracker
        if not slot.fused and slot.source.answered:
            slot.fused = True  # its first answer: fused from now
            slot.announced.pop("gone", None)
            self._live_changed()
            tracker.set_live(slot.index, True, now)
        if isinstance(slot.mouse, GyroConfig):
            from mousedom.sources.iio import GyroSamples  # (late: a rig without one loads none)

            for samples in batches:
                if isinstance(samples, GyroSamples) and len(samples.t):
                    tracker.push_gyro(samples.t, samples.rate, samples.saturated)
                    if self.sink.wants_reports:
                        self.sink.gyro(samples.t, samples.rate, samples.saturated)
            return
        for batch in batches:
            t, dx, dy = batch.columns()
            if len(t):
                # As the source holds them: a live read's lists go on without numpy.
                tracker.push(slot.index, t, dx, dy)
                if batch.quality is not None:
                    tracker.push_quality(slot.index, *batch.quality, lost_from=batch.lost_from)
                if self.sink.wants_reports:
                    self.sink.reports(slot.index, batch.t, batch.dx, batch.dy)

    def _gone(self, slot: Slot, now: float, why: str) -> None:
        # Said once until the sensor is fused again: a port that is no downsampler opens,
        # fails its answer and is retried, for as long as it stays plugged in
        # (its figures apart: "N bytes that are no packet" differ each time)
        kind = re.sub(r"\d+", "N", why)
        said = slot.announced.get("gone") == kind
        (log.debug if said else log.warning)(
            "%s: lost (%s); going on without it, retrying every %gs", slot.name, why, RETRY_S
        )
        slot.announced["gone"] = kind
        self._close_slot(slot)
        slot.retry_at = now + RETRY_S
        self.running.tracker.set_live(slot.index, False, now)
        self.on_change(now)

    def _close_slot(self, slot: Slot) -> None:
        if slot.fd is not None:
            self.by_fd.pop(slot.fd, None)
            try:
                self.poll.unregister(slot.fd)
            except (OSError, ValueError):
                pass  # not registered, or the epoll is closed already
            slot.fd = None
        slot.live = slot.fused = False
        self._live_changed()
        slot.source.close()

    # ------------------------------------------------------------------ what others read

    def _live_changed(self) -> None:
        """What the POSE lines say of the sensors, kept here rather than made per window:
        the names of those not live, the health names per pattern of states (a new set
        of slots may name them differently) and what the wake planning reads."""
        self.missing_names = tuple(s.name for s in self.slots if not s.fused)
        self.names_by_state = {}
        self.plan = [
            PlannedSensor(
                s.period, s.latency, s.source.health, None if s.paced or s.source.probe else s.fd
            )
            for s in self.slots
            if s.fused
        ]

    def names_for(self, state: Sequence[int]) -> WindowNames:
        """(missing, excluded, suspect) sensor names for a window's per-mouse states
        (``window_names``; cached per pattern: a rig has few, and this runs for every
        window).  A mouse lost after the window's end, before its POSE was sent, was used
        in it: it is missing from the next window on."""
        key = tuple(state)  # rows from arrays hold lists
        names = self.names_by_state.get(key)
        if names is None:
            names = self.names_by_state[key] = window_names(
                [s.name for s in self.slots], [s.fused for s in self.slots], key
            )
        return names

    def status_line(self, clients: int) -> str:
        """systemd's STATUS= text."""
        live = [s.name for s in self.slots if s.fused]
        gone = [s.name for s in self.slots if not s.fused]
        text = f"{len(live)}/{len(self.slots)} sensors live"
        if gone:
            text += "; missing: " + ", ".join(gone)
        return text + f"; {clients} clients"
