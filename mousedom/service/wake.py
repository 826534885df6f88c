"""When the daemon reads its sources: the reading policy, as a pure function."""

from __future__ import annotations

import math
from typing import NamedTuple

WAKE_SLACK_S = 0.0001  # after a report's predicted time: pipe and scheduler delays
# A mouse reports only when it has a count: at a slow speed a fast mouse's reports come
# several periods apart.  Its next report is predicted from its last interval where that
# is 1.5 periods or more and at most this long (a mouse speeding up again reports sooner:
# this is the most latency the prediction can cost), else from its period.
SPARSE_MAX_S = 0.004


def plan_wake(
    end: float, mice: list[tuple[float, float, float | None, float | None]], bridge: float = 0.0
) -> tuple[float, float]:
    """When to read the sources for the window ending at ``end``, and when to give up.

    ``mice`` holds (report period, latency, stamp of the last report read or None, the
    interval before that report or None) of each live mouse; ``bridge`` is
    ``late_report_s``.  Reading every report as it arrives (4 mice
    at 1000 Hz: 4000 wakes a second) costs far more than the fusion.  A window can close
    only once every live mouse has reported past its end, and mice report on a steady clock
    (USB polling), so each one's reports after ``end`` are predictable from its last one.
    Its first report after ``end`` does not close the window yet: a report within P/2 may
    still join that report's span, which began before ``end`` (``CountFunction.frontier``).
    Its window is final at its second report (whose span begins after ``end``), or once
    ``complete`` (now - latency) is P/2 past the first, whichever comes first.  The loop
    sleeps until the latest of those (plus a little slack) and reads everything at once:
    one wake a window where waking at the first report woke again for every report of
    every mouse until the second (4.7 wakes a window, 4 mice at 1 kHz).  A mouse whose last
    interval was several periods (SPARSE_MAX_S) is predicted on that interval: on its
    period, the loop woke before its report and then at every report of the others until
    it came (6 wakes a window, 4 mice at 1 kHz reporting every third period).

    If a mouse is late, the loop waits on the descriptors, at most until ``give_up``, when
    the count function's rules close the window (``CountFunction.frontier``): a mouse
    silent since ``last`` is taken for still once it has been silent ``max(period,
    bridge)`` and a period has passed since ``end`` (before that, a catch-up report may
    still cover the window); one that reported past ``end`` once no report can join that
    one's span.  Giving up earlier would only spin: every wake until then finds nothing to
    close.
    """
    wake = give_up = end
    for period, latency, last, gap in mice:
        give_up = max(give_up, final_by_time(end, period, latency, bridge, last))
        if last is None or last > end:
            continue
        # its reports' step: its period, or where it reports sparsely its last interval in
        # whole periods (reports come on the host's polls: the rest of the interval is the
        # stamps' jitter, and a step too long would only wake late)
        step = period
        if gap is not None and 1.5 * period <= gap <= SPARSE_MAX_S:
            step = round(gap / period) * period
        # the first report strictly after ``end`` at that step, and when that report's
        # span is final: at the next report, or P/2 past it by ``complete`` (where one
        # falls exactly on ``end``, that report's span ends there: final once P/2 has
        # passed, or at the next report, whose span begins at ``end``)
        k = math.floor((end - last) / step) + 1
        first = last + k * step
        edge = last + (k - 1) * step
        # Where the step is predicted from the last interval, the wake is a period early:
        # a report's stamp a little late (a host's poll, a busy feeder) would otherwise
        # shift the predicted step by as much and leave its window waiting for the wake
        # (bench/daemon.py --sparse 3: p99 3.1 ms beyond final, against 0.84 on the
        # period; a period early, 0.90).  Awake before the report, the loop then waits on
        # the descriptors as before.
        early = min(step - period, period)
        if edge >= end:  # (final by time alone there: no report's stamp to be early for)
            wake = max(wake, min(edge + 0.5 * period + latency, first - early))
        else:
            wake = max(wake, first + min(step, 0.5 * period + latency) - early)
    return min(wake, give_up) + WAKE_SLACK_S, give_up


def final_by_time(
    end: float, period: float, latency: float, bridge: float, last: float | None
) -> float:
    """When the window ending at ``end`` is final as to a mouse whose last report read is
    stamped ``last`` (None: none yet) without another report, by ``complete`` (now -
    latency), as ``CountFunction.frontier`` rules: one that reported at or past the end
    once no report can join that report's span (P/2 after it); one silent since before
    the end once it has been silent ``max(period, bridge)`` and a period has passed since
    the end (before that, a catch-up report may still cover the window; a report to come
    covers at most a period before its stamp).  ``bridge`` is ``late_report_s``."""
    if last is None:
        done = end + period
    elif last >= end:
        done = last + 0.5 * period
    else:
        done = max(end + period, last + max(period, bridge))
    return done + latency


def span_start(period: float, bridge: float, last: float, gap: float | None) -> float | None:
    """Where the span of a mouse's last report begins (``CountFunction.ingest``'s rule),
    from its stamp and the interval before it: at the report before, where that is P/2 to
    ``max(period, bridge)`` before; a period before its stamp after a longer silence.
    None where it is not known: no interval (a gyro's read of several samples), or one
    under P/2 (the report may have joined the span before, which began earlier)."""
    if gap is None or gap < 0.5 * period:
        return None
    return last - gap if gap <= max(period, bridge) else last - period


# While a window waits for reports from some of the mice, the loop waits until each of
# them has reported or is final by time, and reads nothing before: the other mice's
# reports, and the first ones of those waited for, wait in their kernel buffers.  evdev
# gives a mouse's reader a buffer of at least 64 events (EVDEV_MIN_BUFFER_SIZE, more for
# a device whose reports carry more), 21 reports of REL_X, REL_Y and SYN_REPORT; one that
# overflows drops reports (SYN_DROPPED).  So the loop waits so for at most this many of
# the fastest mouse's periods after its last read of every source, then reads them all
# and waits again.
ALONE_REPORTS = 16


class Waited(NamedTuple):
    """A mouse whose next report the window waits for (``holding``)."""

    mouse: int  # its index into the mice, as plan_wake takes them
    final: float  # when it is final by time without that report (final_by_time)


def holding(
    end: float,
    mice: list[tuple[float, float, float | None, float | None]],
    bridge: float,
    now: float,
    read_at: float,
) -> tuple[list[Waited], float]:
    """The mice whose next report the window ending at ``end`` waits for at ``now``, and
    until when the loop may wait for them without reading (``ALONE_REPORTS`` after
    ``read_at``, its last read of every source).  ``mice`` and ``bridge`` as
    ``plan_wake`` takes them.

    Waited for, until final by time (``final_by_time``): a mouse whose last report read
    is before ``end`` (its first report past the end is to come), and one past the end
    whose span may begin before it (``span_start``: final at its next report).  Not
    waited for: a mouse whose last report's span begins at or after the end (final by its
    reports), one that has not reported at all (the plan does not wait for it), and one
    past the end whose interval is unknown (a gyro's read of several samples; final by
    time within the plan's give-up).  Until each of those waited for has reported or is
    final, no read can close the window: waking at any report instead, a window that
    waited for mice reporting every third period woke two to three times
    (bench/daemon.py --sparse 3), and one that waited for a mouse gone still woke at every
    report of the others until its silence was over.
    """
    waited: list[Waited] = []
    for i, (period, latency, last, gap) in enumerate(mice):
        if last is None:
            continue
        if last >= end:
            start = span_start(period, bridge, last, gap)
            if gap is None or (start is not None and start >= end):
                continue
        final = final_by_time(end, period, latency, bridge, last)
        if now < final:
            waited.append(Waited(i, final))
    if not waited:
        return [], end
    return waited, read_at + ALONE_REPORTS * min(p for p, _, _, _ in mice)
