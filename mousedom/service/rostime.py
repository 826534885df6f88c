"""ROS time (the system clock, what ROS 2 stamps with) against CLOCK_MONOTONIC (what the
daemon stamps with): the one place the lead of one over the other is read."""

from __future__ import annotations

import time
from collections.abc import Callable

BRACKET_S = 50e-6  # a read bracketed this tightly is as good as any: stop trying


def system_lead(
    wall: Callable[[], float] = time.time,
    clock: Callable[[], float] = time.monotonic,
    tries: int = 3,
) -> float:
    """How far the system clock is ahead of the monotonic one, read per use (NTP may step
    it).  The wall clock is read between two monotonic reads and set against their middle;
    of ``tries`` such reads the most tightly bracketed is kept, so that the process losing
    the CPU between two reads (tens of ms on a loaded machine) does not move every stamp
    converted with it by as much."""
    best, lead = float("inf"), 0.0
    for _ in range(tries):
        a = clock()
        w = wall()
        b = clock()
        if b - a < best:
            best, lead = b - a, w - 0.5 * (a + b)
        if best <= BRACKET_S:
            break
    return lead
