"""Map the downsampler's microsecond clock onto host CLOCK_MONOTONIC.  Pure: time is data.

A packet stamped ``f`` by the firmware (seconds, unwrapped) reaches the host at
``h = f + offset(f) + delay`` where the transport delay (UART, USB, scheduling) is never
negative.  So ``h - f`` is an upper bound of the offset, and the lower envelope of those
points is the offset itself.  The crystals of the two clocks differ by up to a few hundred
ppm, so the offset is a line, not a constant: ``offset(f) = a + b f``.

The estimate is the line under all points of a sliding window that is closest to them
on average (it touches the lower convex hull at the points' mean firmware time; that is
the line minimising the summed distance to the points while staying under them).  To keep
the cost flat, each ``bucket`` seconds of points is reduced to its lowest point first.
Until the window spans ``min_span`` seconds the drift is taken as zero.  Outputs never go
backwards and are never later than the arrival time of the packet they belong to.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

WRAP = 1 << 32  # the firmware's 32-bit microsecond counter


def went_back(last_us: int, t_us: int) -> bool:
    """``t_us`` is earlier than ``last_us`` on the firmware clock, and not by a wrap (a
    wrap moves it back by more than half the counter): the firmware restarted."""
    return 0 < last_us - t_us <= WRAP // 2


@dataclass
class FirmwareClock:
    """Unwraps the firmware's 32-bit microsecond stamps into seconds since its boot."""

    _last_raw: int | None = None
    _epoch: int = 0

    def unwrap(self, t_us: int) -> float:
        """Seconds; a step backwards of more than half the range is a wrap."""
        if self._last_raw is not None and t_us < self._last_raw:
            if self._last_raw - t_us > WRAP // 2:
                self._epoch += WRAP
        self._last_raw = t_us
        return (self._epoch + t_us) * 1e-6

    def is_backwards(self, t_us: int) -> bool:
        """True when ``t_us`` is earlier than the last stamp (and not a wrap): a reboot."""
        return self._last_raw is not None and went_back(self._last_raw, t_us)

    def reset(self) -> None:
        self._last_raw, self._epoch = None, 0


@dataclass
class _Bucket:
    index: int
    f: float
    off: float  # host - firmware of the lowest point


class ClockSync:
    """Firmware seconds -> host seconds with a minimum-offset filter that tracks drift."""

    def __init__(
        self,
        window: float = 60.0,
        bucket: float = 0.5,
        min_span: float = 5.0,
        max_drift: float = 1e-3,
    ) -> None:
        if not (window > 0 and bucket > 0 and window >= bucket):
            raise ValueError("window and bucket must be positive, window >= bucket")
        self.window, self.bucket = window, bucket
        self.min_span, self.max_drift = min_span, max_drift
        self._last_out: float | None = None
        self.reset()

    def reset(self) -> None:
        """Forget the fit (the firmware restarted: its clock began again).  The last output
        stays the floor: host times never step back, not even by the rounding of a fresh
        single-point fit (which once gave an output 1e-13 s before the previous one)."""
        self._buckets: deque[_Bucket] = deque()
        self._a = 0.0  # offset at f = 0
        self._b = 0.0  # drift (host seconds gained per firmware second)
        self.samples = 0

    @property
    def drift(self) -> float:
        return self._b

    def offset(self, f: float) -> float:
        return self._a + self._b * f

    def update(self, f: float, host_t: float) -> float:
        """Add one observation (firmware ``f`` s, arrival ``host_t`` s); return ``f`` on
        the host clock."""
        self.samples += 1
        off = host_t - f
        index = int(f // self.bucket)
        if self._buckets and self._buckets[-1].index == index:
            last = self._buckets[-1]
            changed = off < last.off
            if changed:
                last.f, last.off = f, off
        else:
            self._buckets.append(_Bucket(index, f, off))
            changed = True
            while self._buckets and self._buckets[0].f < f - self.window:
                self._buckets.popleft()
        if changed or len(self._buckets) == 1:
            self._fit()
        # The line is under every point of the window, the current one included, so
        # the estimate never lies after the arrival; the max() keeps it monotonic.
        out = min(f + self.offset(f), host_t)
        if self._last_out is not None and out < self._last_out:
            out = self._last_out
        self._last_out = out
        return out

    def _fit(self) -> None:
        pts = [(b.f, b.off) for b in self._buckets]
        if len(pts) < 2 or pts[-1][0] - pts[0][0] < self.min_span:
            self._b = 0.0 if len(pts) < 2 else self._b
            self._a = min(o - self._b * x for x, o in pts)
            return
        hull = _lower_hull(pts)
        mean_f = sum(x for x, _ in pts) / len(pts)
        slope = 0.0
        for (x0, y0), (x1, y1) in zip(hull, hull[1:], strict=False):
            if x0 <= mean_f <= x1:
                slope = (y1 - y0) / (x1 - x0) if x1 > x0 else 0.0
                break
        slope = max(-self.max_drift, min(self.max_drift, slope))
        self._b = slope
        self._a = min(o - slope * x for x, o in pts)


def _lower_hull(pts: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Lower convex hull of points sorted by x (Andrew's monotone chain)."""
    hull: list[tuple[float, float]] = []
    for p in pts:
        while len(hull) >= 2:
            (x1, y1), (x2, y2) = hull[-2], hull[-1]
            if (x2 - x1) * (p[1] - y1) - (y2 - y1) * (p[0] - x1) <= 0:
                hull.pop()
            else:
                break
        hull.append(p)
    return hull
