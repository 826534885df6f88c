"""One mouse's cumulative count function F(t), the tracker's per-mouse state.

A report's counts belong to the time they were measured (docs/models.md, "Timing").  A
USB mouse is polled every period P and reports what it measured since its last report: a
report stamped t covers [t_prev, t] when the mouse reported t_prev at most ``bridge`` before
(a host that skipped polls for 30 ms gets one catch-up report holding all 30 ms of counts,
and a mouse creeping along reports every few periods), and [t - P, t] after a longer
silence (it was still, or lifted, and starts again).  Reports stamped less than P/2 after
the one before were held up on their way (their stamps bunch after a delay): they join that
report's span, so a bunch of late reports rises over the time it was measured in, not at
the instant it arrived.  A joined span never exceeds ``bridge``.

F is flat between spans and rises linearly over each, so a window's counts are
F(end) - F(start).  Only the part of F after the closed frontier is kept, as knots relative
to F there (the anchor): the knots' times, cumulative REL_X and cumulative REL_Y.  Joining a
report to its predecessor moves F only after the predecessor's span starts, so windows
close no later than that while a report may still join (``frontier``): the daemon and
replay place every count identically.

Two representations, converted on demand: three Python lists while the knots are few (the
daemon carries about one window's worth, and numpy's cost per call would be most of its
work), one (3, K) array when they are many (replay closes millions of windows per call).
Both paths do the same IEEE operations in the same order, so they give the same counts
(tests/test_onewindow.py holds them equal).
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from typing import Any

import numpy as np

from mousedom import core

# The knots as three Python lists: times, cumulative REL_X, cumulative REL_Y
KnotLists = tuple[list[float], list[float], list[float]]


def _exact_int_sums(steps: np.ndarray) -> bool:
    """Every partial sum of each row is below 2**53 in magnitude: int64 cannot wrap, and a
    float64 sum of the same integers is exact, so both give the same values."""
    if not steps.size:
        return True
    biggest = max(int(steps.max()), -int(steps.min()))  # Python ints: no abs(-2**63)
    return biggest * steps.shape[-1] < 2**53


class CountFunction:
    """The not-yet-closed part of one mouse's cumulative count function.

    It owns its queue, knots and liveness: the tracker reads fields (``pending``, ``knots``,
    ``dead``, ``last_t``) on its per-window path, and changes them only through the
    methods (``queue``, ``complete_to``, ``declare_live``, ``ingest``, ``close``...)."""

    def __init__(self, period: float, bridge: float = 0.0) -> None:
        self.period = period
        # a report this soon after the previous one covers all the time since: at least P
        self.bridge = max(period, bridge)
        self.join = 0.5 * period  # a report this soon after the previous one joins its span
        # Latest stamp pushed (queued or not): the one record of the mouse's last stamp in
        # fusion (Tracker.finish closes up to it).  A source's health.last_t (SOURCE, the
        # daemon's silence rule) sees the same stamps in the daemon, but lives with the
        # device, across tracker reloads, and replay has none: kept there, not shared.
        self.last_t = -math.inf
        self.knot_t = -math.inf  # stamp of the last report turned into knots
        self.pending: list[tuple] = []  # (t, dx, dy): float lists (small pushes) or arrays
        self.complete = -math.inf  # all reports stamped <= this have been pushed
        self.knots: KnotLists | np.ndarray = ([], [], [])
        self.dead: list[list[float]] = []  # [from, to) spans in which the mouse is not live
        self.counts_in = [0.0, 0.0]  # REL_X, REL_Y pushed (floats: added to per read)
        self.late = 0  # reports stamped behind the closed frontier (moved forward)
        # The report span (s) straddling the anchor, where longer than 1.5 P, else 0: a
        # window whose edge cuts a long span (a USB catch-up) took its share of it in
        # proportion to time, wrong by a part of the change of motion over the span
        # (noisemodel: the granularity term).
        self.anchor_span = 0.0
        self.window_span = 0.0  # close_one's last window's: the larger of its edges'
        # where the rising span the anchor cuts began (NaN: it cuts none): the anchor knot
        # stands in for that span's start once windows are closed inside it
        self.cut_from = math.nan
        self.backwards = 0  # reports stamped before the previous one (clamped)

    @property
    def live(self) -> bool:
        return not self.dead or self.dead[-1][1] != math.inf

    def frontier(self) -> float:
        """The time up to which this mouse's F is final (queued reports ingested first).

        A report still to come covers at most P before its stamp (stamped after
        ``complete``); until ``complete`` is ``bridge`` past the last report, one may
        cover all the time since that report; and until it is P/2 past, one may join the
        last report's span, which then rises from that span's start."""
        last, complete = self.knot_t, self.complete
        if complete >= last + self.bridge:
            return max(last, complete - self.period)
        if complete >= last + self.join:
            return last
        kt = self.knots[0]
        n = len(kt)
        # the last span's start (the anchor if the span began before the closed frontier)
        return kt[n - 2] if n >= 2 and kt[n - 1] == last else last

    # ------------------------------------------------------------------ knots

    def n_knots(self) -> int:
        return len(self.knots[0])

    def knot_array(self) -> np.ndarray:
        k = self.knots
        if isinstance(k, tuple):
            k = self.knots = np.array(k, dtype=np.float64).reshape(3, -1)
        return k

    def knot_lists(self) -> KnotLists:
        k = self.knots
        if isinstance(k, tuple):
            return k
        kt, kx, ky = k.tolist()
        lists = self.knots = (kt, kx, ky)
        return lists

    def settled(self, t: float) -> bool:
        """Whether every count is closed (F flat at the anchor) and no knot lies after
        ``t``: nothing for a window after ``t`` to take (Tracker.skip_quiet)."""
        k = self.knots
        kt, kx, ky = k if isinstance(k, tuple) else k.tolist()
        return not (any(kx) or any(ky) or (kt and kt[-1] > t))

    def level(self) -> np.ndarray:
        """F at the last knot, relative to the anchor (0 before any knot)."""
        k = self.knots
        if not len(k[0]):
            return np.zeros(2)
        return np.array([k[1][-1], k[2][-1]], dtype=np.float64)

    def queued(self) -> int:
        return sum(len(p[0]) for p in self.pending)

    # ------------------------------------------------------------------ reports -> knots

    def ingest(self, edge: float) -> None:
        """Turn the queued reports into knots (arrays); ``edge`` is the closed frontier."""
        if not self.pending:
            return
        if len(self.pending) == 1:
            t, dx, dy = (np.asarray(c) for c in self.pending[0])
        else:
            t, dx, dy = (np.concatenate(cols) for cols in zip(*self.pending, strict=True))
        self.pending = []
        t = t.astype(np.float64, copy=False)
        # Time must not run backwards: clamp to the running maximum (counted, kept).
        # Stamps in order (the usual case) are their own running maximum.
        prev = np.concatenate([[self.knot_t], t[:-1]])  # each report's previous stamp
        moved = False
        if not (t >= prev).all():
            run_max = np.maximum.accumulate(np.concatenate([[self.knot_t], t]))[1:]
            self.backwards += int(np.count_nonzero(run_max > t))
            t, moved = run_max, True
        # Reports behind the closed frontier go into the first open window.  t is now
        # non-decreasing, so those are a prefix: found by bisection, not by a pass.
        late = int(np.searchsorted(t, edge, side="left"))
        if late:
            self.late += late
            t, moved = np.maximum(t, edge), True
        if moved:
            prev = np.concatenate([[self.knot_t], t[:-1]])
        gap = t - prev
        # the span: since the previous report within the bridge, else one period (prev is
        # -inf before the first report: a gap of inf)
        start = np.where(gap <= self.bridge, prev, t - self.period)
        # max(..., edge) as well: start is non-decreasing, so only a prefix can be below.
        below = int(np.searchsorted(start, edge, side="left"))
        if below:
            start[:below] = edge

        # Knot pairs: F holds its level until the report's span starts, then rises to it.
        # The old knots and the new pairs are written into one array (no concatenation
        # after), each count row straight into its strided place.
        n_old = self.n_knots()
        level = self.level().tolist()
        knots = np.empty((3, n_old + 2 * len(t)))
        if n_old:
            knots[:, :n_old] = self.knot_array()
        new = knots[:, n_old:]
        new[0, 0::2] = start
        new[0, 1::2] = t
        for row, (steps, lv) in enumerate(zip((dx, dy), level, strict=True), start=1):
            if steps.dtype.kind == "i" and _exact_int_sums(steps):
                # Whole counts (captures, live reads): summed as integers, under half the
                # time of a float cumsum, and the same values.
                cum = np.cumsum(steps, dtype=np.int64).astype(np.float64)
            else:
                cum = np.cumsum(steps, dtype=np.float64)
            self.counts_in[row - 1] += float(cum[-1])
            np.add(cum, lv, out=new[row, 1::2])
            # (cum + level) - step, the step taken as float64 (exact for whole counts)
            np.subtract(new[row, 1::2], steps, out=new[row, 0::2], dtype=np.float64)
        joins = np.flatnonzero(gap < self.join)
        if joins.size:
            knots = self._joined(knots, n_old, joins, t, prev, start, edge)
        self.knots = knots
        self.knot_t = float(t[-1])

    def _joined(
        self, knots: np.ndarray, n_old: int, joins: np.ndarray, t: np.ndarray,
        prev: np.ndarray, start: np.ndarray, edge: float,
    ) -> np.ndarray:  # fmt: skip
        """``ingest``'s knots with the reports held up on their way (``joins``: stamped
        under P/2 after the one before) joined to the previous report's span, as
        ``ingest_small`` joins them: the previous span's end knot and the report's start
        knot go, its end knot stays; a joined span never exceeds the bridge."""
        keep = np.ones(knots.shape[1], dtype=bool)
        ramp = start.tolist()  # each report's span start, once joined
        tl, pl = t.tolist(), prev.tolist()
        old_t = knots[0, :n_old].tolist()
        for j in joins.tolist():
            if pl[j] <= edge:
                continue
            if j:
                first = ramp[j - 1]
            elif n_old >= 2 and old_t[-1] == pl[0]:
                first = old_t[-2]
            else:
                continue
            if tl[j] - first > self.bridge:
                continue
            keep[n_old + 2 * j - 1] = False  # the previous span's end (maybe an old knot)
            keep[n_old + 2 * j] = False  # this report's start
            ramp[j] = first
        return knots[:, keep]

    def ingest_small(self, edge: float) -> None:
        """``ingest`` report by report: the same operations in the same order on floats."""
        pending, self.pending = self.pending, []
        t: list[float] = []
        dx: list[float] = []
        dy: list[float] = []
        for pt, pdx, pdy in pending:  # lists from push, or arrays of a larger push
            t += pt if isinstance(pt, list) else pt.tolist()
            dx += pdx if isinstance(pdx, list) else pdx.tolist()
            dy += pdy if isinstance(pdy, list) else pdy.tolist()
        period, bridge, join = self.period, self.bridge, self.join
        kt, kx, ky = self.knot_lists()
        native = core.native
        done = None
        if native is not None:  # the same loop compiled (csrc/knots.c), or None: declined
            done = native.ingest_small(t, dx, dy, kt, kx, ky, self.knot_t, edge, period,
                                       bridge, join)  # fmt: skip
        if done is not None:
            cx, cy, backwards, late, prev = done
        else:
            cx, cy, backwards, late, prev = _ingest_loop(
                t, dx, dy, kt, kx, ky, self.knot_t, edge, period, bridge, join
            )
        self.counts_in[0] += cx
        self.counts_in[1] += cy
        self.backwards += backwards
        self.late += late
        self.knot_t = prev

    # ------------------------------------------------------------------ closing windows

    def _long(self, length: float) -> float:
        return length if length > 1.5 * self.period else 0.0

    def close(
        self, edges: np.ndarray, out: np.ndarray | None = None, spans: np.ndarray | None = None
    ) -> np.ndarray:
        """Counts (n, 2) of the windows between consecutive ``edges`` (arrays), after which
        the anchor moves to the last edge.  The first edge is the current anchor.  ``out``:
        an (n, 2) array (a view is fine) to write them into; ``spans``, an (n,) one for
        each window's longest long span cut by its edges (``anchor_span``)."""
        counts = np.empty((len(edges) - 1, 2)) if out is None else out
        if not self.n_knots():
            counts[:] = 0.0
            if spans is not None:
                spans[:] = 0.0
            self.anchor_span, self.cut_from = 0.0, math.nan
            return counts
        at, start = self._cut_spans(edges[1:] if spans is not None else edges[-1:])
        if spans is not None:
            spans[:] = np.maximum(np.concatenate([[self.anchor_span], at[:-1]]), at)
        self.anchor_span, self.cut_from = float(at[-1]), float(start[-1])
        # F is relative to the closed frontier, so its value there is 0: the first window's
        # counts are F at its end, each later one's the difference of F at its two ends.
        kt, kfx, kfy = self.knot_array()
        last = []
        for axis, kf in enumerate((kfx, kfy)):
            f = np.interp(edges[1:], kt, kf)
            counts[0, axis] = f[0]
            np.subtract(f[1:], f[:-1], out=counts[1:, axis])
            last.append(f[-1])
        self._rebase(float(edges[-1]), np.array(last))
        return counts

    def _rebase(self, edge: float, level: np.ndarray) -> None:
        # Knots exactly on the edge are kept: a jump there (reports with one stamp) may
        # have been evaluated on either side, and keeping them, relative, loses neither.
        # Knot times never decrease (see ingest), so "time >= edge" is a tail: a slice.
        k = self.knot_array()  # (close made it one)
        kept = k[:, np.searchsorted(k[0], edge) :]
        knots = np.empty((3, kept.shape[1] + 1))
        knots[:, 0] = (edge, 0.0, 0.0)
        knots[0, 1:] = kept[0]
        knots[1:, 1:] = kept[1:] - level[:, None]
        self.knots = knots

    def _cut_spans(self, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each time in ``at``: the length of the rising span strictly around it
        where over 1.5 P (else 0), and where it began (NaN: none), on the knot array
        (``cut_span`` one at a time)."""
        kt, kx, ky = self.knot_array()
        j = np.searchsorted(kt, at, side="right")
        inside = (j > 0) & (j < len(kt))
        jj, j0 = np.minimum(j, len(kt) - 1), np.maximum(j - 1, 0)
        cut = (j0 == 0) & (self.cut_from == self.cut_from)  # in the span the anchor cut
        rises = np.abs(kx[jj] - kx[j0]) + np.abs(ky[jj] - ky[j0]) > 0.5
        inside &= (kt[j0] < at) & (cut | rises)
        begin = np.where(cut, self.cut_from, kt[j0])
        start = np.where(inside, begin, math.nan)
        length = np.where(inside, kt[jj] - begin, 0.0)
        return np.where(length > 1.5 * self.period, length, 0.0), start

    def close_one(self, end: float) -> tuple[float, float]:
        """``close`` for one window ending at ``end``, on the knot lists."""
        kt, kx, ky = self.knot_lists()
        if not kt:
            self.anchor_span = self.window_span = 0.0
            self.cut_from = math.nan
            return 0.0, 0.0
        self.cut_from, length, fx, fy, *knots = close_knots(end, kt, kx, ky, self.cut_from)
        cut = self._long(length)
        self.window_span = cut if cut > self.anchor_span else self.anchor_span
        self.anchor_span = cut
        self.knots = tuple(knots)  # type: ignore[assignment]
        return fx, fy

    # ------------------------------------------------------------ what the tracker says

    def queue(self, t: list | np.ndarray, dx: list | np.ndarray, dy: list | np.ndarray,
              last: float) -> None:  # fmt: skip
        """Reports pushed (``last``: their latest stamp), to be turned into knots when
        windows close."""
        self.pending.append((t, dx, dy))
        if last > self.last_t:
            self.last_t = last

    def timed_as(self, fresh: CountFunction) -> CountFunction:
        """This count function, carried into a reloaded tracker whose own is ``fresh``
        (``Tracker.carry``): its reports, knots, liveness and counters as they are, the
        rules for reports still to come (report period, bridge) the new config's."""
        self.period, self.bridge, self.join = fresh.period, fresh.bridge, fresh.join
        return self

    def complete_to(self, t: float) -> None:
        """Every report stamped <= t has been pushed."""
        if t > self.complete:
            self.complete = t

    def declare_live(self, live: bool, t: float, first_end: float = -math.inf) -> None:
        """The sensor vanished (False) or came back (True) at time t; a dead span's
        windows do not use it.  ``first_end``: the end of the first window still open.
        That window takes what lies behind its start (reports stamped before it, the
        period a first report reaches back: ``ingest`` moves them into it), so a sensor
        back at or before its start (every window up to then could close) would bring counts from
        before it came back into it: its dead span lasts until that window's end, as a
        sensor back inside that window is not used in it either."""
        if live == self.live:
            return
        if live:
            self.dead[-1][1] = max(t, first_end)
            self.complete_to(t)
        else:
            self.dead.append([t, math.inf])

    def close_live(self, edges: np.ndarray, out: np.ndarray) -> None:
        """Clear ``out`` (n,) for the windows between consecutive ``edges`` that overlap a
        dead span (``close``'s windows); forgets the spans that end by the last edge."""
        if self.dead:
            for start, end in self.dead:
                out[(edges[:-1] < end) & (edges[1:] > start)] = False
            self.forget_dead(float(edges[-1]))

    def forget_dead(self, end: float) -> None:
        """Dead spans that end by ``end`` are past: the windows up to it are closed."""
        if self.dead:
            self.dead = [span for span in self.dead if span[1] > end]

    def skip_to(self, end: float) -> None:
        """Windows up to ``end`` were skipped with nothing in them (Tracker.skip_quiet):
        no knots to keep."""
        self.knots = ([], [], [])
        self.anchor_span, self.cut_from = 0.0, math.nan
        self.forget_dead(end)

    def live_in(self, start: float, end: float) -> bool:
        """Whether the mouse was live over all of [start, end]; forgets dead spans that
        end by ``end`` (the windows are closed in order)."""
        if not self.dead:
            return True
        live = True
        for a, b in self.dead:
            if start < b and end > a:
                live = False
        self.forget_dead(end)
        return live


def interp_at(x: float, xp: list[float], fp: list[float]) -> float:
    """np.interp(x, xp, fp) for one point of non-decreasing ``xp``, with numpy's operations
    (numpy/_core/src/multiarray/compiled_base.c): the segment is the last j with
    xp[j] <= x, a point on a knot takes that knot's value, else the slope formula."""
    if x > xp[-1]:
        return fp[-1]
    if x < xp[0]:
        return fp[0]
    j = bisect_right(xp, x) - 1
    if j == len(xp) - 1 or xp[j] == x:
        return fp[j]
    # xp[j] < x < xp[j + 1], all finite: the result is finite (numpy's NaN repair is moot)
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    return slope * (x - xp[j]) + fp[j]


def cut_span(
    x: float, kt: list[float], kx: list[float], ky: list[float], cut_from: float
) -> tuple[float, float]:
    """(where it began, its length) of the rising span strictly around ``x``, or (NaN, 0):
    the float twin of ``CountFunction._cut_spans``, the same comparisons.  Rising: by over
    half a count (a report holds whole counts; knots relative to a fractional anchor
    differ by rounding where F is flat).  The first knot is the anchor: the rest of a span
    it cut (which began at ``cut_from``) rises whatever is left of it."""
    j = bisect_right(kt, x)
    if j == 0 or j >= len(kt) or not kt[j - 1] < x:
        return math.nan, 0.0
    if j == 1 and cut_from == cut_from:  # in the span the anchor cut (its rest may be tiny)
        return cut_from, kt[j] - cut_from
    if abs(kx[j] - kx[j - 1]) + abs(ky[j] - ky[j - 1]) <= 0.5:
        return math.nan, 0.0
    return kt[j - 1], kt[j] - kt[j - 1]


def close_knots(
    end: float, kt: list[float], kx: list[float], ky: list[float], cut_from: float
) -> tuple[float, float, float, float, list[float], list[float], list[float]]:
    """``CountFunction.close_one``'s window ending at ``end`` out of its knots (at least
    one): the rising span the edge cuts (``cut_span``: where it began, its length), F at
    the edge (fx, fy), and the knots rebased there (new lists), relative to F at the edge.
    In the compiled core where it is built (csrc/knots.c); this is its specification."""
    native = core.native
    if native is not None:
        done = native.close_knots(end, kt, kx, ky, cut_from)
        if done is not None:
            return done
    cut_from, length = cut_span(end, kt, kx, ky, cut_from)
    fx, fy = interp_at(end, kt, kx), interp_at(end, kt, ky)
    j = bisect_left(kt, end)
    return (cut_from, length, fx, fy, [end, *kt[j:]], [0.0, *[v - fx for v in kx[j:]]],
            [0.0, *[v - fy for v in ky[j:]]])  # fmt: skip


def _ingest_loop(
    t: list, dx: list, dy: list, kt: list, kx: list, ky: list, knot_t: float, edge: float,
    period: float, bridge: float, join: float,
) -> tuple[Any, Any, int, int, float]:  # fmt: skip
    """``CountFunction.ingest_small``'s loop (the compiled core's ``ingest_small`` is this,
    in C): the reports become knots appended to kt, kx, ky; returns the counts' sums, the
    reports stamped backwards and behind ``edge``, and the last report's stamp."""
    lx, ly = (kx[-1], ky[-1]) if kt else (0.0, 0.0)
    run = prev = knot_t
    cx, cy = dx[0], dy[0]  # np.cumsum starts from the first value, not from 0 + it
    backwards = late = 0
    for k, (ti, a, b) in enumerate(zip(t, dx, dy, strict=True)):
        if k:
            cx += a
            cy += b
        if run > ti:
            backwards += 1
        else:
            run = ti
        ti = run
        if ti < edge:
            late += 1
            ti = edge
        x, y = cx + lx, cy + ly
        gap = ti - prev
        n = len(kt)
        if (
            gap < join
            and n >= 2
            and kt[n - 1] == prev
            and prev > edge
            and (ti - kt[n - 2] <= bridge)
        ):
            # held up on its way: the previous report's span stretches to take it
            kt[n - 1], kx[n - 1], ky[n - 1] = ti, x, y
            prev = ti
            continue
        # the span: since the previous report within the bridge, else one period
        start = prev if gap <= bridge else ti - period
        if edge > start:
            start = edge
        kt += (start, ti)
        kx += (x - a, x)
        ky += (y - b, y)
        prev = ti
    return cx, cy, backwards, late, prev
