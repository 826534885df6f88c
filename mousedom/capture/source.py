"""A capture replayed as a live source, paced on an injected clock (``run --demo``).

    src = ReplaySource("left", "demo.mdcap", device=None, speed=1.0, loop=True,
                       clock=time.monotonic)
    src.open()
    ... in the selectors loop:
    timeout = src.timeout(now)          # seconds until the next report is due, or None
    batches = src.read(now)             # every report due by ``now``, restamped on the clock

Report times are restamped: a report recorded at t is due at clock time
c0 + (t - t_first) / speed, where c0 is the clock at ``open()``; that due time is its
stamp, so the tracker sees a live-looking stream.  With ``loop`` the capture starts again
after its end (one report period later), times continuing.

A replay has no file descriptor that becomes readable: ``fileno()`` returns -1, which
tells the daemon's loop to poll the source on every tick (``read(now)`` returns what is
due).  A loop of its own can instead use ``timeout(now)`` (or ``next_due()``) as its
select timeout.

Several mice replayed from one file stay aligned: every ReplaySource of the same file and
clock shares one anchor (the clock time at which the first of them opened, and the
file's first event), and with ``loop`` they all restart after the file's overall last
report, not their own.  Built from a ``MouseConfig`` (as the daemon does, for mice with
``replay:`` in the config), a source loops by default.

``GyroReplaySource`` replays a capture's gyro the same way (``gyro: replay:``), its
``read`` giving ``GyroSamples`` as the IIO source does: the recorded rates have the mount's
axis and sign applied already.  Mice and gyro of one file share the anchor and restart
together.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator

import numpy as np

from mousedom.capture.assignment import gyro_devices
from mousedom.capture.base import Capture, CaptureError
from mousedom.capture.sniff import open_capture
from mousedom.config import GyroConfig, MouseConfig
from mousedom.sources.base import Reports, Source, SourceGone, SourceUnavailable
from mousedom.sources.iio import GyroSamples

# (file, clock) -> (clock time, data time) at which the first replay of that file started.
_ANCHORS: dict[tuple[str, int], tuple[float, float]] = {}
# A source opened on an anchor from before (a reload that changed its file and back, a
# retry after it was lost) goes on where the anchor says, as a device plugged back in
# would: the reports due while it was closed are not delivered.  All at once they were
# re-stamped on arrival, 2,990 reports of 294 s in one window (a jump).  Those due in
# the last second are delivered: the mice of one file opened one after the other at the
# start, milliseconds apart, keep every report.
REOPEN_SKIP_S = 1.0


class ReplaySource(Source):
    kind = "replay"
    paced = True  # reports are handed over once due: nothing older can still arrive

    def __init__(
        self,
        name: str | MouseConfig,
        path: str | None = None,
        device: str | None = None,
        speed: float = 1.0,
        loop: bool | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if isinstance(name, MouseConfig):
            mouse = name
            name, path = mouse.name, path or mouse.replay
            device = device if device is not None else mouse.replay_device
            loop = True if loop is None else loop
        if path is None:
            raise ValueError("a replay source needs a capture file")
        super().__init__(name)
        if not speed > 0:
            raise ValueError("speed must be positive")
        self.path = path
        self.device = device
        self.speed = float(speed)
        self.loop = bool(loop)
        self.clock = clock
        self._capture: Capture | None = None
        self._dev = 0
        self._it: Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
        self._buf_t = np.empty(0)
        self._skip_before = -math.inf  # (set at open: REOPEN_SKIP_S)
        self._buf_dx = np.empty(0)
        self._buf_dy = np.empty(0)
        self._c0 = 0.0
        self._t_first: float | None = None
        self._shift = 0.0  # data seconds added by earlier loops
        self._span = 0.0
        self._period = 0.008
        self.finished = False

    # ----------------------------------------------------------------- Source hooks

    def _open(self) -> None:
        if not os.path.exists(self.path):
            raise SourceUnavailable(f"{self.path}: capture file not found")
        cap = open_capture(self.path)
        self._dev = self._pick(cap)
        self._capture = cap
        first = cap.first_time()
        key = (os.path.realpath(self.path), id(self.clock))
        if key not in _ANCHORS or first is None:
            _ANCHORS[key] = (self.clock(), first if first is not None else math.nan)
        self._c0, t_first = _ANCHORS[key]
        self._t_first = None if math.isnan(t_first) else t_first
        self._skip_before = self.clock() - REOPEN_SKIP_S
        self._shift = 0.0
        self._span = self._overall_span(cap) if self.loop else 0.0
        self.finished = False
        self._restart()

    def _overall_span(self, cap: Capture) -> float:
        """Data seconds from the file's first event to its last report, any device."""
        last = -math.inf
        periods = []
        for feed in cap.feeds():
            for batch in feed.batches:
                stamps = [mo.t for mo in batch.motion] + [r.t for r in batch.gyro]
                for t in stamps:
                    if len(t):
                        last = max(last, float(t[-1]))
                    if len(t) > 1:
                        periods.append(float(np.median(np.diff(t[:1000]))))
        # The same gap for every mouse of the file, so that they restart together.
        periods = [p for p in periods if p > 0]
        if periods:
            self._period = min(periods)
        first = cap.first_time()
        return last - first if first is not None and math.isfinite(last) else 0.0

    def _pick(self, cap: Capture) -> int:
        movers = [i for i, d in enumerate(cap.devices) if d.rel_xy is not False]
        if self.device is not None:
            # By name or by recorded node (identical mice share a name), as `replay` does.
            hits = [
                i
                for i in movers
                if self.device in (cap.devices[i].name, cap.devices[i].extra.get("node"))
            ]
        else:
            hits = [i for i in movers if cap.devices[i].mouse == self.name]
            if not hits:
                hits = [i for i in movers if cap.devices[i].name == self.name]
            if not hits and len(movers) == 1:
                hits = movers
        if len(hits) != 1:
            names = ", ".join(repr(cap.devices[i].name) for i in movers)
            raise CaptureError(
                f"{self.path}: cannot tell which device is mouse {self.name!r} "
                f"(devices: {names}); name it with device="
            )
        return hits[0]

    def _restart(self) -> None:
        assert self._capture is not None
        feeds = [f for f in self._capture.feeds() if self._dev in f.devices]
        self._it = self._reports(feeds[0].batches) if feeds else iter(())

    def _reports(self, batches) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        for batch in batches:
            for mo in batch.motion:
                if mo.device == self._dev and len(mo.t):
                    yield mo.t, mo.dx, mo.dy

    def fileno(self) -> int:
        return -1  # nothing to select on: poll on every tick, or wait for timeout()

    def close(self) -> None:
        self._capture = None
        self._it = None

    def _read(self, now: float) -> list[Reports]:
        rows = self._due_rows(now)
        return [] if rows is None else [Reports(self.name, *rows)]

    def _due_rows(self, now: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Every report due by ``now``, restamped: (t, dx, dy), or None."""
        if self._capture is None:
            raise SourceGone("replay not open")
        parts_t, parts_dx, parts_dy = [], [], []
        while True:
            if not len(self._buf_t) and not self._fill():
                break
            due = self._due(self._buf_t)
            gone = int(np.searchsorted(due, self._skip_before, side="left"))
            if gone:  # due while the source was closed (REOPEN_SKIP_S)
                self._buf_t, self._buf_dx, self._buf_dy = (
                    a[gone:] for a in (self._buf_t, self._buf_dx, self._buf_dy)
                )
                continue
            k = int(np.searchsorted(due, now, side="right"))
            if k:
                parts_t.append(due[:k])
                parts_dx.append(self._buf_dx[:k])
                parts_dy.append(self._buf_dy[:k])
                self._buf_t = self._buf_t[k:]
                self._buf_dx = self._buf_dx[k:]
                self._buf_dy = self._buf_dy[k:]
            if len(self._buf_t):
                break
        if not parts_t:
            return None
        return np.concatenate(parts_t), np.concatenate(parts_dx), np.concatenate(parts_dy)

    # ----------------------------------------------------------------- pacing

    def _due(self, t: np.ndarray) -> np.ndarray:
        # Reports are buffered only once _fill has taken the first one's time.
        assert self._t_first is not None
        return self._c0 + (t + self._shift - self._t_first) / self.speed

    def _fill(self) -> bool:
        """Load the next reports into the buffer; False at the very end."""
        assert self._it is not None
        for _ in range(2):
            part = next(self._it, None)
            if part is not None:
                t, dx, dy = part
                if self._t_first is None:
                    self._t_first = float(t[0])
                self._buf_t, self._buf_dx, self._buf_dy = t, dx, dy
                return True
            if not self.loop or self._t_first is None:
                self.finished = True
                return False
            # Start again one report period after the end, times continuing.
            self._shift += self._span + self._period
            self._restart()
        self.finished = True
        return False

    def next_due(self) -> float | None:
        """Clock time at which the next report is due; None when the replay is over."""
        if self._capture is None:
            return None
        if not len(self._buf_t) and not self._fill():
            return None
        return float(self._due(self._buf_t[:1])[0])

    def timeout(self, now: float | None = None) -> float | None:
        """Seconds to wait before ``read`` has something (0: now), None when over."""
        due = self.next_due()
        if due is None:
            return None
        now = self.clock() if now is None else now
        return max(0.0, due - now) if math.isfinite(due) else None


class GyroReplaySource(ReplaySource):
    """A capture's gyro as the rig's gyro, paced on the clock (``gyro: replay:``): ``read``
    gives ``GyroSamples`` (stamps restamped as the mice's, rates as recorded)."""

    kind = "replay"

    def __init__(
        self,
        gyro: GyroConfig,
        name: str = "gyro",
        loop: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if gyro.replay is None:
            raise ValueError("a gyro replay needs gyro.replay")
        super().__init__(name, gyro.replay, device=gyro.replay_device, loop=loop, clock=clock)

    def _pick(self, cap: Capture) -> int:
        gyros = gyro_devices(cap, self.device)  # as `mousedom replay` picks it (find_gyro)
        if len(gyros) != 1:
            held = ", ".join(repr(cap.devices[i].name) for i in gyro_devices(cap))
            if not held:
                raise CaptureError(f"{self.path}: gyro.replay: the capture holds no gyro")
            raise CaptureError(
                f"{self.path}: cannot tell which device is the gyro (gyros: {held}); "
                "name it with gyro.replay.device"
            )
        return gyros[0]

    def _reports(self, batches) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        for batch in batches:
            for r in batch.gyro:
                if r.device == self._dev and len(r.t):
                    sat = np.zeros(len(r.t), bool) if r.saturated is None else r.saturated
                    yield r.t, r.rate, sat

    def read(self, now: float) -> list[GyroSamples]:  # type: ignore[override]
        """The samples due by ``now`` (the health counted as for any source)."""
        try:
            rows = self._due_rows(now)
        except SourceGone as e:
            self.health.connected = False
            self.health.error = str(e)
            raise
        if rows is None:
            return []
        t, rate, sat = rows
        self._count(len(t), float(t[-1]), now)
        saturated = np.asarray(sat, dtype=bool)
        return [GyroSamples(self.name, t, np.asarray(rate, dtype=float),
                            saturated if saturated.any() else None)]  # fmt: skip
