"""Pacing: release data stamped t at clock time c0 + (t - t_first) / speed.

Kept apart from parsing and fusion (as python-can keeps its MessageSync apart from its
log readers): the clock and the sleep come in by injection, so tests drive a fake clock
and never sleep, and ``mousedom run --demo`` can pace a replay on the daemon's clock.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import fields

from mousedom.fusion.tracker import PoseBatch


class Pacer:
    """Maps data time onto clock time at ``speed`` times real time."""

    def __init__(
        self,
        speed: float,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if not speed > 0:
            raise ValueError("speed must be positive")
        self.speed = speed
        self.clock = clock
        self.sleep = sleep
        self._t0: float | None = None
        self._c0 = 0.0

    def start(self, t: float, at: float | None = None) -> None:
        """Anchor data time ``t`` at clock time ``at`` (default: now)."""
        self._t0 = float(t)
        self._c0 = self.clock() if at is None else float(at)

    def due(self, t: float) -> float:
        """Clock time at which data stamped ``t`` is due (anchors on first use)."""
        if self._t0 is None:
            self.start(t)
        return self._c0 + (float(t) - self._t0) / self.speed  # type: ignore[operator]

    def data_time(self, clock_time: float) -> float:
        """The inverse of ``due``: data time that is due at ``clock_time``."""
        if self._t0 is None:
            raise RuntimeError("pacer not started")
        return self._t0 + (clock_time - self._c0) * self.speed

    def wait(self, t: float) -> None:
        """Block until data stamped ``t`` is due."""
        delay = self.due(t) - self.clock()
        if delay > 0:
            self.sleep(delay)


def slice_batch(b: PoseBatch, i: int, j: int) -> PoseBatch:
    def part(name: str):
        v = getattr(b, name)
        return None if v is None else v[i:j]

    return PoseBatch(**{f.name: part(f.name) for f in fields(PoseBatch)})


def paced(
    sink: Callable[[PoseBatch], None], pacer: Pacer, flush: Callable[[], None] | None = None
) -> Callable[[PoseBatch], None]:
    """Wrap a sink so each window is handed on when its end time is due."""

    def paced_sink(b: PoseBatch) -> None:
        for i in range(len(b)):
            pacer.wait(float(b.t[i]))
            sink(slice_batch(b, i, i + 1))
            if flush is not None:
                flush()

    return paced_sink
