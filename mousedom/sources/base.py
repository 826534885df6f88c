"""What every sensor source gives the fusion: batches of motion reports, and its health.

One small base class does the common bookkeeping (counts, rates, last report time); each
backend (evdev, serial ADNS-3080, replay) fills in the hooks ``_open``, ``fileno`` and
``_read``.  The daemon's selectors loop calls ``read`` when ``fileno`` is readable and
hands the returned ``Reports`` to the tracker.  A vanished device raises ``SourceGone``;
the daemon marks the sensor dead and calls ``open`` again later to reattach.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np


class SourceUnavailable(Exception):
    """The device cannot be opened now (absent, no permission); retry later."""


class SourceGone(Exception):
    """The device went away while open (ENODEV, EOF, serial error)."""


@dataclass
class Reports:
    """Motion reports of one sensor, in evdev convention, stamped on host CLOCK_MONOTONIC.

    ``dx`` is REL_X (+ = the sensor moved to its right), ``dy`` is REL_Y (+ = it moved
    backwards).  Counts are float64 so that sources may carry split or scaled counts, but
    live sources deliver integers.
    """

    mouse: str
    t: np.ndarray
    dx: np.ndarray
    dy: np.ndarray

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=np.float64)
        self.dx = np.asarray(self.dx, dtype=np.float64)
        self.dy = np.asarray(self.dy, dtype=np.float64)

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class SourceHealth:
    """What SOURCE status messages say about one sensor."""

    name: str
    kind: str
    connected: bool = False
    reports: int = 0
    last_t: float | None = None
    rate_hz: float = 0.0
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
            "rate_hz": round(self.rate_hz, 3),
            "dropped": self.dropped,
            "skipped": self.skipped,
            "error": self.error,
            **self.extra,
        }


class Source(ABC):
    """A sensor the daemon can poll; backends fill in the three hooks."""

    kind = "source"

    def __init__(self, name: str) -> None:
        self.name = name
        self.health = SourceHealth(name=name, kind=self.kind)
        self._rate_t0: float | None = None
        self._rate_n = 0

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
            self._count(b, now)
        return batches

    def _count(self, batch: Reports, now: float) -> None:
        n = len(batch)
        if not n:
            return
        self.health.reports += n
        self.health.last_t = float(batch.t[-1])
        # Report rate over a sliding ~1 s span: cheap and good enough for status.
        if self._rate_t0 is None or now - self._rate_t0 > 1.0:
            if self._rate_t0 is not None and now > self._rate_t0:
                self.health.rate_hz = self._rate_n / (now - self._rate_t0)
            self._rate_t0, self._rate_n = now, 0
        self._rate_n += n

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
