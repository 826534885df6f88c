"""What a replay did, collected while the pose batches stream past: per window counts,
the path, each mouse's health and its reader's statistics (for the summary and the
plot)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mousedom.capture.base import DeviceStats
from mousedom.fusion import robust
from mousedom.fusion.tracker import PoseBatch


def measured_rate(s: DeviceStats) -> float:
    """Reports (or samples) a second between a device's first and last stamp; 0 with
    fewer than two."""
    if s.reports < 2 or s.first_t is None or s.last_t is None or s.last_t <= s.first_t:
        return 0.0
    return (s.reports - 1) / (s.last_t - s.first_t)


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
    late: int = 0  # ... late: held out while its counts were owed (robust.LATE)
    # Those windows by the reason the fusion gave (robust.REASONS' text: count), the most
    # frequent first; a reason never given is left out.
    excluded_why: dict[str, int] = field(default_factory=dict)
    suspect_why: dict[str, int] = field(default_factory=dict)
    scale: tuple[float, float] | None = None  # learnt scale (REL_X, REL_Y) at the end; None:
    # no window had one learnt
    # Seconds the replay subtracted from this capture's times (its epoch offset, 0 for
    # relative and monotonic captures): ``stats`` stays on the capture's own time base,
    # and the captures given together are compared only once on the replay's.
    offset: float = 0.0

    @property
    def reports_per_s(self) -> float:
        """The measured report rate (``rate_hz`` is the config's window rate)."""
        return measured_rate(self.stats)

    @property
    def span(self) -> tuple[float, float] | None:
        """Its first and last report on the replay's time base (the windows'); None: it
        had no report."""
        first, last = self.stats.first_t, self.stats.last_t
        if first is None or last is None:
            return None
        return (first - self.offset, last - self.offset)


@dataclass
class GyroSummary:
    """The replayed gyro: where it came from, its samples, its bias at the end."""

    file: str
    device: str
    stats: DeviceStats  # its samples are the ``reports``
    bias: float | None = None  # rad/s after the last window that had one; None: never
    bias_sigma: float | None = None

    @property
    def samples_per_s(self) -> float:
        return measured_rate(self.stats)


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
    late: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    excluded_why: np.ndarray = field(default_factory=lambda: _no_reasons(0))
    suspect_why: np.ndarray = field(default_factory=lambda: _no_reasons(0))
    scale: np.ndarray | None = None  # (N, 2), None while no window had one learnt
    # The gyro's bias and its sigma (rad/s) after the last window that gave them
    gyro_bias: tuple[float | None, float | None] = (None, None)
    gyro: GyroSummary | None = None  # the replayed gyro (filled in at the end)
    gyro_dropped: bool = False  # the config's gyro was in no capture: replayed without it

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
            self.late = np.zeros(state.shape[1], dtype=np.int64)
            self.excluded_why = _no_reasons(state.shape[1])
            self.suspect_why = _no_reasons(state.shape[1])
        self.excluded += np.count_nonzero(state == robust.EXCLUDED, axis=0)
        self.suspect += np.count_nonzero(state == robust.SUSPECT, axis=0)
        self.late += np.count_nonzero(state == robust.LATE, axis=0)
        # A code the fusion does not name (none should occur) counts as "no reason given".
        reason = np.asarray(b.reason, dtype=np.int64)
        reason = np.where((reason >= 0) & (reason < len(robust.REASONS)), reason, robust.NONE)
        for k in range(len(robust.REASONS)):
            this = reason == k
            self.excluded_why[:, k] += np.count_nonzero(this & (state == robust.EXCLUDED), axis=0)
            self.suspect_why[:, k] += np.count_nonzero(this & (state == robust.SUSPECT), axis=0)
        if b.scale is not None:
            self.scale = np.array(b.scale[-1], dtype=np.float64)
        if b.gyro is not None:
            known = np.flatnonzero(np.isfinite(b.gyro[:, 1]))
            if len(known):
                bias, sigma = b.gyro[known[-1], 1:3]
                self.gyro_bias = (float(bias), float(sigma))
        xs = np.concatenate([[self._last_xy[0]], b.x])
        ys = np.concatenate([[self._last_xy[1]], b.y])
        self.path_length += float(np.hypot(np.diff(xs), np.diff(ys)).sum())
        self._last_xy = (float(b.x[-1]), float(b.y[-1]))
        if self.t_first is None:
            self.t_first = float(b.t[0])
        self.t_last = float(b.t[-1])
        self.final = b.last()

    def health_of(self, mouse: int) -> dict[str, Any]:
        """MouseSummary's health fields of the config's mouse ``mouse``."""
        counted = mouse < len(self.excluded)
        scale = None
        if self.scale is not None:
            scale = (float(self.scale[mouse, 0]), float(self.scale[mouse, 1]))
        return {
            "excluded": int(self.excluded[mouse]) if counted else 0,
            "suspect": int(self.suspect[mouse]) if counted else 0,
            "late": int(self.late[mouse]) if counted else 0,
            "excluded_why": _why(self.excluded_why[mouse]) if counted else {},
            "suspect_why": _why(self.suspect_why[mouse]) if counted else {},
            "scale": scale,
        }

    @property
    def duration(self) -> float:
        """Seconds from the first report of any mouse to the last, on the replay's time
        base: an epoch capture's own stamps are ~1.3e9 s from a relative one's t = 0, and
        only its rebased times (``MouseSummary.offset``) measure the span the windows had
        (the figure ``convert``'s rebased file replays to)."""
        spans = [sp for m in self.mice if (sp := m.span) is not None]
        if not spans:
            return 0.0
        return max(last for _, last in spans) - min(first for first, _ in spans)

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
