"""The tracker's time rules, each against a hand-computed answer (issue 17).

- A report stamped t covers the motion since its mouse's previous report when that came
  at most ``late_report_s`` (B) before, else one report period P back: [t_prev, t] or
  [t - P, t] (DESIGN.md, "Time alignment"; a USB catch-up report holds the counts of the
  polls the host skipped).  One stamped under P/2 after the previous report joins that
  report's span (stamps that bunch after a delay), a joined span never longer than B.
- A report stamped exactly on a window edge belongs to the window that ends there, and so
  do repeated stamps there.
- ``interp_at`` is ``np.interp`` for one point, repeated knots included.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.config import parse_config
from mousedom.fusion.countfunction import interp_at
from mousedom.fusion.tracker import Tracker

ONE_MOUSE = (
    "rate_hz: {rate}\nmodel: diff-drive\nlate_report_s: {late}\nmice:\n"
    "  m: {{cpi: 400, mount: {{x: 0.1, y: 0, yaw: 0}}, report_hz: {hz}}}\n"
)


def _window_counts(rate, hz, reports, *, one_window: bool, late: float = 0.1) -> list[float]:
    """REL_Y counts per window of a one-mouse rig, t0 = 0."""
    config = parse_config(ONE_MOUSE.format(rate=rate, hz=hz, late=late), need_sources=False)
    tracker = Tracker(config, t0=0.0)
    if one_window:
        tracker._SMALL, tracker._INGEST_SMALL = 1, 64
        out = []
        # One read per stamp: reports with one stamp arrive together (one read() of the
        # node), and a poll between them would close the window they end.
        for t in sorted({t for t, _ in reports}):
            dys = [dy for s, dy in reports if s == t]
            tracker.push(0, [t] * len(dys), [0.0] * len(dys), dys)
            out.append(tracker.poll())
        out.append(tracker.finish())
        rows = [r for b in out for r in b.rows()]
        return [r.counts[0][1] for r in rows]
    tracker._SMALL = tracker._INGEST_SMALL = 0  # the array path only
    t, dy = zip(*reports, strict=True)
    tracker.push(0, np.array(t), np.zeros(len(t)), np.array(dy))
    b = tracker.finish()
    return [r.counts[0][1] for r in b.rows()]


@pytest.mark.parametrize("one_window", [False, True], ids=["array", "one-window"])
def test_after_a_silence_beyond_the_bridge_a_report_reaches_one_period_back(one_window):
    """Reports at 6 ms and 200 ms, P = 8 ms, B = 100 ms, windows of 5 ms: the second
    report's 8 counts spread over [192, 200] ms, so 3 land in (190, 195] and 5 in
    (195, 200]; nothing before."""
    counts = _window_counts(200.0, 125.0, [(0.006, 4.0), (0.200, 8.0)], one_window=one_window)
    # The first report covers [0, 6] ms (the grid starts at 0): 5/6 then 1/6 of its 4.
    want = [4 * 5 / 6, 4 * 1 / 6] + [0.0] * 36 + [3.0, 5.0]
    assert counts == pytest.approx(want, abs=1e-9)


@pytest.mark.parametrize("one_window", [False, True], ids=["array", "one-window"])
@pytest.mark.parametrize("late", [0.05, 0.1])
def test_a_catch_up_report_covers_all_the_time_since_the_previous_one(one_window, late):
    """Reports at 6 ms and 46 ms (a host that skipped four polls of 8 ms): the second's
    10 counts were measured over [6, 46] ms, a quarter per 10 ms window; with B below the
    gap they would all land in the last period."""
    reports = [(0.006, 4.0), (0.046, 10.0)]
    counts = _window_counts(100.0, 125.0, reports, one_window=one_window, late=late)
    want = [4.0 + 10 * 4 / 40, 2.5, 2.5, 2.5, 10 * 6 / 40]
    assert counts == pytest.approx(want, abs=1e-9)
    short = _window_counts(100.0, 125.0, reports, one_window=one_window, late=0.02)
    assert short == pytest.approx([4.0, 0.0, 0.0, 10 * 2 / 8, 10 * 6 / 8], abs=1e-9)


@pytest.mark.parametrize("one_window", [False, True], ids=["array", "one-window"])
def test_reports_that_bunch_after_a_delay_join_the_span_before(one_window):
    """Reports at 6, 20 and 21 ms (P = 8 ms): the third came 1 ms after the second, under
    P/2: both were held up, and their 4 + 6 counts rise together over [6, 21] ms."""
    reports = [(0.006, 4.0), (0.020, 4.0), (0.021, 6.0)]
    counts = _window_counts(200.0, 125.0, reports, one_window=one_window)
    want = [4 * 5 / 6, 4 / 6 + 10 * 4 / 15, 10 * 5 / 15, 10 * 5 / 15, 10 * 1 / 15]
    assert counts == pytest.approx(want, abs=1e-9)
    # a joined span is never longer than B: with B = P = 8 ms the second report covers
    # [12, 20] ms (14 ms after the first: one period), and the third, 9 ms from that
    # span's start, stands alone over [20, 21] ms
    short = _window_counts(200.0, 125.0, reports, one_window=one_window, late=0.008)
    want = [4 * 5 / 6, 4 / 6, 4 * 3 / 8, 4 * 5 / 8, 6.0]
    assert short == pytest.approx(want, abs=1e-9)


@pytest.mark.parametrize("one_window", [False, True], ids=["array", "one-window"])
def test_reports_stamped_on_a_window_edge_belong_to_the_window_that_ends_there(one_window):
    """Two reports of 3 and 5 counts stamped exactly at 10 ms (a window edge), the mouse's
    first: the first spans [2, 10] ms, the second [10, 10]: all 8 counts end by the edge,
    so the window ending at 10 ms has them all and the next none."""
    reports = [(0.010, 3.0), (0.010, 5.0), (0.030, 0.0)]
    counts = _window_counts(100.0, 125.0, reports, one_window=one_window)
    assert counts[0] == pytest.approx(8.0) and counts[1:] == pytest.approx(
        [0.0] * (len(counts) - 1)
    )


KNOTS = [
    ([0.0, 1.0, 1.0, 2.0], [0.0, 3.0, 8.0, 8.0]),  # a jump: two knots at one time
    ([0.0, 0.0, 0.0, 1.0], [1.0, 2.0, 4.0, 5.0]),  # three at the first time
    ([0.5, 1.5, 1.5, 1.5], [0.0, 1.0, 2.0, 3.0]),  # three at the last time
    ([0.0, 1.0], [0.0, 10.0]),
]


@pytest.mark.parametrize("xp, fp", KNOTS)
@pytest.mark.parametrize("x", [-1.0, 0.0, 0.25, 0.5, 1.0, 1.25, 1.5, 2.0, 3.0])
def test_interp_at_is_np_interp_on_repeated_knots(xp, fp, x):
    assert interp_at(x, xp, fp) == float(np.interp(x, xp, fp))


@settings(max_examples=500, deadline=None)
@given(st.lists(st.integers(0, 6), min_size=1, max_size=12), st.integers(-1, 7), st.data())
def test_interp_at_equals_np_interp(steps, x, data):
    xp = np.cumsum(steps).astype(float).tolist()  # non-decreasing, with repeats
    fp = data.draw(st.lists(st.floats(-100, 100), min_size=len(xp), max_size=len(xp)))
    assert interp_at(float(x), xp, fp) == float(np.interp(float(x), xp, fp))
