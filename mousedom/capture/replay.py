"""The replay engine: capture readers -> tracker -> pose batches, streamed in chunks.

Every capture yields feeds (see ``mousedom.capture.base``); the engine always advances
the feed whose watermark lags most, pushes its reports into the tracker, declares the
feed's mice complete up to that watermark, and hands whatever windows can close to a
sink.  So however long the input, only about one block per feed plus the tracker's open
windows are in memory.  A mouse whose file ended is declared complete up to the slowest
live feed, so that it does not hold the others back.

No clock and no pacing here: ``mousedom.capture.pacing`` wraps the sink when a user asks for
``--speed``.  Poses are written by ``CsvSink``; ``Summary`` collects what the summary
and the plot need while the batches stream past.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TextIO

import numpy as np

from mousedom.capture.assignment import Assignment, captures_of, mice_by_device
from mousedom.capture.base import Capture, DeviceStats, lagging_first
from mousedom.capture.fixedpoint import fixed_bytes
from mousedom.capture.scientific import scientific_bytes
from mousedom.capture.timebase import time_offset
from mousedom.config import Config
from mousedom.fusion import robust
from mousedom.fusion.tracker import PoseBatch, Tracker

CSV_COLUMNS = ("t", "x", "y", "theta", "vx", "vy", "omega", "used", "ok", "consistent")
_ROW = "%.6f,%.9f,%.9f,%.9f,%.6f,%.6f,%.6f,%d,%d,%d"
# Then per mouse: state_<name> (fusion.robust.STATES: 0 tracking, 1 suspect, 2 excluded,
# 3 missing) and reason_<name> (fusion.robust.REASONS: 0 none, 1 inconsistent, 2 silent
# while others move, 3 saturated, 4 low quality), as numbers so the file stays numeric.
# Then the pose covariance, the upper triangle of the batch's cov over (x, y, theta) in the
# units of the pose columns (m^2, m^2, m rad, m^2, m rad, rad^2), exponent form, and per
# mouse scale_x_<name>, scale_y_<name>: the learnt scale of its counts along its own axes
# (REL_X, REL_Y; 1 where none is learnt).
COV_COLUMNS = ("cov_xx", "cov_xy", "cov_xt", "cov_yy", "cov_yt", "cov_tt")
_COV_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_COV_DIGITS = 6  # "%.6e": seven significant digits
_SCALE_DIGITS = 6  # "%.6f"


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
    feed: object
    capture: Capture
    mice: dict[int, tuple[int, ...]]  # device -> mouse indices (one file may feed two mice)
    offset: float  # seconds subtracted from this feed's times
    watermark: float = -math.inf  # in tracker time
    done: bool = False
    decoders: dict = field(default_factory=dict)  # serial device -> AdnsDecoder
    serial: frozenset = frozenset()  # devices that are serial sources


@dataclass
class MouseSummary:
    name: str
    file: str
    device: str
    stats: DeviceStats
    counts_in: tuple[float, float] = (0.0, 0.0)
    counts_out: tuple[float, float] = (0.0, 0.0)
    excluded: int = 0  # windows after which the fusion had it excluded (robust.EXCLUDED)
    suspect: int = 0  # ... suspect (robust.SUSPECT)
    # Those windows by the reason the fusion gave (robust.REASONS' text: count), the most
    # frequent first; a reason never given is left out.
    excluded_why: dict[str, int] = field(default_factory=dict)
    suspect_why: dict[str, int] = field(default_factory=dict)
    scale: tuple[float, float] | None = None  # learnt scale (REL_X, REL_Y) at the end; None:
    # no window had one learnt

    @property
    def rate_hz(self) -> float:
        s = self.stats
        if s.reports < 2 or s.first_t is None or s.last_t is None or s.last_t <= s.first_t:
            return 0.0
        return (s.reports - 1) / (s.last_t - s.first_t)


@dataclass
class Summary:
    """What a replay did; filled while the batches stream through ``add``."""

    names: tuple[str, ...]
    windows: int = 0
    not_ok: int = 0
    path_length: float = 0.0
    t_first: float | None = None
    t_last: float | None = None
    final: dict[str, float] = field(default_factory=dict)
    mice: list[MouseSummary] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    # Where the path so far ends: a replay starts at the origin, and the path from there
    # to the first window's pose counts (measured from that pose, the path could be
    # shorter than the displacement).
    _last_xy: tuple[float, float] = (0.0, 0.0)
    # Per mouse (config order): windows excluded and suspect, and those by reason (N,
    # len(REASONS)): column k counts robust.REASONS[k]; the last learnt scale.
    excluded: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    suspect: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    excluded_why: np.ndarray = field(default_factory=lambda: _no_reasons(0))
    suspect_why: np.ndarray = field(default_factory=lambda: _no_reasons(0))
    scale: np.ndarray | None = None  # (N, 2), None while no window had one learnt

    def add(self, b: PoseBatch) -> None:
        n = len(b)
        if not n:
            return
        self.windows += n
        self.not_ok += int(np.count_nonzero(~b.ok))
        state = b.state
        if len(self.excluded) != state.shape[1]:
            self.excluded = np.zeros(state.shape[1], dtype=np.int64)
            self.suspect = np.zeros(state.shape[1], dtype=np.int64)
            self.excluded_why = _no_reasons(state.shape[1])
            self.suspect_why = _no_reasons(state.shape[1])
        self.excluded += np.count_nonzero(state == robust.EXCLUDED, axis=0)
        self.suspect += np.count_nonzero(state == robust.SUSPECT, axis=0)
        # A code the fusion does not name (none should occur) counts as "no reason given".
        reason = np.asarray(b.reason, dtype=np.int64)
        reason = np.where((reason >= 0) & (reason < len(robust.REASONS)), reason, robust.NONE)
        for k in range(len(robust.REASONS)):
            this = reason == k
            self.excluded_why[:, k] += np.count_nonzero(this & (state == robust.EXCLUDED), axis=0)
            self.suspect_why[:, k] += np.count_nonzero(this & (state == robust.SUSPECT), axis=0)
        if b.scale is not None:
            self.scale = np.array(b.scale[-1], dtype=np.float64)
        xs = np.concatenate([[self._last_xy[0]], b.x])
        ys = np.concatenate([[self._last_xy[1]], b.y])
        self.path_length += float(np.hypot(np.diff(xs), np.diff(ys)).sum())
        self._last_xy = (float(b.x[-1]), float(b.y[-1]))
        if self.t_first is None:
            self.t_first = float(b.t[0])
        self.t_last = float(b.t[-1])
        self.final = b.last()

    def health_of(self, mouse: int) -> dict:
        """MouseSummary's health fields of the config's mouse ``mouse``."""
        counted = mouse < len(self.excluded)
        scale = None
        if self.scale is not None:
            scale = (float(self.scale[mouse, 0]), float(self.scale[mouse, 1]))
        return {
            "excluded": int(self.excluded[mouse]) if counted else 0,
            "suspect": int(self.suspect[mouse]) if counted else 0,
            "excluded_why": _why(self.excluded_why[mouse]) if counted else {},
            "suspect_why": _why(self.suspect_why[mouse]) if counted else {},
            "scale": scale,
        }

    @property
    def duration(self) -> float:
        firsts = [m.stats.first_t for m in self.mice if m.stats.first_t is not None]
        lasts = [m.stats.last_t for m in self.mice if m.stats.last_t is not None]
        return (max(lasts) - min(firsts)) if firsts else 0.0

    @property
    def reports(self) -> int:
        return sum(m.stats.reports for m in self.mice)


def _no_reasons(n_mice: int) -> np.ndarray:
    return np.zeros((n_mice, len(robust.REASONS)), dtype=np.int64)


def _why(counts: np.ndarray) -> dict[str, int]:
    """One mouse's windows by reason, as {reason: windows}, the most frequent first (ties
    in robust.REASONS' order); code 0 (robust.NONE) is named "no reason given"."""
    names = ("no reason given", *robust.REASONS[1:])
    order = sorted(range(len(names)), key=lambda k: (-int(counts[k]), k))
    return {names[k]: int(counts[k]) for k in order if counts[k]}


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
        self.config = config
        self.assignments = assignments
        self.captures = captures_of(assignments)
        self.offset, warnings = time_offset(self.captures)
        self.warnings = list(warnings)
        firsts = [
            t - self._offset_of(c) for c in self.captures if (t := c.first_time()) is not None
        ]
        self.t0 = min(firsts) if firsts else None
        self.tracker = Tracker(config, t0=self.t0, model=model, integrator=integrator)

    def _offset_of(self, cap: Capture) -> float:
        return self.offset if cap.time_base == "epoch" else 0.0

    def run(
        self,
        sink: Callable[[PoseBatch], None],
        progress: Callable[[float], None] | None = None,
    ) -> Summary:
        """Stream everything; call ``sink`` with each batch of closed windows."""
        tracker = self.tracker
        summary = Summary(self.config.names)
        states: list[_FeedState] = []
        for cap in self.captures:
            devmap = mice_by_device(self.assignments, cap)
            for feed in cap.feeds():
                mice = {d: devmap[d] for d in feed.devices if d in devmap}
                if mice:
                    serial = frozenset(d for d in mice if cap.devices[d].kind == "serial")
                    states.append(_FeedState(feed, cap, mice, self._offset_of(cap), serial=serial))
        ended: list[int] = []
        total = sum(c.bytes_total for c in self.captures) or 1
        n = len(self.config.mice)
        # Reports read but not yet pushed, and how far each mouse's input is complete.
        pending: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = [[] for _ in range(n)]
        want = [-math.inf] * n
        last_t = -math.inf
        pushed_t = -math.inf  # the latest report handed to the tracker

        def emit(b: PoseBatch) -> None:
            if len(b):
                summary.add(b)
                sink(b)

        longest_period = max((1.0 / m.report_hz for m in self.config.mice), default=0.0)

        def skip_gap() -> bool:
            """Skip a long gap before the next report (see MAX_GAP_S); True if it did."""
            firsts = [float(waiting[0][0][0]) for waiting in pending if waiting]
            if not firsts or tracker.t0 is None or min(firsts) - pushed_t <= MAX_GAP_S:
                return False
            # Every report stamped before min(want) has been read: none hides in the gap.
            until = min(min(firsts), min(want)) - longest_period
            if until <= tracker.frontier_time:
                return False
            span = tracker.skip_quiet(until)
            if span is None:
                return False
            self.warnings.append(
                f"no mouse reported from t={span[0]:.6f} to t={span[1]:.6f} "
                f"({span[1] - span[0]:.6g} s): that gap was skipped, not windowed "
                "(no rows for it; the pose is held across it)"
            )
            return True

        def pump() -> None:
            """Push and close at most MAX_WINDOWS windows at a time.

            The tracker closes every window it can in one batch: after a pause of an hour
            at 1 kHz that is 3.6 million windows at once (gigabytes).  So reports are
            handed over, and completeness declared, no further than MAX_WINDOWS windows
            past the closed frontier.  Reports reach the tracker in the same order and
            never behind its frontier, so the poses are the very same.
            """
            nonlocal pushed_t
            while True:
                if tracker.t0 is None:
                    lim = math.inf
                else:
                    lim = tracker.frontier_time + MAX_WINDOWS * tracker.period
                    # Not more than a gap's worth past the last report: a longer gap is
                    # skipped (skip_gap), not windowed through.
                    lim = min(lim, max(pushed_t, tracker.frontier_time) + MAX_GAP_S)
                for mouse in range(n):
                    waiting = pending[mouse]
                    while waiting:
                        t, dx, dy = waiting[0]
                        k = int(np.searchsorted(t, lim, side="right"))
                        if k:
                            pushed_t = max(pushed_t, float(t[k - 1]))
                        if k == len(t):
                            tracker.push(mouse, t, dx, dy)
                            waiting.pop(0)
                            continue
                        if k:
                            tracker.push(mouse, t[:k], dx[:k], dy[:k])
                            waiting[0] = (t[k:], dx[k:], dy[k:])
                        break
                    if want[mouse] > -math.inf:
                        tracker.complete_until(min(want[mouse], lim), mouse)
                b = tracker.poll()
                emit(b)
                if skip_gap():
                    continue
                if not len(b):
                    return

        def queue(mouse: int, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
            nonlocal last_t
            pending[mouse].append((np.asarray(t, np.float64), dx, dy))
            last_t = max(last_t, float(t[-1]))

        for st, batch in lagging_first(states):
            if batch is None:
                ended.extend(m for mice in st.mice.values() for m in mice)
                continue
            for mo in batch.motion:
                if len(mo.t):
                    t = mo.t - st.offset if st.offset else mo.t
                    for mouse in st.mice.get(mo.device, ()):
                        queue(mouse, t, mo.dx, mo.dy)
            for chunk in batch.serial:
                mice = st.mice.get(chunk.device)
                if not mice:
                    continue
                dec = st.decoders.get(chunk.device)
                if dec is None:
                    from mousedom.sources.adns import replay_decoder

                    dec = st.decoders[chunk.device] = replay_decoder(self.config.mice[mice[0]])
                r = dec.feed_many(chunk.t - st.offset, chunk.data)
                t, dx, dy = r.t, r.dx, r.dy
                if len(t):
                    for mouse in mice:
                        queue(mouse, t, dx, dy)
                        if r.quality is not None:
                            tracker.push_quality(mouse, *r.quality)
                    st.capture.stats[chunk.device].add_motion(t, dx, dy)
            if batch.complete > -math.inf:
                st.watermark = batch.complete - st.offset
                if math.isfinite(st.watermark):
                    for dev, mice in st.mice.items():
                        margin = SERIAL_MARGIN_S if dev in st.serial else 0.0
                        for mouse in mice:
                            want[mouse] = max(want[mouse], st.watermark - margin)
            finite = [s.watermark for s in states if not s.done and math.isfinite(s.watermark)]
            if ended and finite:
                for mouse in ended:
                    want[mouse] = max(want[mouse], min(finite))
            pump()
            if progress is not None:
                progress(sum(c.bytes_done for c in self.captures) / total)
        # The end: everything read is complete; close all but the last windows in bounded
        # steps, then let the tracker close the rest.
        for mouse in range(n):
            want[mouse] = max(want[mouse], last_t)
        pump()
        for mouse in range(n):
            for t, dx, dy in pending[mouse]:  # nothing is left; kept so no count can be lost
                tracker.push(mouse, t, dx, dy)
        emit(tracker.finish())
        for st in states:
            for dev, dec in st.decoders.items():
                st.capture.stats[dev].dropped_frames += dec.lost  # packets refused or missing

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
                    counts_in=tuple(counts_in[a.mouse]),
                    counts_out=tuple(counts_out[a.mouse]),
                    **summary.health_of(a.mouse),
                )
            )
        for c in self.captures:
            summary.warnings += c.warnings
        summary.warnings = self.warnings + summary.warnings
        for name, st in tracker.stats().items():
            if st.get("late"):
                summary.warnings.append(
                    f"mouse {name}: {st['late']} reports came after their window had closed "
                    "and were moved into the next one"
                )
        if not summary.windows:
            summary.warnings.append("no motion reports in the captures: no pose to write")
        return summary


def _safe(names: tuple[str, ...]) -> list[str]:
    """Names as CSV column suffixes (a name's commas and quotes would break the CSV)."""
    return ["".join(c if c.isalnum() or c in "-_." else "_" for c in n) for n in names]


def health_columns(names: tuple[str, ...]) -> list[str]:
    """The per-mouse state and reason columns."""
    return [f"{kind}_{n}" for n in _safe(names) for kind in ("state", "reason")]


def scale_columns(names: tuple[str, ...]) -> list[str]:
    """The per-mouse learnt scale columns, after the covariance."""
    return [f"{kind}_{n}" for n in _safe(names) for kind in ("scale_x", "scale_y")]


def csv_columns(names: tuple[str, ...]) -> list[str]:
    """The header of the replay CSV of a rig whose mice are ``names``."""
    return [*CSV_COLUMNS, *health_columns(names), *COV_COLUMNS, *scale_columns(names)]


class CsvSink:
    """Writes pose batches as CSV rows (header first)."""

    def __init__(self, out: TextIO, names: tuple[str, ...] = ()) -> None:
        self.out = out
        self.rows = 0
        self.n = len(names)
        self._tails: dict[int, str] = {}
        self.radix = max(self.n + 1, 5)  # used <= N mice, states < 4, reasons < 5
        out.write(",".join(csv_columns(names)) + "\n")
        # One row by %-format, for batches the array formatters do not take (not finite).
        fmt = _FLOATS + "%s" + "%.6e," * len(COV_COLUMNS) + "%.6f," * (2 * self.n)
        self._row_format = fmt[:-1] + "\n"

    def __call__(self, b: PoseBatch) -> None:
        n = len(b)
        if not n:
            return
        # The whole-number columns (used, ok, consistent, each mouse's state and reason)
        # take few distinct values: each distinct tail of a row is formatted once.
        ints = np.column_stack([b.used, b.ok, b.consistent]).astype(np.int64)
        if self.n:
            both = np.stack([b.state, b.reason], axis=2).reshape(n, 2 * self.n)
            ints = np.column_stack([ints, both.astype(np.int64)])
        codes, inverse = _row_codes(ints, self.radix)
        tails = []
        for code, row in zip(codes.tolist(), ints[_first_of(inverse, len(codes))].tolist(),
                             strict=True):  # fmt: skip
            tail = self._tails.get(code) if code >= 0 else None
            if tail is None:
                tail = ",".join(map(str, row)) + ","
                if code >= 0 and len(self._tails) < 4096:
                    self._tails[code] = tail
            tails.append(tail)
        floats = np.column_stack([b.t, b.x, b.y, b.theta, b.vx, b.vy, b.omega])
        cov = np.asarray(b.cov)[:, [i for i, _ in _COV_INDEX], [j for _, j in _COV_INDEX]]
        scales = b.scales()[:, : self.n].reshape(n, 2 * self.n) if self.n else np.zeros((n, 0))
        fields = fixed_bytes(floats, _DIGITS)
        cov_fields = scientific_bytes(cov, _COV_DIGITS)
        scale_fields = fixed_bytes(scales, np.full(2 * self.n, _SCALE_DIGITS)) if self.n else None
        if fields is None or cov_fields is None or (self.n and scale_fields is None):
            # Not finite, or too large for the array formatters: one %-operation per row.
            values = np.column_stack([floats, cov, scales]).tolist()
            fmt, rows = self._row_format, zip(values, inverse.tolist(), strict=True)
            self.out.write("".join(fmt % (*v[:7], tails[i], *v[7:]) for v, i in rows))
        else:
            blocks = [fields, cov_fields] + ([scale_fields] if scale_fields is not None else [])
            self.out.write(_join_rows(blocks, tails, inverse))
        self.rows += n


def _join_rows(
    blocks: list[tuple[np.ndarray, np.ndarray]], tails: list[str], inverse: np.ndarray
) -> str:
    """The rows' text: each row's float fields (the first block, with their separators),
    then its tail, then the other blocks (at least one; fixed layouts, a separator after
    each field); the row's last separator becomes its newline."""
    raw = [t.encode("ascii") for t in tails]
    lengths = np.array([len(t) for t in raw])
    width = int(lengths.max())
    table = np.zeros((len(raw), width), dtype=np.uint8)
    for i, t in enumerate(raw):
        table[i, : len(t)] = np.frombuffer(t, dtype=np.uint8)
    (first, first_keep), rest = blocks[0], blocks[1:]
    n = len(first)
    text = np.concatenate(
        [first.reshape(n, -1), table[inverse]] + [t.reshape(n, -1) for t, _ in rest], axis=1
    )
    keep = np.concatenate([first_keep.reshape(n, -1), np.arange(width) < lengths[inverse, None]]
                          + [k.reshape(n, -1) for _, k in rest], axis=1)  # fmt: skip
    # The last kept byte is the separator after the last field, at the same place in every
    # row (the last block's fields have a fixed layout): it becomes the newline.
    last = keep.shape[1] - 1 - int(np.argmax(rest[-1][1][0, ::-1]))
    text[:, last] = ord("\n")
    return text[keep].tobytes().decode("ascii")


_FLOATS = _ROW[: _ROW.index(",%d") + 1]  # with the comma before the tail
_DIGITS = np.array([int(f[2]) for f in _FLOATS.split(",")[:-1]])  # decimals per float column


def _row_codes(ints: np.ndarray, radix: int) -> tuple[np.ndarray, np.ndarray]:
    """Distinct rows of small non-negative ints (each < radix) as one int64 code each,
    the same in every batch, and each row's index among them (np.unique of rows without
    its slow axis=0 path)."""
    weights = np.int64(radix) ** np.arange(ints.shape[1], dtype=np.int64)
    if radix ** ints.shape[1] >= 2**62 or (ints.size and not 0 <= ints.min() <= ints.max() < radix):
        # too many columns for one code, or values out of range: rows as they are
        rows, inverse = np.unique(ints, axis=0, return_inverse=True)
        return -1 - np.arange(len(rows)), inverse.ravel()  # codes not cached across calls
    codes, inverse = np.unique(ints @ weights, return_inverse=True)
    return codes, inverse.ravel()


def _first_of(inverse: np.ndarray, k: int) -> np.ndarray:
    """For each of k distinct values, the first row that has it."""
    first = np.full(k, len(inverse), dtype=np.int64)
    np.minimum.at(first, inverse, np.arange(len(inverse)))
    return first


def read_csv(text: str) -> dict[str, np.ndarray]:
    """Parse what ``CsvSink`` wrote (for tests, golden files and the plot)."""
    lines = text.strip().splitlines()
    header = lines[0].split(",")
    data = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]]).reshape(
        -1, len(header)
    )
    return {name: data[:, i] for i, name in enumerate(header)}
