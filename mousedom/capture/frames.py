"""Group evdev events into motion reports, vectorised, for the capture readers.

A *frame* is every event up to and including a SYN_REPORT; a *report* is a frame that
holds REL_X and/or REL_Y.  The readers parse text into plain event arrays (time, type,
code, value) a block at a time and hand them here; the events after the last SYN_REPORT
of a block are carried over to the next block, so blocks may cut frames anywhere.

Kernel rules (Documentation/input/event-codes.rst): after SYN_DROPPED a client drops the
partial frame and everything up to and including the next SYN_REPORT.  Here that is the
whole frame the SYN_DROPPED sits in; its events are counted as dropped, never used.

Non-motion events (buttons, wheels including REL_WHEEL_HI_RES, MSC_SCAN, ...) are skipped
and counted, and never mistaken for motion: only (EV_REL, REL_X) and (EV_REL, REL_Y) move.

Why not the live evdev reader's frame assembler: that one works event by event on a
live stream; replaying a text capture needs the same rules over whole arrays at once to
reach the speed targets.  The rules are the same and the tests check them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EV_SYN, EV_KEY, EV_REL = 0, 1, 2
SYN_REPORT, SYN_DROPPED = 0, 3
REL_X, REL_Y = 0, 1


@dataclass
class Frames:
    """Motion reports of one block, plus what was skipped or dropped in it."""

    t: np.ndarray  # float64 time of each report (its SYN_REPORT)
    dx: np.ndarray  # int64 sum of REL_X in the frame
    dy: np.ndarray  # int64 sum of REL_Y in the frame
    index: np.ndarray  # int64 index (into the block's events) of each report's SYN_REPORT
    frames: int  # SYN_REPORT frames completed in this block
    skipped: int  # non-motion events in frames that were kept
    dropped_frames: int  # frames discarded because of SYN_DROPPED
    dropped_events: int  # non-SYN events in those frames
    lost_x: int  # REL_X counts in dropped frames (lost by the kernel, reported)
    lost_y: int
    rest: int  # index of the first event after the last SYN_REPORT (carry it over)


def group_frames(
    typ: np.ndarray, code: np.ndarray, value: np.ndarray, t: np.ndarray
) -> Frames:
    """Turn one block of events into motion reports (see the module docstring)."""
    typ = np.asarray(typ)
    code = np.asarray(code)
    value = np.asarray(value, dtype=np.int64)
    t = np.asarray(t, dtype=np.float64)
    is_syn = typ == EV_SYN
    is_rep = is_syn & (code == SYN_REPORT)
    ends = np.flatnonzero(is_rep)
    if len(ends) == 0:
        empty_f = np.empty(0, np.float64)
        empty_i = np.empty(0, np.int64)
        return Frames(empty_f, empty_i, empty_i, empty_i, 0, 0, 0, 0, 0, 0, 0)
    rest = int(ends[-1]) + 1
    nf = len(ends)
    is_rep = is_rep[:rest]
    is_syn = is_syn[:rest]
    typ, code, value = typ[:rest], code[:rest], value[:rest]
    fid = np.cumsum(is_rep) - is_rep  # frame number of every event, its SYN_REPORT included
    dropped = np.zeros(nf, dtype=bool)
    dropped[fid[is_syn & (code == SYN_DROPPED)]] = True
    is_rel = typ == EV_REL
    isx = is_rel & (code == REL_X)
    isy = is_rel & (code == REL_Y)
    # bincount weights are float64: exact for integer sums below 2**53.
    sx = np.bincount(fid[isx], weights=value[isx], minlength=nf).astype(np.int64)
    sy = np.bincount(fid[isy], weights=value[isy], minlength=nf).astype(np.int64)
    motion = np.bincount(fid[isx | isy], minlength=nf) > 0
    keep = motion & ~dropped
    other = ~(is_syn | isx | isy)
    in_dropped = dropped[fid]
    return Frames(
        t=t[ends[keep]],
        dx=sx[keep],
        dy=sy[keep],
        index=ends[keep].astype(np.int64),
        frames=nf,
        skipped=int(np.count_nonzero(other & ~in_dropped)),
        dropped_frames=int(np.count_nonzero(dropped)),
        dropped_events=int(np.count_nonzero(~is_syn & in_dropped)),
        lost_x=int(sx[dropped].sum()),
        lost_y=int(sy[dropped].sum()),
        rest=rest,
    )
