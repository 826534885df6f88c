"""Stamps far from the clock (issue 26): a FIFO mouse whose writer puts absurd times in its
records (2**62 seconds, a stream read out of step with its records, 1e6 s or 30 s ahead)
crashed the daemon, grew it to gigabytes, or dropped every client.  Now such a report is
re-stamped to its read's time at the source boundary: its counts are kept, the source's
health says so, the daemon goes on publishing and SIGTERM stops it at once."""

from __future__ import annotations

import math
import signal
import struct
import time

import numpy as np
import pytest
from daemon_fixtures import Conn, rig_runner
from hypothesis import given
from hypothesis import strategies as st

from mousedom.fusion import sim
from mousedom.sources.base import (
    STAMP_AHEAD_S,
    STAMP_BEHIND_S,
    bound_stamp_array,
    bound_stamps,
)
from mousedom.sources.events import EV_REL, EV_SYN, REL_X, REL_Y, SYN_REPORT

NOW = 1000.0


@given(st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                          st.floats(NOW - 70, NOW + 1)), max_size=40))  # fmt: skip
def test_list_and_array_bounds_agree_and_keep_only_plausible_stamps(ts):
    lst = list(ts)
    n, worst = bound_stamps(lst, NOW)
    arr, n2, worst2 = bound_stamp_array(np.array(ts, dtype=float), NOW)
    assert arr.tolist() == lst and n == n2
    assert (worst == worst2) or (math.isinf(worst) and math.isinf(worst2))
    bad = [v for v in ts if not NOW - STAMP_BEHIND_S <= v <= NOW + STAMP_AHEAD_S]
    assert n == len(bad)
    assert all(NOW - STAMP_BEHIND_S <= v <= NOW + STAMP_AHEAD_S for v in lst)
    kept = [v for v in ts if v not in bad]
    assert [v for v, w in zip(lst, ts, strict=True) if w in kept] == kept


def _record(sec: int, usec: int, typ: int, code: int, value: int) -> bytes:
    return struct.pack("<qqHHi", sec, usec, typ, code, value)


def _frame(t_sec: int, t_usec: int, dx: int, dy: int) -> bytes:
    return (_record(t_sec, t_usec, EV_REL, REL_X, dx) + _record(t_sec, t_usec, EV_REL, REL_Y, dy)
            + _record(t_sec, t_usec, EV_SYN, SYN_REPORT, 0))  # fmt: skip


@pytest.fixture
def rig_run(tmp_path):
    yield from rig_runner(tmp_path)


def test_absurd_stamps_are_a_reported_fault_never_a_crash(rig_run):
    run = rig_run(sim.straight(6.0, 0.05))
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    assert len(c.poses(0.3)) >= 5
    mouse = run.mice["front"]
    now = time.monotonic()
    bad = [
        _frame(2**62, 0, 3, -5),  # 2**62 seconds
        _frame(int(now) + 1_000_000, 0, 2, 0),  # 1e6 s ahead
        _frame(int(now) + 30, 0, 1, 1),  # 30 s ahead
        _frame(0, 2**62, -4, 2),  # a microseconds field of 2**62
        _frame(-(2**62), 0, 1, 0),  # far behind
        # A stream out of step with its records (7 bytes too many), then back in step.
        b"\x01" * 7 + _frame(int(now), 0, 5, 5) * 8 + b"\x00" * 17,
    ]
    with run.feeder.lock:
        for data in bad:
            mouse.write(data)
    rss0 = _rss_kb(run.daemon.proc.pid)
    poses = c.poses(1.5)
    assert len(poses) >= 50, len(poses)  # 50 Hz on, not a backlog of far windows
    gaps = np.diff([p["t"] for p in poses])
    assert gaps.max() < 0.1 and all(math.isfinite(p["x"]) for p in poses)
    assert run.daemon.proc.poll() is None
    c.send({"cmd": "status"})
    src = c.until("SOURCE", lambda m: m["name"] == "front", limit=500)
    assert src["stamps_restamped"] >= 5 and "re-stamped on arrival" in src["error"]
    assert _rss_kb(run.daemon.proc.pid) < rss0 + 50_000  # no growth toward far windows
    assert "stamped far from the clock" in run.daemon.log()
    t = time.monotonic()
    run.daemon.signal(signal.SIGTERM)
    assert run.daemon.proc.wait(5) == 0 and time.monotonic() - t < 1.0


def _rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0
