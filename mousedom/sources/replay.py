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

A replay has no file descriptor that becomes readable.  ``fileno()`` returns the read end
of a private pipe that never does, so registering it is harmless; the loop must use
``timeout()`` (or ``next_due()``) as its select timeout and call ``read(now)`` when it
has passed.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator

import numpy as np

from mousedom.capture import Capture, CaptureError, open_capture
from mousedom.sources.base import Reports, Source, SourceGone, SourceUnavailable


class ReplaySource(Source):
    kind = "replay"

    def __init__(
        self,
        name: str,
        path: str,
        device: str | None = None,
        speed: float = 1.0,
        loop: bool = False,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(name)
        if not speed > 0:
            raise ValueError("speed must be positive")
        self.path = path
        self.device = device
        self.speed = float(speed)
        self.loop = loop
        self.clock = clock
        self._pipe: tuple[int, int] | None = None
        self._capture: Capture | None = None
        self._dev = 0
        self._it: Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
        self._buf_t = np.empty(0)
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
        self._c0 = self.clock()
        self._t_first = None
        self._shift = 0.0
        self.finished = False
        self._restart()
        if self._pipe is None:
            self._pipe = os.pipe()

    def _pick(self, cap: Capture) -> int:
        movers = [i for i, d in enumerate(cap.devices) if d.rel_xy is not False]
        if self.device is not None:
            hits = [i for i in movers if cap.devices[i].name == self.device]
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
        if self._pipe is None:
            self._pipe = os.pipe()
        return self._pipe[0]

    def close(self) -> None:
        if self._pipe is not None:
            for fd in self._pipe:
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._pipe = None

    def _read(self, now: float) -> list[Reports]:
        if self._capture is None:
            raise SourceGone("replay not open")
        parts_t, parts_dx, parts_dy = [], [], []
        while True:
            if not len(self._buf_t) and not self._fill():
                break
            due = self._due(self._buf_t)
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
            return []
        return [
            Reports(
                self.name,
                np.concatenate(parts_t),
                np.concatenate(parts_dx),
                np.concatenate(parts_dy),
            )
        ]

    # ----------------------------------------------------------------- pacing

    def _due(self, t: np.ndarray) -> np.ndarray:
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
                if len(t) > 1:
                    self._period = float(np.median(np.diff(t[:1000]))) or self._period
                self._span = max(self._span, float(t[-1]) - self._t_first)
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
