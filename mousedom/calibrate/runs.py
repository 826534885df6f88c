"""Cutting recordings into runs at idle gaps, and into time windows.

A calibration session is a sequence of runs (one push, one turn, one drive) separated by
pauses.  A rig moves as one body, so the runs are found on the union of every mouse's
motion reports: a new run starts where no mouse reported motion for longer than ``gap``.

A report stamped t covers the motion since the device's previous report where that came
within a bridge (the config's late_report_s: a USB host's catch-up report after skipped
polls), else one report period back (it starts again after a rest): the fusion's rule
(``fusion.countfunction``; DESIGN.md's "one period back" put a 30 ms catch-up's counts in
its last 8 ms, across window edges).  ``window_counts`` spreads each report uniformly over
that span, so that windows cut anywhere get the counts that belong to them, and the window
sums still add up exactly to the totals (no count is lost).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from mousedom.errors import UserError
from mousedom.fusion.countfunction import CountFunction
from mousedom.sources.base import Reports


@dataclass(frozen=True)
class Run:
    """One run: the first and last motion report stamps (seconds)."""

    t0: float
    t1: float

    @property
    def duration(self) -> float:
        return self.t1 - self.t0


def in_time_order(
    name: str, ts: Sequence[np.ndarray], dxs: Sequence[np.ndarray], dys: Sequence[np.ndarray]
) -> Reports:
    """Pieces of one mouse's reports as one ``Reports``, stably sorted by stamp."""
    if not ts:
        return Reports(name, np.zeros(0), np.zeros(0), np.zeros(0))
    t = np.concatenate(ts)
    order = np.argsort(t, kind="stable")
    return Reports(name, t[order], np.concatenate(dxs)[order], np.concatenate(dys)[order])


def moving(rep: Reports) -> np.ndarray:
    """Stamps of the reports of ``rep`` that carry motion."""
    keep = (np.asarray(rep.dx) != 0) | (np.asarray(rep.dy) != 0)
    return np.asarray(rep.t, dtype=float)[keep]


def split_runs(recording: Mapping[str, Reports], gap: float = 0.5) -> list[Run]:
    """Runs of motion over all mice, split where every mouse was still for > ``gap`` s."""
    if gap <= 0:
        raise ValueError("gap must be positive")
    stamps = [moving(rep) for rep in recording.values()]
    t = np.sort(np.concatenate(stamps)) if stamps else np.zeros(0)
    if len(t) == 0:
        return []
    breaks = np.flatnonzero(np.diff(t) > gap)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(t) - 1]])
    return [Run(float(t[a]), float(t[b])) for a, b in zip(starts, ends, strict=True)]


def run_counts(
    recording: Mapping[str, Reports], runs: Sequence[Run], names: Sequence[str]
) -> np.ndarray:
    """(n_runs, N, 2) counts (REL_X, REL_Y) summed per run and mouse, in ``names`` order.

    Every report with a stamp inside [t0, t1] of a run belongs to it: runs are separated
    by idle gaps, so no motion report falls between two runs.
    """
    out = np.zeros((len(runs), len(names), 2))
    if not runs:
        return out
    t0 = np.array([r.t0 for r in runs])
    t1 = np.array([r.t1 for r in runs])
    for j, name in enumerate(names):
        rep = recording[name]
        t = np.asarray(rep.t, dtype=float)
        k = np.searchsorted(t0, t, side="right") - 1  # the run that starts at or before t
        inside = (k >= 0) & (t <= t1[np.clip(k, 0, None)])
        for axis, values in enumerate((rep.dx, rep.dy)):
            v = np.asarray(values, dtype=float)
            np.add.at(out[:, j, axis], k[inside], v[inside])
    return out


def cumulative(
    t: np.ndarray, values: np.ndarray, period: float, bridge: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Knots (x, y) of the piecewise-linear cumulative sum of ``values`` over time.

    The fusion's rule (``fusion.countfunction``, docs/models.md "Timing is not a fault"),
    so that a calibration and the fusion count a report where it was measured alike: a
    report rises linearly over the time since its mouse's previous report where that was
    at most ``bridge`` seconds before (a USB host's catch-up report after skipped polls, a
    mouse creeping along), else over one report ``period`` (the first report after a rest);
    a report stamped under half a period after the one before (held up on its way) joins
    that report's span.  ``bridge`` 0: one period at most, as before (DESIGN.md).
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(values, dtype=float)
    if len(t) and np.any(np.diff(t) < 0):
        raise ValueError("report stamps must be non-decreasing")
    if len(t) == 0:
        return np.array([0.0]), np.array([0.0])
    f = CountFunction(period, bridge)
    f.queue(t, v, np.zeros_like(v), float(t[-1]))
    f.ingest(-math.inf)
    knots = f.knot_array()
    return knots[0], knots[1]


def window_counts(
    t: np.ndarray, values: np.ndarray, edges: np.ndarray, period: float, bridge: float = 0.0
) -> np.ndarray:
    """Counts per window (edges[k], edges[k+1]], each report spread over its span
    (``cumulative``)."""
    return _windows(*cumulative(t, values, period, bridge), edges)


def runs_window_counts(
    t: np.ndarray,
    values: np.ndarray,
    edges: Sequence[np.ndarray],
    period: float,
    bridge: float = 0.0,
) -> np.ndarray:
    """``window_counts`` for every run's edges, concatenated; the cumulative sum of the
    whole recording is built once, not once per run."""
    x, y = cumulative(t, values, period, bridge)
    if not len(edges):
        return np.zeros(0)
    return np.concatenate([_windows(x, y, e) for e in edges])


def _windows(x: np.ndarray, y: np.ndarray, edges: np.ndarray) -> np.ndarray:
    at = np.interp(np.asarray(edges, dtype=float), x, y, left=0.0, right=y[-1])
    return np.diff(at)


def run_windows(runs: Sequence[Run], window: float, margin: float) -> list[np.ndarray]:
    """Window edges inside each run: [t0 - margin, t1] cut into near-equal windows.

    ``margin`` (one report period) reaches back to the start of the first report's span.
    ``window <= 0`` makes each run a single window.
    """
    out = []
    for r in runs:
        a, b = r.t0 - margin, r.t1
        n = 1 if window <= 0 else max(1, int(round((b - a) / window)))
        out.append(np.linspace(a, b, n + 1))
    return out


def run_number(numbers: Sequence[int] | None, k: int) -> int:
    """The user's number of the k-th run a calibration was given (0-based ``k``): its
    number in the session (``numbers``), where runs before it were left out as bumps;
    k + 1 where all were kept."""
    return int(numbers[k]) if numbers is not None else k + 1


def run_spread(per_run: np.ndarray, tolerance: float) -> tuple[float, float, np.ndarray]:
    """Mean, standard error of the mean, and the indices of the runs whose value is off
    the mean by more than ``tolerance`` (relative): what CPI and distance report."""
    per_run = np.asarray(per_run, dtype=float)
    mean = float(np.mean(per_run))
    stderr = float(np.std(per_run, ddof=1) / np.sqrt(len(per_run)))
    off = np.flatnonzero(np.abs(per_run - mean) / mean > tolerance)
    return mean, stderr, off


def need_runs(found: int, needed: int, what: str, gap: float) -> None:
    """Raise a UserError when fewer than ``needed`` runs were found."""
    if found < needed:
        raise UserError(
            f"{what}: found {found} run(s), need at least {needed} "
            f"(runs are separated by pauses of more than {gap:g} s; see --gap)"
        )


CUT_SHARE = 0.1  # the others' motion in a run after (or before) one mouse's: a cut capture


def _path(rep: Reports, a: float, b: float) -> float:
    """The counts ``rep`` read in (a, b], as a path (each report's length, summed)."""
    t = np.asarray(rep.t, dtype=float)
    sel = (t > a) & (t <= b)
    return float(np.sum(np.hypot(np.asarray(rep.dx, float)[sel], np.asarray(rep.dy, float)[sel])))


def check_whole_captures(recording: Mapping[str, Reports], runs: Sequence[Run], gap: float) -> None:
    """Raise when a mouse's motion ends (or begins) inside a run while the others read
    more than CUT_SHARE of their motion in that run after it (before it), later than
    ``gap``: its capture was cut short (a killed recorder, a full disk, a truncated file)
    and that run's counts for it are only a part of the run.

    The others' share, not the time alone: a mouse still for longer than ``gap`` inside a
    run (at the centre of a turn), or the last counts of a rig that creeps as it stops
    (read by a mouse of high CPI only), is not a cut.
    """
    for name, rep in recording.items():
        t = moving(rep)
        if not len(t):
            continue  # no motion at all: the calibration says so, naming the mouse
        others = [r for n, r in recording.items() if n != name]
        for k, r in enumerate(runs):
            for edge, inside, part in (
                (float(t[-1]), r.t0 <= t[-1] < r.t1 - gap, (float(t[-1]), r.t1)),
                (float(t[0]), r.t0 + gap < t[0] <= r.t1, (r.t0 - gap, float(t[0]))),
            ):
                if not inside:
                    continue
                share = max(
                    (_path(o, *part) / total for o in others
                     if (total := _path(o, r.t0 - gap, r.t1)) > 0),
                    default=0.0,
                )  # fmt: skip
                if share > CUT_SHARE:
                    ends, when = ("ends", "after") if edge == t[-1] else ("begins", "before")
                    raise UserError(
                        f"mouse {name}: its motion {ends} at t = {edge:.3f} s, inside run "
                        f"{k + 1} ({r.t0:.3f} .. {r.t1:.3f} s), where the other mice read "
                        f"{share:.0%} of their motion in it {when}: its capture {ends} in the "
                        "middle of a motion (cut short?); every run must be whole"
                    )
