"""The tracker's time rules, each against a hand-computed answer (issue 17).

- A report stamped t covers the motion since its mouse's previous report, but never more
  than one report period P back: [max(t_prev, t - P), t] (DESIGN.md, "Time alignment").
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
    "rate_hz: {rate}\nmodel: diff-drive\nmice:\n"
    "  m: {{cpi: 400, mount: {{x: 0.1, y: 0, yaw: 0}}, report_hz: {hz}}}\n"
)


def _window_counts(rate, hz, reports, *, one_window: bool) -> list[float]:
    """REL_Y counts per window of a one-mouse rig, t0 = 0."""
    config = parse_config(ONE_MOUSE.format(rate=rate, hz=hz), need_sources=False)
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
def test_a_report_reaches_one_period_back_and_no_further(one_window):
    """Reports at 6 ms and 100 ms, P = 8 ms, windows of 5 ms: the second report's 8 counts
    spread over [92, 100] ms, so 3 land in (90, 95] and 5 in (95, 100]; nothing before."""
    counts = _window_counts(200.0, 125.0, [(0.006, 4.0), (0.100, 8.0)], one_window=one_window)
    # The first report covers [0, 6] ms (the grid starts at 0): 5/6 then 1/6 of its 4.
    want = [4 * 5 / 6, 4 * 1 / 6] + [0.0] * 16 + [3.0, 5.0]
    assert counts == pytest.approx(want, abs=1e-9)


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
