"""A SOURCE status's rate_hz is the reports read over the last second when the status is
made (sources.base.Source.rate): it was updated only when reports were read, so a mouse
that stopped (or went) kept its last rate for good while its age grew, and it read 0 for
the whole first second."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.sources.base import RATE_SPAN_S, Reports, Source


class _Fed(Source):
    """A source whose reads return what the test queued for them."""

    kind = "test"

    def __init__(self) -> None:
        super().__init__("m")
        self.next: list[float] = []

    def _open(self) -> None:
        pass

    def fileno(self) -> int:
        return -1

    def _read(self, now: float) -> list[Reports]:
        t, self.next = self.next, []
        return [Reports.from_lists("m", t, [1] * len(t), [0] * len(t))]


def _feed(src: _Fed, rate_hz: float, start: float, end: float, read_every: float = 0.01):
    """Reports at ``rate_hz`` from ``start`` to ``end``, read every ``read_every`` s."""
    k, now = 0, start
    while now < end - 1e-12:
        now = min(now + read_every, end)
        batch = []
        while start + (k + 1) / rate_hz <= now + 1e-12:
            k += 1
            batch.append(start + k / rate_hz)
        src.next = batch
        src.read(now)
    return now


@pytest.mark.parametrize("rate_hz", [125.0, 500.0, 1000.0])
def test_the_rate_follows_the_mouse_and_falls_to_zero_after_it_stops(rate_hz):
    src = _Fed()
    assert src.rate(100.0) == 0.0  # nothing read yet
    end = _feed(src, rate_hz, 100.0, 100.3)
    assert src.rate(end) == pytest.approx(rate_hz, rel=0.05)  # the first second: so far
    end = _feed(src, rate_hz, end, 102.5)
    assert src.rate(end) == pytest.approx(rate_hz, rel=0.02)
    # stopped: read, nothing there, or not read at all (a source gone)
    assert src.rate(end + 0.5) == pytest.approx(rate_hz / 2, rel=0.05)
    assert src.rate(end + RATE_SPAN_S + 0.01) == 0.0
    assert src.rate(end + 60.0) == 0.0


@settings(max_examples=50, deadline=None)
@given(st.floats(20.0, 2000.0), st.floats(0.003, 0.05), st.floats(1.1, 5.0))
def test_the_rate_is_the_reports_of_the_last_second(rate_hz, read_every, seconds):
    src = _Fed()
    end = _feed(src, rate_hz, 0.0, seconds, read_every)
    # the reports read in (end - 1 s, end]: one read's worth of rounding either side
    assert src.rate(end) == pytest.approx(rate_hz, abs=rate_hz * read_every + 1.0)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.lists(st.floats(0.0001, 0.01), max_size=5), min_size=1, max_size=8))
def test_the_last_gap_is_the_interval_before_the_last_report_across_reads(reads):
    """``SourceHealth.last_gap`` (what the wake's plan predicts a sparse mouse's next
    report from, service/wake.py) is the last report's stamp less the one before it,
    whether that one came in the same read or in an earlier one; None before two."""
    src = _Fed()
    stamps: list[float] = []
    t = 10.0
    for gaps in reads:
        batch = []
        for g in gaps:
            t += g
            batch.append(t)
        stamps += batch
        src.next = batch
        src.read(t + 0.001)
        if len(stamps) >= 2:
            assert src.health.last_gap == pytest.approx(stamps[-1] - stamps[-2], abs=1e-12)
        else:
            assert src.health.last_gap is None


def test_a_read_of_several_reports_without_the_one_before_says_no_gap():
    """A source that hands ``_count`` several reports but not the stamp before the last
    (the gyro's: iio, ROS 2, replay) leaves ``last_gap`` unknown rather than the interval
    since its previous read, which spans the whole read (a 1 kHz gyro read 4 at a time
    was planned as a sparse mouse)."""
    src = _Fed()
    src._count(1, 10.0, 10.001)
    src._count(1, 10.003, 10.004)
    assert src.health.last_gap == pytest.approx(0.003)
    src._count(4, 10.007, 10.008)
    assert src.health.last_gap is None
    src._count(4, 10.011, 10.012, before=10.010)
    assert src.health.last_gap == pytest.approx(0.001)
