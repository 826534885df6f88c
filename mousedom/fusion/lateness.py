"""Whether a mouse the screen holds out is late rather than faulty (``Health.LATE``).

A mouse whose counts arrive late (a USB host that stalled past ``late_report_s``, stamps
late by a long tail) reads short by the motion of its last moments, and then catches up:
what it owes, its readings less the others' account of them summed since it was held
out, is minus the motion the others predict for it over its most recent windows, a
prefix of them and a fraction of the next.  Those points form a polyline from 0 through
-p_now, -(p_now + p_prev), ...; a late mouse's debt lies on it, within the windows' error,
until the counts come and the debt returns to 0.  A lifted mouse's debt lies on it too,
but never returns: past ``robust.late_s`` it is excluded.  A jumping mouse, one reading
double or sideways, owes what no lateness explains and is excluded at once.  Only the
motion a mouse was predicted over the last ``late_s`` is looked at: a lag longer than
that is not lateness.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np


def lag_distance2(owed: np.ndarray, recent: np.ndarray) -> float:
    """Squared distance from ``owed`` (2,) to the polyline 0, -recent[0],
    -(recent[0] + recent[1]), ...: the debt of a mouse late by any time within the
    windows whose predicted motions ``recent`` (J, 2) lists, newest first."""
    owed = np.asarray(owed, dtype=float)
    verts = np.concatenate([np.zeros((1, 2)), -np.cumsum(np.asarray(recent, float), axis=0)])
    a, ab = verts[:-1], np.diff(verts, axis=0)
    length2 = np.einsum("ij,ij->i", ab, ab)
    along = np.einsum("ij,ij->i", owed - a, ab)
    f = np.clip(np.divide(along, length2, out=np.zeros_like(along), where=length2 > 0), 0, 1)
    gap = owed - (a + f[:, None] * ab)
    return float(min(np.einsum("ij,ij->i", gap, gap).min(initial=math.inf), owed @ owed))


class Lateness:
    """The predictions of the last windows (what each mouse should have read), and how
    long each mouse has been held as late.  Owned by the screen (``robust.Screen``)."""

    def __init__(self, n: int, window: float, late_s: float) -> None:
        self.limit = max(1, math.ceil(late_s / window - 1e-9))  # windows a mouse may lag
        # predictions of past windows, oldest first: (N, 2) arrays, or the one-window
        # path's lists of [x, y] (converted only when a mouse is judged)
        self.recent: deque[Any] = deque(maxlen=self.limit)
        self.held = [0] * n

    def remember(self, p: Any) -> None:
        self.recent.append(p)

    def remember_rows(self, p_rows: Sequence[Any] | np.ndarray) -> None:
        self.recent.extend(p_rows[-self.limit :])

    def explains(self, i: int, owed: np.ndarray, p_now: np.ndarray, tol2: float) -> bool:
        """Whether mouse i's debt ``owed`` is one of a mouse late by up to ``limit``
        windows (p_now: its predicted motion in this window), within ``tol2``."""
        rows = [np.asarray(p_now, dtype=float)]
        rows += [np.asarray(r, dtype=float).reshape(-1, 2)[i] for r in reversed(self.recent)]
        return lag_distance2(owed, np.array(rows[: self.limit + 1])) <= tol2
