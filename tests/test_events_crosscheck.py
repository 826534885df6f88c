"""Two implementations of the kernel's frame rules must agree: the live decoder's
``FrameAssembler`` (mousedom/events.py) and the capture readers' ``group_frames``
(mousedom/capture/frames.py, written independently on the captures branch)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.capture.frames import group_frames
from mousedom.events import EV_KEY, EV_MSC, EV_REL, EV_SYN, SYN_DROPPED, SYN_REPORT, FrameAssembler

CODES = [
    (EV_SYN, SYN_REPORT),
    (EV_SYN, SYN_DROPPED),
    (EV_REL, 0),
    (EV_REL, 1),
    (EV_REL, 8),
    (EV_REL, 11),
    (EV_KEY, 0x110),
    (EV_MSC, 4),
]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(CODES), st.integers(-1000, 1000)), max_size=150))
def test_assembler_agrees_with_capture_group_frames(rows):
    n = len(rows)
    t = np.arange(n) * 0.001
    ty = np.array([r[0][0] for r in rows], dtype=np.uint16)
    co = np.array([r[0][1] for r in rows], dtype=np.uint16)
    va = np.array([r[1] for r in rows], dtype=np.int64)
    theirs = group_frames(ty, co, va, t)
    for small in (0, 10**9):
        a = FrameAssembler(small)
        ours = a.feed(t, ty, co, va)  # no flush: group_frames leaves the tail to the caller
        assert ours.t.tolist() == theirs.t.tolist()
        assert ours.dx.tolist() == theirs.dx.tolist()
        assert ours.dy.tolist() == theirs.dy.tolist()
        s = a.stats
        assert s.frames == theirs.frames
        assert s.dropped_frames == theirs.dropped_frames
        assert s.dropped_events == theirs.dropped_events
        assert (s.dropped_dx, s.dropped_dy) == (theirs.lost_x, theirs.lost_y)
