"""When the daemon reads its sources: the reading policy, as a pure function."""

from __future__ import annotations

import math

WAKE_SLACK_S = 0.0001  # after a report's predicted time: pipe and scheduler delays


def plan_wake(
    end: float, mice: list[tuple[float, float, float | None]], bridge: float = 0.0
) -> tuple[float, float]:
    """When to read the sources for the window ending at ``end``, and when to give up.

    ``mice`` holds (report period, latency, stamp of the last report read or None) of each
    live mouse; ``bridge`` is ``late_report_s``.  Reading every report as it arrives (4 mice
    at 1000 Hz: 4000 wakes a second) costs far more than the fusion.  A window can close
    only once every live mouse has reported past its end, and mice report on a steady clock
    (USB polling), so each one's reports after ``end`` are predictable from its last one.
    Its first report after ``end`` does not close the window yet: a report within P/2 may
    still join that report's span, which began before ``end`` (``CountFunction.frontier``).
    Its window is final at its second report (whose span begins after ``end``), or once
    ``complete`` (now - latency) is P/2 past the first, whichever comes first.  The loop
    sleeps until the latest of those (plus a little slack) and reads everything at once:
    one wake a window where waking at the first report woke again for every report of
    every mouse until the second (4.7 wakes a window, 4 mice at 1 kHz).

    If a mouse is late, the loop waits on the descriptors, at most until ``give_up``, when
    the count function's rules close the window (``CountFunction.frontier``): a mouse
    silent since ``last`` is taken for still once it has been silent ``max(period,
    bridge)`` and a period has passed since ``end`` (before that, a catch-up report may
    still cover the window); one that reported past ``end`` once no report can join that
    one's span.  Giving up earlier would only spin: every wake until then finds nothing to
    close.
    """
    wake = give_up = end
    for period, latency, last in mice:
        if last is None or last > end:
            # past the end: final once no report can join its span (P/2 later)
            done = end + period if last is None else max(end + period, last + 0.5 * period)
            give_up = max(give_up, done + latency)
            continue
        give_up = max(give_up, max(end + period, last + max(period, bridge)) + latency)
        # the first report slot strictly after ``end`` on this mouse's own clock, and when
        # that report's span is final: at the next report, or P/2 past it by ``complete``
        # (where a slot falls exactly on ``end``, that report's span ends there: final once
        # P/2 has passed, or at the next report, whose span begins at ``end``)
        k = math.floor((end - last) / period) + 1
        first = last + k * period
        edge = last + (k - 1) * period
        if edge >= end:
            wake = max(wake, min(edge + 0.5 * period + latency, first))
        else:
            wake = max(wake, first + min(period, 0.5 * period + latency))
    return min(wake, give_up) + WAKE_SLACK_S, give_up
