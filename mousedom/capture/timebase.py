"""One time base for captures given together: the epoch offset and the warnings about
times that cannot be aligned."""

from __future__ import annotations

import os

from mousedom.capture.base import Capture


def relative_alignment_warning(captures: list[Capture]) -> str | None:
    """The one rule for separate files with relative times, in replay and calibration
    alike: each file's t = 0 is taken as the same instant, and this warning says so."""
    files = {os.path.realpath(c.path): c for c in captures if c.time_base == "relative"}
    if len(files) < 2:
        return None
    names = ", ".join(sorted(os.path.basename(c.path) for c in files.values()))
    return (
        f"{names}: times relative to each recording's own start; they are aligned at "
        "their t = 0, which is right only if the recordings started together (to be sure, "
        "record the mice into one file: `mousedom record`, or one `libinput record`)"
    )


def time_offset(captures: list[Capture]) -> tuple[float, list[str]]:
    """Seconds to subtract from epoch-stamped captures (0 for the others), and warnings.

    Epoch times are rebased to the earliest event of all epoch files given together, so
    that they stay aligned with one another; relative and monotonic times are kept.
    """
    firsts = [t for c in captures if c.time_base == "epoch" and (t := c.first_time()) is not None]
    warnings: list[str] = []
    bases = {c.time_base for c in captures}
    if "epoch" in bases and len(bases) > 1:
        warnings.append(
            "captures mix epoch (wall clock) and relative/monotonic times; "
            "their events cannot be aligned in time"
        )
    elif bases == {"monotonic", "relative"}:
        # Seconds since boot against seconds since a recording's start: as far apart as
        # the machine had been up, with empty windows all the way between.
        names = ", ".join(f"{os.path.basename(c.path)} ({c.time_base})" for c in captures)
        warnings.append(
            f"captures mix monotonic (since boot) and relative times ({names}); "
            "their events cannot be aligned in time"
        )
    aligned = relative_alignment_warning(captures)
    if aligned and bases == {"relative"}:
        warnings.append(aligned)
    return (min(firsts) if firsts else 0.0), warnings


def grid_anchor(captures: list[Capture], offset: float) -> float | None:
    """Where replay's window grid starts, on its time base (epoch captures less
    ``offset``): the earliest of each capture's grid start (``Capture.grid_start``: the
    daemon that recorded it began its windows there, and replay's windows are then its
    windows) or, for a capture that states none, its first event.  None: no events."""
    starts = [
        t - (offset if c.time_base == "epoch" else 0.0)
        for c in captures
        if (t := c.grid_start()) is not None or (t := c.first_time()) is not None
    ]
    return min(starts) if starts else None
