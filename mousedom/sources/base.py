"""What every sensor source gives the fusion: batches of motion reports, and its health.

One small base class does the common bookkeeping (counts, rates, last report time); each
backend (evdev, serial ADNS-3080, replay) fills in the hooks ``_open``, ``fileno`` and
``_read``.  The daemon's selectors loop calls ``read`` when ``fileno`` is readable and
hands the returned ``Reports`` to the tracker.  A vanished device raises ``SourceGone``;
the daemon marks the sensor dead and calls ``open`` again later to reattach.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from mousedom import core

# A report's stamp is a time on the host's CLOCK_MONOTONIC, taken at or before the read that
# delivers it.  A stamp beyond these bounds of the read's own time is a fault of the source
# (a FIFO writer's bug, a stream read out of step with its 24-byte records, a clock that
# was stepped): it is re-stamped to the read's time, so its counts are kept, the source's
# health says so, and no window grid is stretched to the far time (a stamp 1e6 s ahead
# once made the daemon close windows for ever).  Behind: a daemon stopped for a while
# (SIGSTOP, a VM pause) reads reports the kernel stamped that long ago, which are true.
STAMP_AHEAD_S = 1.0
STAMP_BEHIND_S = 60.0

# No gyro measures this (MEMS parts reach 70 rad/s, 4000 deg/s): a gyro source drops a
# sample that reads more (a hostile scale attribute, a raw reading out of its range), and
# the native capture format refuses one, so a window's sum of them stays finite.
MAX_RATE = 1e6  # rad/s


def clamp_forward(t: np.ndarray, last: float) -> tuple[np.ndarray, int]:
    """Stamps made non-decreasing (each at least the previous one, starting from ``last``),
    and how many were moved."""
    out = np.maximum.accumulate(np.concatenate([[last], t]))[1:]
    return out, int(np.count_nonzero(out > t))


def bound_stamps(t: list[float], now: float) -> tuple[int, float]:
    """Re-stamp, in place, the stamps of ``t`` outside [now - STAMP_BEHIND_S, now +
    STAMP_AHEAD_S] to ``now``; (how many, the largest distance from ``now``, 0.0 if none).
    Stamps that are not finite numbers count as infinitely far."""
    lo, hi = now - STAMP_BEHIND_S, now + STAMP_AHEAD_S
    # The usual case: one pass each, in C (min and max skip a NaN that is not first: the
    # sum is NaN if any stamp is)
    if t and lo <= min(t) and max(t) <= hi and math.isfinite(sum(t)):
        return 0, 0.0
    n, worst = 0, 0.0
    for i, v in enumerate(t):
        if not lo <= v <= hi:  # NaN fails this too
            n += 1
            off = abs(v - now)
            worst = max(worst, off if off == off else float("inf"))
            t[i] = now
    return n, worst


def clamp_list(t: list[float], last: float) -> int:
    """``clamp_forward`` in place on a list: each stamp raised to at least the previous one
    (starting from ``last``); returns how many were moved."""
    run = last
    for v in t:
        if v < run:
            break
        run = v
    else:
        return 0  # in order (the usual case): nothing written
    run, back = last, 0
    for i, v in enumerate(t):
        if v < run:
            t[i] = run
            back += 1
        else:
            run = v
    return back


def forward_list(t: list[float], now: float, last: float) -> tuple[int, float, int]:
    """``Source._forward``'s rule on a live read's list of stamps, in place: the far ones
    re-stamped (``bound_stamps``: how many, the largest distance), then all made
    non-decreasing from ``last`` (``clamp_list``: how many moved).  In the compiled core
    where it is built (csrc/decode.c); this is its specification."""
    native = core.native
    if native is not None:
        done = native.forward_list(t, now, last, STAMP_BEHIND_S, STAMP_AHEAD_S)
        if done is not None:
            return done
    far, worst = bound_stamps(t, now)
    return far, worst, clamp_list(t, last)


def bound_stamp_array(t: np.ndarray, now: float) -> tuple[np.ndarray, int, float]:
    """``bound_stamps`` for an array (a copy when anything is re-stamped)."""
    lo, hi = now - STAMP_BEHIND_S, now + STAMP_AHEAD_S
    bad = ~((t >= lo) & (t <= hi))
    if not bad.any():
        return t, 0, 0.0
    off = np.abs(t[bad] - now)
    worst = float(np.nanmax(off)) if np.isfinite(off).any() else float("inf")
    if np.isnan(off).any():
        worst = float("inf")
    return np.where(bad, now, t), int(bad.sum()), worst


class SourceUnavailable(Exception):
    """The device cannot be opened now (absent, no permission); retry later."""


class SourceGone(Exception):
    """The device went away while open (ENODEV, EOF, serial error)."""


class Reports:
    """Motion reports of one sensor, in evdev convention, stamped on host CLOCK_MONOTONIC.

    ``dx`` is REL_X (+ = the sensor moved to its right), ``dy`` is REL_Y (+ = it moved
    backwards).  ``t``, ``dx`` and ``dy`` are float64 arrays of one length: counts are
    float so that sources may carry split or scaled counts, but live sources deliver
    integers.

    A live read's few reports may be built ``from_lists``: they are then kept as the
    Python lists the source made, handed on as such by ``columns()`` (``Tracker.push``
    queues lists without numpy), and the arrays are only made if someone asks for them.
    """

    __slots__ = ("mouse", "_t", "_dx", "_dy", "_lists", "quality", "lost_from")

    def __init__(self, mouse: str, t: ArrayLike, dx: ArrayLike, dy: ArrayLike) -> None:
        self.mouse = mouse
        # The sensor's own word on each report, where it has one (the ADNS-3080):
        # (t, SQUAL or None, overflow) lists, for ``Tracker.push_quality``; and, beside
        # them, where counts were lost on the line before a report (packets that never
        # arrived), the time since which (None: none), or None for no such losses.
        self.quality: tuple[list[float], list[Any], list[bool]] | None = None
        self.lost_from: list[float | None] | None = None
        # The arrays, or (from_lists) None until asked for: made from _lists then.
        self._t: np.ndarray | None = np.asarray(t, dtype=np.float64)
        self._dx: np.ndarray | None = np.asarray(dx, dtype=np.float64)
        self._dy: np.ndarray | None = np.asarray(dy, dtype=np.float64)
        self._lists: tuple[list[float], list[Any], list[Any]] | None = None

    @classmethod
    def from_lists(cls, mouse: str, t: list[float], dx: list[Any], dy: list[Any]) -> Reports:
        """Reports from three lists of one length: t floats, dx and dy numbers (ints or
        floats).  The lists are kept, not copied: the caller hands them over."""
        r = cls.__new__(cls)
        r.mouse = mouse
        r.quality = None
        r.lost_from = None
        r._t = r._dx = r._dy = None
        r._lists = (t, dx, dy)
        return r

    @property
    def t(self) -> np.ndarray:
        if self._t is None:
            self._t = self._array(0)
        return self._t

    @property
    def dx(self) -> np.ndarray:
        if self._dx is None:
            self._dx = self._array(1)
        return self._dx

    @property
    def dy(self) -> np.ndarray:
        if self._dy is None:
            self._dy = self._array(2)
        return self._dy

    def _array(self, column: int) -> np.ndarray:
        """A column of ``from_lists``'s lists as an array (an array not yet made)."""
        if self._lists is None:  # __init__ makes all three arrays: never here
            raise RuntimeError("Reports holds neither arrays nor lists")
        return np.array(self._lists[column], dtype=np.float64)

    def columns(self) -> tuple[Any, Any, Any]:
        """(t, dx, dy) as they are held: the lists of ``from_lists``, else the arrays.
        For ``Tracker.push``, which takes either, with no conversion on the way."""
        if self._lists is not None:
            return self._lists
        return self._t, self._dx, self._dy

    def __len__(self) -> int:
        return len(self.columns()[0])

    def __repr__(self) -> str:
        return f"Reports({self.mouse!r}, t={self.t!r}, dx={self.dx!r}, dy={self.dy!r})"


@dataclass
class SourceHealth:
    """What SOURCE status messages say about one sensor."""

    name: str
    kind: str
    connected: bool = False
    reports: int = 0
    last_t: float | None = None
    last_gap: float | None = None  # last_t less the report's before (the wake's plan: not sent)
    reports_per_s: float = 0.0  # over the last second, when a status is made (Source.rate)
    dropped: int = 0  # frames or packets lost (SYN_DROPPED, sequence gaps, CRC errors)
    skipped: int = 0  # events that are not motion (buttons, wheels), counted not used
    error: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)  # e.g. squal, faults for the ADNS

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "connected": self.connected,
            "reports": self.reports,
            "last_t": self.last_t,
            # The wire key stays "rate_hz": the socket protocol is an external contract.
            "rate_hz": round(self.reports_per_s, 3),
            "dropped": self.dropped,
            "skipped": self.skipped,
            "error": self.error,
            **self.extra,
        }


RATE_SPAN_S = 1.0  # the SOURCE status's rate_hz is over this long


class Source(ABC):
    """A sensor the daemon can poll; backends fill in the three hooks."""

    kind = "source"
    # How late a report may reach the reader after its stamp: the daemon's silence rule
    # waits a mouse's report period plus this before it takes the mouse to be still.
    latency = 0.003
    # Read on the daemon's own schedule (a replay hands over each report once due), not
    # when a descriptor is readable; nothing stamped before the read can still come.
    paced = False
    # Read at every wake of the daemon even when its descriptor is not readable: a device
    # whose removal its descriptor does not report (an IIO buffer's poll says nothing once
    # the device is unregistered; only a read says ENODEV), so that a read finds out.
    probe = False
    # Whether what is open has shown itself to be the sensor (a serial port may hold
    # another device): until then the daemon reads it but does not fuse it (slots.py).
    answered = True
    # A backend that bounds its stamps itself (before a rule of its own that needs them
    # bounded, as evdev's forward clamp) says so; read() then does not do it again.
    bounds_own_stamps = False

    def __init__(self, name: str) -> None:
        self.name = name
        self.health = SourceHealth(name=name, kind=self.kind)
        # The reads of the last RATE_SPAN_S, (when, reports), for ``rate``; and the first
        # read's time (the first second's rate is over the time since it)
        self._reads: deque[tuple[float, int]] = deque()
        self._first_read: float | None = None
        self.stamps_restamped = 0  # reports whose stamp was far from the clock (see above)
        # Stamps are made non-decreasing at the boundary (``_forward``): the tracker and
        # the capture format rely on it.  A kernel clock does not run backwards, but a FIFO
        # writer's, a driver's or a replug's restarted stream's stamps can.
        self._last_t = -math.inf  # the last stamp handed over
        self.time_backwards = 0  # reports stamped before the one before (moved forward)

    def _forward(self, stamps: np.ndarray, now: float) -> np.ndarray:
        """A read's stamps as handed over: far ones re-stamped to ``now`` first (one must
        not become the floor every later stamp is raised to), then each raised to at least
        the one before it, from the last handed over; counted (``stamps_restamped``,
        ``time_backwards``)."""
        bounded, n_far, worst = bound_stamp_array(stamps, now)
        self._far_stamps(n_far, worst)
        t, back = clamp_forward(bounded, self._last_t)
        self.time_backwards += back
        self._last_t = float(t[-1])
        return t

    def _far_stamps(self, n: int, worst: float) -> None:
        """Count re-stamped reports and say so in the health (SOURCE, the log once)."""
        if not n:
            return
        first = not self.stamps_restamped
        self.stamps_restamped += n
        self.health.extra["stamps_restamped"] = self.stamps_restamped
        self.health.error = (
            f"{self.stamps_restamped} report(s) stamped far from the clock (up to "
            f"{worst:.3g} s): re-stamped on arrival, counts kept"
        )
        if first:
            import logging

            logging.getLogger(__name__).warning("%s: %s", self.name, self.health.error)

    def open(self) -> None:
        """Open (or reopen) the device; raises SourceUnavailable when it is not there."""
        try:
            self._open()
        except SourceUnavailable as e:
            self.health.connected = False
            self.health.error = str(e)
            raise
        self.health.connected = True
        self.health.error = None
        self.health.last_gap = None  # (a reopened device's reports start again)

    def read(self, now: float) -> list[Reports]:
        """Read what is ready; raises SourceGone when the device vanished."""
        try:
            batches = self._read(now)
        except SourceGone as e:
            self.health.connected = False
            self.health.error = str(e) or "device gone"
            self.close()
            raise
        for b in batches:
            t = b.columns()[0]
            n = len(t)
            if not n:
                continue
            if not self.bounds_own_stamps:
                if type(t) is list:
                    n_far, worst = bound_stamps(t, now)
                else:
                    b._t, n_far, worst = bound_stamp_array(t, now)
                    t = b._t
                if n_far:
                    self._far_stamps(n_far, worst)
                    if b.quality is not None:  # the sensor's word on the same reports
                        bound_stamps(b.quality[0], now)
                if b.lost_from is not None and any(v is not None for v in b.lost_from):
                    # where counts were lost since: a stamp too, held to the same bounds
                    # (a span reaching back a day would gate the mouse to its frontier)
                    since = [v for v in b.lost_from if v is not None]
                    bound_stamps(since, now)
                    it = iter(since)
                    b.lost_from[:] = [None if v is None else next(it) for v in b.lost_from]
            self._count(n, float(t[-1]), now, float(t[-2]) if n > 1 else None)
        return batches

    def _count(self, n: int, last_t: float, now: float, before: float | None = None) -> None:
        """``n`` reports read at ``now``, the last stamped ``last_t`` (``before``: the one
        before it, where the read held both): the health's counts, last stamp and the
        interval before it, and the read for the report rate (``rate``)."""
        health = self.health
        health.reports += n
        # (a read of several reports without the one before the last says nothing of it:
        # the gyro's sources, whose samples the wake's plan takes on their period)
        prev = before if before is not None else health.last_t if n == 1 else None
        health.last_gap = None if prev is None else last_t - prev
        health.last_t = last_t
        reads = self._reads
        reads.append((now, n))
        if reads[0][0] <= now - RATE_SPAN_S:
            self._drop_reads(now)
        if self._first_read is None:
            self._first_read = now

    def _drop_reads(self, now: float) -> None:
        reads = self._reads
        while reads and reads[0][0] <= now - RATE_SPAN_S:
            reads.popleft()

    def rate(self, now: float) -> float:
        """Reports per second read over the last RATE_SPAN_S before ``now`` (over the time
        since the first read while that is shorter, at least a tenth of a second): 0 a
        second after the mouse stopped or went, as its status must say, where a rate
        updated only by reads kept the last one for good."""
        self._drop_reads(now)
        if self._first_read is None:
            return 0.0
        span = min(RATE_SPAN_S, max(now - self._first_read, 0.1))
        return sum(n for _, n in self._reads) / span

    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def fileno(self) -> int: ...

    @abstractmethod
    def _read(self, now: float) -> list[Reports]: ...

    def identity(self) -> str | None:
        """The device this source has open, symlinks followed (None: not a device that
        two sources could share).  The daemon refuses a second mouse on the same one."""
        return None

    def close(self) -> None:  # noqa: B027 (an optional hook, not abstract)
        """Release the device; safe to call twice."""
