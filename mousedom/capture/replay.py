"""The replay engine: capture readers -> tracker -> pose batches, streamed in chunks.

Every capture yields feeds (see ``mousedom.capture.base``); the engine always advances
the feed whose watermark lags most, pushes its reports into the tracker, declares the
feed's mice complete up to that watermark, and hands whatever windows can close to a
sink.  So however long the input, only about one block per feed plus the tracker's open
windows are in memory.  A mouse whose file ended is declared complete up to the slowest
live feed, so that it does not hold the others back.

No clock and no pacing here: ``mousedom.capture.pacing`` wraps the sink when a user asks for
``--speed``.  Poses are written by ``CsvSink`` (``capture.posecsv``); ``Summary``
(``capture.summary``) collects what the summary and the plot need while the batches stream
past.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from mousedom.capture.assignment import (
    Assignment,
    GyroAssignment,
    captures_of,
    find_gyro,
    mice_by_device,
)
from mousedom.capture.base import Batch, Capture, Feed, Serial, lagging_first
from mousedom.capture.posecsv import CsvSink, csv_columns, read_csv
from mousedom.capture.summary import GyroSummary, MouseSummary, Summary
from mousedom.capture.timebase import grid_anchor, time_offset
from mousedom.config import Config
from mousedom.fusion.gyro import gyro_period
from mousedom.fusion.tracker import PoseBatch, Tracker

if TYPE_CHECKING:
    from mousedom.sources.adns_decode import AdnsDecoder

# Re-exported: what importers of the replay engine also take from here.
__all__ = [
    "MAX_GAP_S",
    "MAX_WINDOWS",
    "SERIAL_MARGIN_S",
    "CsvSink",
    "MouseSummary",
    "Replay",
    "Summary",
    "csv_columns",
    "read_csv",
]


# Serial packets are mapped from the firmware clock onto host time by a filter that may
# place a packet a little before the host read that brought it: declare a serial mouse
# complete only this far behind its feed's watermark.
SERIAL_MARGIN_S = 0.1

# The most windows closed at once (bounded memory however long a pause in the input).
MAX_WINDOWS = 16384

# A stretch this long in which no mouse reports is skipped, not windowed through: a
# corrupted stamp (a relative file whose second event is 1.3e9 s later) or a recording
# paused overnight would otherwise cost time in proportion to the span, not the reports.
# The CSV has no rows for a skipped gap, the pose is held across it, and a warning names
# it.  (Mice report only while they move, so shorter pauses are windowed as usual.)
MAX_GAP_S = 60.0


@dataclass
class _FeedState:
    feed: Feed
    capture: Capture
    # device -> sensor indices: the mice it feeds (one file may feed two), or the gyro
    # (the tracker's sensor N, after the N mice)
    mice: dict[int, tuple[int, ...]]
    offset: float  # seconds subtracted from this feed's times
    watermark: float = -math.inf  # in tracker time
    done: bool = False
    decoders: dict[int, AdnsDecoder] = field(default_factory=dict)  # serial device -> decoder
    serial: frozenset[int] = frozenset()  # devices that are serial sources


# A sensor's input read but not yet pushed, in time order: a mouse's (t, dx, dy) blocks,
# the gyro's (t, rate).
_Block = tuple[np.ndarray, ...]


class _Run:
    """One ``Replay.run``: the feeds, the reports read but not yet handed to the tracker,
    how far each mouse's input is known complete, and the windows closed so far."""

    def __init__(self, replay: Replay, sink: Callable[[PoseBatch], None], summary: Summary) -> None:
        self.config = replay.config
        self.tracker = replay.tracker
        self.warnings = replay.warnings  # the replay's own list: a skipped gap is added to it
        self.sink = sink
        self.summary = summary
        self.states = replay.feed_states()
        tracker = self.tracker
        # The sensors in the tracker's order: the mice, then the gyro if it is replayed.
        self.push: list[Callable[..., None]] = [
            _mouse_push(tracker, k) for k in range(len(self.config.mice))
        ]
        periods = [1.0 / m.report_hz for m in self.config.mice]
        if replay.gyro is not None and self.config.gyro is not None:
            self.push.append(tracker.push_gyro)
            periods.append(gyro_period(self.config.gyro))
        n = len(self.push)
        self.ended: list[int] = []  # sensors whose feed has ended
        self.pending: list[list[_Block]] = [[] for _ in range(n)]
        self.want = [-math.inf] * n  # how far each sensor's input is complete
        self.last_t = -math.inf  # the latest report read
        self.pushed_t = -math.inf  # the latest report handed to the tracker
        self.skipped_to = -math.inf  # where the last skipped gap ended
        self.longest_period = max(periods, default=0.0)

    def emit(self, b: PoseBatch) -> None:
        if len(b):
            self.summary.add(b)
            self.sink(b)

    # ------------------------------------------------------------------ reading feeds

    def queue(self, sensor: int, t: np.ndarray, *columns: np.ndarray) -> None:
        self.pending[sensor].append((np.asarray(t, np.float64), *columns))
        self.last_t = max(self.last_t, float(t[-1]))

    def take(self, st: _FeedState, batch: Batch) -> None:
        """Queue a feed's batch, and move what its mice are known complete to."""
        for mo in batch.motion:
            if len(mo.t):
                t = mo.t - st.offset if st.offset else mo.t
                for mouse in st.mice.get(mo.device, ()):
                    self.queue(mouse, t, mo.dx, mo.dy)
        for chunk in batch.serial:
            mice = st.mice.get(chunk.device)
            if mice:
                self._take_serial(st, chunk, mice)
        for rates in batch.gyro:  # the gyro's samples: one more stream, as a mouse's
            if len(rates.t):
                t = rates.t - st.offset if st.offset else rates.t
                sat = rates.saturated
                sat = np.zeros(len(t), bool) if sat is None else sat
                for sensor in st.mice.get(rates.device, ()):
                    self.queue(sensor, t, rates.rate, sat)
        if batch.complete > -math.inf:
            self._advance(st, batch.complete - st.offset)
        finite = [s.watermark for s in self.states if not s.done and math.isfinite(s.watermark)]
        if self.ended and finite:
            # A mouse whose file ended must not hold the others back.
            for mouse in self.ended:
                self.want[mouse] = max(self.want[mouse], min(finite))

    def _take_serial(self, st: _FeedState, chunk: Serial, mice: tuple[int, ...]) -> None:
        """Raw ADNS-3080 bytes through the daemon's own decoder (one per device)."""
        dec = st.decoders.get(chunk.device)
        if dec is None:
            from mousedom.sources.adns import replay_decoder

            dec = st.decoders[chunk.device] = replay_decoder(self.config.mice[mice[0]])
        r = dec.feed_many(chunk.t - st.offset, chunk.data)
        t, dx, dy = r.t, r.dx, r.dy
        if len(t):
            for mouse in mice:
                self.queue(mouse, t, dx, dy)
                if r.quality is not None:
                    self.tracker.push_quality(mouse, *r.quality, lost_from=r.lost_from)
            st.capture.stats[chunk.device].add_motion(t, dx, dy)

    def _advance(self, st: _FeedState, watermark: float) -> None:
        """The feed is complete up to ``watermark`` (tracker time): so are its mice, a
        serial one up to SERIAL_MARGIN_S before it."""
        st.watermark = watermark
        if math.isfinite(st.watermark):
            for dev, mice in st.mice.items():
                margin = SERIAL_MARGIN_S if dev in st.serial else 0.0
                for mouse in mice:
                    self.want[mouse] = max(self.want[mouse], st.watermark - margin)

    # ------------------------------------------------------------------ closing windows

    def pump(self) -> None:
        """Push and close at most MAX_WINDOWS windows at a time.

        The tracker closes every window it can in one batch: after a pause of an hour
        at 1 kHz that is 3.6 million windows at once (gigabytes).  So reports are
        handed over, and completeness declared, no further than MAX_WINDOWS windows
        past the closed frontier.  Reports reach the tracker in the same order and
        never behind its frontier, so the poses are the very same.
        """
        while True:
            lim = self._limit()
            for sensor in range(len(self.pending)):
                self._push_until(sensor, lim)
            # Completeness is bounded from the reports now pushed, not from the bound
            # they were pushed to: how far a pause is windowed (MAX_GAP_S past its last
            # report) must not depend on how the input was split into batches.
            lim = self._limit()
            for sensor in range(len(self.pending)):
                if self.want[sensor] > -math.inf:
                    self.tracker.complete_until(min(self.want[sensor], lim), sensor)
            b = self.tracker.poll()
            self.emit(b)
            if self.skip_gap():
                continue
            if not len(b):
                return

    def _limit(self) -> float:
        """How far reports may be pushed in this round of ``pump``."""
        tracker = self.tracker
        if tracker.t0 is None:
            return math.inf
        lim = tracker.frontier_time + MAX_WINDOWS * tracker.period
        # Not more than a gap's worth past the last report (or the last skip's end; the
        # start before any report): a longer gap is skipped (skip_gap), not windowed
        # through, and windowed as far whether or not the report after it was read yet.
        base = max(self.pushed_t, self.skipped_to)
        if base == -math.inf:
            base = tracker.frontier_time
        return min(lim, base + MAX_GAP_S)

    def _push_until(self, sensor: int, lim: float) -> None:
        """Hand the tracker the sensor's waiting input stamped at or before ``lim``."""
        waiting = self.pending[sensor]
        push = self.push[sensor]
        while waiting:
            block = waiting[0]
            t = block[0]
            k = int(np.searchsorted(t, lim, side="right"))
            if k:
                self.pushed_t = max(self.pushed_t, float(t[k - 1]))
            if k == len(t):
                push(*block)
                waiting.pop(0)
                continue
            if k:
                push(*(c[:k] for c in block))
                waiting[0] = tuple(c[k:] for c in block)
            break

    def skip_gap(self) -> bool:
        """Skip a long gap before the next report (see MAX_GAP_S); True if it did."""
        tracker = self.tracker
        firsts = [float(waiting[0][0][0]) for waiting in self.pending if waiting]
        if not firsts or tracker.t0 is None or min(firsts) - self.pushed_t <= MAX_GAP_S:
            return False
        # Every report stamped before min(want) has been read: none hides in the gap.
        until = min(min(firsts), min(self.want)) - self.longest_period
        if until <= tracker.frontier_time:
            return False
        span = tracker.skip_quiet(until)
        if span is None:
            return False
        self.skipped_to = span[1]
        # (its first MAX_GAP_S were windowed as any pause is: the reports before it may
        # still have closed windows there; the rest is skipped)
        self.warnings.append(
            f"no mouse reported from t={self.pushed_t:.6f} to t={min(firsts):.6f} "
            f"({min(firsts) - self.pushed_t:.6g} s): windowed to t={span[0]:.6f}, that "
            f"gap was skipped from there to t={span[1]:.6f} ({span[1] - span[0]:.6g} s: no "
            "rows for it; the pose is held across it)"
        )
        return True

    def finish(self) -> None:
        """The end: everything read is complete; close all but the last windows in
        bounded steps, then let the tracker close the rest."""
        n = len(self.pending)
        for sensor in range(n):
            self.want[sensor] = max(self.want[sensor], self.last_t)
        self.pump()
        for sensor in range(n):
            for block in self.pending[sensor]:  # nothing is left; kept so no count is lost
                self.push[sensor](*block)
        self.emit(self.tracker.finish())
        for st in self.states:
            for dev, dec in st.decoders.items():
                st.capture.stats[dev].dropped_frames += dec.lost  # packets missing, each once


class Replay:
    """Replay the assigned captures through a tracker.  ``run(sink)`` drives it."""

    def __init__(
        self,
        config: Config,
        assignments: list[Assignment],
        *,
        model: str | None = None,
        integrator: str | None = None,
    ) -> None:
        self.assignments = assignments
        self.captures = captures_of(assignments)
        self.offset, warnings = time_offset(self.captures)
        # The config's gyro from the captures; a config whose gyro none of them holds is
        # replayed without it (find_gyro says so), never waiting for samples.
        self.gyro: GyroAssignment | None
        self.gyro, gyro_warnings = find_gyro(config, self.captures)
        self.gyro_dropped = config.gyro is not None and self.gyro is None
        if self.gyro_dropped:
            config = dataclasses.replace(config, gyro=None)
        self.config = config
        self.warnings = list(warnings) + gyro_warnings
        self.t0 = grid_anchor(self.captures, self.offset)
        self.tracker = Tracker(config, t0=self.t0, model=model, integrator=integrator)

    def _offset_of(self, cap: Capture) -> float:
        return self.offset if cap.time_base == "epoch" else 0.0

    def feed_states(self) -> list[_FeedState]:
        """Fresh feeds of every capture, those that feed an assigned mouse."""
        states: list[_FeedState] = []
        for cap in self.captures:
            devmap = mice_by_device(self.assignments, cap)
            if self.gyro is not None and self.gyro.capture is cap:
                devmap[self.gyro.device] = (len(self.config.mice),)  # the tracker's sensor N
            for feed in cap.feeds():
                mice = {d: devmap[d] for d in feed.devices if d in devmap}
                if mice:
                    serial = frozenset(d for d in mice if cap.devices[d].kind == "serial")
                    states.append(_FeedState(feed, cap, mice, self._offset_of(cap), serial=serial))
        return states

    def run(
        self,
        sink: Callable[[PoseBatch], None],
        progress: Callable[[float], None] | None = None,
    ) -> Summary:
        """Stream everything; call ``sink`` with each batch of closed windows."""
        summary = Summary(self.config.names)
        run = _Run(self, sink, summary)
        total = sum(c.bytes_total for c in self.captures) or 1
        for st, batch in lagging_first(run.states):
            if batch is None:
                run.ended.extend(m for mice in st.mice.values() for m in mice)
                continue
            run.take(st, batch)
            run.pump()
            if progress is not None:
                progress(sum(c.bytes_done for c in self.captures) / total)
        run.finish()
        self._summarise(summary)
        return summary

    def _summarise(self, summary: Summary) -> None:
        """Each mouse's summary, and the warnings, once the tracker has closed all."""
        tracker = self.tracker
        counts_in = tracker.counts_in
        counts_out = tracker.counts_out
        for a in self.assignments:
            m = self.config.mice[a.mouse]
            summary.mice.append(
                MouseSummary(
                    name=m.name,
                    file=a.capture.path,
                    device=a.capture.devices[a.device].name,
                    stats=a.capture.stats[a.device],
                    counts_in=_pair(counts_in[a.mouse]),
                    counts_out=_pair(counts_out[a.mouse]),
                    offset=self._offset_of(a.capture),
                    **summary.health_of(a.mouse),
                )
            )
        if self.gyro is not None:
            cap, dev = self.gyro.capture, self.gyro.device
            summary.gyro = GyroSummary(cap.path, cap.devices[dev].name, cap.stats[dev],
                                       *summary.gyro_bias)  # fmt: skip
        summary.gyro_dropped = self.gyro_dropped
        for c in self.captures:
            summary.warnings += c.warnings
        summary.warnings = self.warnings + summary.warnings
        for name, late in _late_reports(tracker).items():
            if late:
                summary.warnings.append(
                    f"mouse {name}: {late} reports came after their window had closed "
                    "and were moved into the next one"
                )
        if not summary.windows:
            summary.warnings.append("no motion reports in the captures: no pose to write")


def _late_reports(tracker: Tracker) -> dict[str, int]:
    """Per mouse, its reports that came after their window had closed."""
    return {name: st["late"] for name, st in tracker.stats().items()}


def _mouse_push(tracker: Tracker, mouse: int) -> Callable[..., None]:
    def push(t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
        tracker.push(mouse, t, dx, dy)

    return push


def _pair(row: np.ndarray) -> tuple[float, float]:
    """A mouse's (REL_X, REL_Y) row of counts, as the tuple the summary keeps."""
    x, y = row
    return (x, y)
