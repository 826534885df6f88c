"""What a sensor says about its own reports (the ADNS-3080's SQUAL and overflow flag),
turned into per-window evidence for the fault-tolerant screen (``robust``).

A report covers the same span the tracker gives its counts: [t - P, t] for a report
period P.  Only notable reports are kept (SQUAL below ``robust.SQUAL_FULL``, or counts
lost to an overflow), so a healthy sensor costs nothing per window.  For a window, the
lowest SQUAL of the reports overlapping it and any overflow decide:
- ``low_quality``: an overflow, or SQUAL below the mouse's ``min_squal``: gated;
- ``scale``: SQUAL_FULL / SQUAL (>= 1) multiplies the mouse's expected error floor: fewer
  features, a noisier correlation.
"""

from __future__ import annotations

import math

import numpy as np

SQUAL_FULL = 30  # from this SQUAL on, the noise is as configured


class SensorEvidence:
    def __init__(self, periods: list[float], min_squal: list[int | None]) -> None:
        self.periods = list(periods)
        self.min_squal = [0 if m is None else m for m in min_squal]
        self.spans: list[list[tuple[float, float, float, bool]]] = [[] for _ in periods]

    def __bool__(self) -> bool:
        return any(self.spans)

    def push(
        self, mouse: int, t: list, squal: list, overflow: list, lost_from: list | None = None
    ) -> None:
        """Reports' stamps, SQUAL (None: unknown), whether counts were lost, and where
        they were lost on the way before a report (packets that never arrived), the time
        since which (None: none): that report's span reaches back to it."""
        period = self.periods[mouse]
        keep = self.spans[mouse]
        since = lost_from if lost_from is not None else [None] * len(t)
        for ti, sq, ov, lf in zip(t, squal, overflow, since, strict=True):
            if ov or (sq is not None and sq < SQUAL_FULL):
                q = math.inf if sq is None else float(sq)
                start = float(ti) - period
                if lf is not None:
                    start = min(start, float(lf))
                keep.append((start, float(ti), q, bool(ov)))

    def _judge(self, mouse: int, squal: float, overflow: bool) -> tuple[float, bool]:
        low = overflow or squal < self.min_squal[mouse]
        scale = SQUAL_FULL / max(squal, 1.0) if squal < SQUAL_FULL else 1.0
        return scale, low

    def window(self, start: float, end: float) -> tuple[list[float], list[bool]] | None:
        """(scale, low_quality) per mouse for the window [start, end], or None if no
        notable report touches it.  Spans that end before ``start`` are dropped."""
        out = None
        for i, spans in enumerate(self.spans):
            if not spans:
                continue
            spans[:] = [s for s in spans if s[1] > start]
            hits = [s for s in spans if s[0] < end]
            if hits:
                if out is None:
                    out = ([1.0] * len(self.spans), [False] * len(self.spans))
                squal = min(s[2] for s in hits)
                out[0][i], out[1][i] = self._judge(i, squal, any(s[3] for s in hits))
        return out

    def windows(self, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``window`` for consecutive windows between ``edges`` (n + 1,): (n, N) arrays."""
        n = len(edges) - 1
        if n <= 0 or not self:
            return None
        scale = np.ones((n, len(self.spans)))
        low = np.zeros((n, len(self.spans)), dtype=bool)
        for i, spans in enumerate(self.spans):
            spans[:] = [s for s in spans if s[1] > edges[0]]
            for a, b, squal, ov in spans:
                k0 = max(0, int(np.searchsorted(edges, a, side="right")) - 1)
                k1 = min(n, int(np.searchsorted(edges, b, side="left")))
                for k in range(k0, k1):
                    if a < edges[k + 1] and b > edges[k]:
                        sc, lo = self._judge(i, squal, ov)
                        scale[k, i] = max(scale[k, i], sc)
                        low[k, i] |= lo
        return scale, low
