"""ReplaySource: a capture as a live source on an injected clock."""

from __future__ import annotations

import numpy as np
import pytest

from mousedom.capture import CaptureError, DeviceInfo, NativeWriter
from mousedom.capture.evemu import format_evemu
from mousedom.capture.source import ReplaySource
from mousedom.sources.base import SourceUnavailable


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _capture(tmp_path):
    t = 7.0 + np.arange(50) * 0.01  # 0.49 s of reports every 10 ms
    dx = np.arange(1, 51)
    dy = -np.ones(50, dtype=int)
    p = tmp_path / "m.evemu"
    p.write_text(format_evemu(t, dx, dy))
    return p, t, dx, dy


def test_reports_are_due_on_the_clock_and_restamped(tmp_path):
    p, t, dx, dy = _capture(tmp_path)
    clock = Clock()
    src = ReplaySource("m", str(p), speed=2.0, clock=clock)
    src.open()
    assert src.next_due() == pytest.approx(100.0)
    got = src.read(clock.now)
    assert len(got) == 1 and got[0].dx.tolist() == [1]
    clock.now = 100.1  # 0.1 s at speed 2 = 0.2 s of data: reports 1..20 are due
    got = src.read(clock.now)[0]
    assert got.dx.tolist() == list(range(2, 22))
    np.testing.assert_allclose(got.t, 100.0 + (t[1:21] - 7.0) / 2.0)
    assert src.timeout(clock.now) == pytest.approx(100.0 + (t[21] - 7.0) / 2 - 100.1)
    clock.now = 1000.0
    rest = src.read(clock.now)[0]
    assert int(rest.dx.sum()) + sum(range(1, 22)) == int(dx.sum())
    assert src.next_due() is None and src.timeout() is None and src.finished
    assert src.read(clock.now + 1) == []
    assert src.health.reports == 50
    assert src.fileno() == -1  # polled: nothing to select on
    src.close()


def test_loop_continues_time(tmp_path):
    p, t, dx, _ = _capture(tmp_path)
    clock = Clock()
    src = ReplaySource("m", str(p), loop=True, clock=clock)
    src.open()
    clock.now = 100.0 + 0.49 + 0.01 + 0.49  # the second pass has just ended
    got = src.read(clock.now)[0]
    assert len(got.t) == 100
    assert np.all(np.diff(got.t) > 0)
    assert got.t[50] == pytest.approx(100.5)  # one report period after the first pass
    assert int(got.dx.sum()) == 2 * int(dx.sum())
    assert not src.finished and src.next_due() == pytest.approx(101.0)


def test_device_selection_in_a_native_file(tmp_path):
    p = tmp_path / "two.mdcap"
    devs = [
        DeviceInfo(name="a", mouse="left", rel_xy=True),
        DeviceInfo(name="b", mouse="right", rel_xy=True),
    ]
    with NativeWriter(p, devs) as w:
        w.motion(0, [1.0, 2.0], [1, 1], [0, 0])
        w.motion(1, [1.5], [5], [5])
    clock = Clock()
    right = ReplaySource("right", str(p), clock=clock)
    right.open()
    by_device = ReplaySource("x", str(p), device="a", clock=clock)
    by_device.open()
    clock.now = 1e6
    assert right.read(clock.now)[0].dx.tolist() == [5]
    assert by_device.read(clock.now + 10)[0].dx.tolist() == [1, 1]
    with pytest.raises(CaptureError, match="which device"):
        ReplaySource("nobody", str(p), clock=clock).open()


def test_missing_file_is_unavailable(tmp_path):
    src = ReplaySource("m", str(tmp_path / "none.evemu"))
    with pytest.raises(SourceUnavailable):
        src.open()
    assert not src.health.connected


def test_built_from_a_mouse_config_loops_and_mice_share_one_anchor(tmp_path):
    from mousedom.config import parse_config

    p = tmp_path / "two.mdcap"
    devs = [
        DeviceInfo(name="a", mouse="left", rel_xy=True),
        DeviceInfo(name="b", mouse="right", rel_xy=True),
    ]
    with NativeWriter(p, devs, time_base="monotonic") as w:
        w.motion(0, [10.0, 10.5, 11.0], [1, 1, 1], [0, 0, 0])
        w.motion(1, [10.2, 12.0], [5, 5], [0, 0])
    cfg = parse_config(
        f"mice:\n  left: {{cpi: 400, mount: {{x: 0, y: 0.1}}, replay: {p}}}\n"
        f"  right: {{cpi: 400, mount: {{x: 0, y: -0.1}}, replay: {p}}}\n",
        str(tmp_path / "c.yaml"),
    )
    clock = Clock()
    left = ReplaySource(cfg.mice[0], clock=clock)
    left.open()
    clock.now += 0.3  # the second source opens later, on the same anchor
    right = ReplaySource(cfg.mice[1], clock=clock)
    right.open()
    assert left.loop and right.loop and left.fileno() == -1
    clock.now = 100.0 + 2.0 + 0.5 + 0.25  # past the whole file (2 s) and one period on
    lt = left.read(clock.now)[0].t
    rt = right.read(clock.now)[0].t
    assert lt.tolist() == pytest.approx([100.0, 100.5, 101.0, 102.5])
    assert rt.tolist() == pytest.approx([100.2, 102.0, 102.7])


def test_identical_mice_are_picked_by_their_recorded_node(tmp_path):
    """The daemon's replay source takes replay.device as `mousedom replay` does: a device
    name, or the node of two identically named mice."""
    p = tmp_path / "twins.mdcap"
    devs = [
        DeviceInfo(name="USB Mouse", rel_xy=True, extra={"node": "/dev/input/event5"}),
        DeviceInfo(name="USB Mouse", rel_xy=True, extra={"node": "/dev/input/event6"}),
    ]
    with NativeWriter(p, devs) as w:
        w.motion(0, [1.0, 2.0], [1, 1], [0, 0])
        w.motion(1, [1.5], [5], [5])
    clock = Clock()
    src = ReplaySource("right", str(p), device="/dev/input/event6", clock=clock)
    src.open()
    clock.now = 1e6
    assert src.read(clock.now)[0].dx.tolist() == [5]
    with pytest.raises(CaptureError, match="which device"):
        ReplaySource("right", str(p), device="USB Mouse", clock=clock).open()


def test_a_source_reopened_on_its_files_anchor_goes_on_from_now(tmp_path):
    """A replay source opened again later (a reload that changed its file and back, a
    retry) on the anchor of its file's first replay: the reports due while it was closed
    are not delivered (a device plugged back in does not send what it missed).  All at once
    they were re-stamped on arrival: 2,990 reports of 294 s in one window.  Those due within
    REOPEN_SKIP_S of the opening are (mice of one file opened one after the other)."""
    from mousedom.capture.source import REOPEN_SKIP_S

    p = tmp_path / "one.mdcap"
    with NativeWriter(p, [DeviceInfo(name="a", mouse="m", rel_xy=True)]) as w:
        t = np.arange(1, 1001) * 0.1  # 100 s of reports, one every 0.1 s
        w.motion(0, t, np.ones(1000, int), np.zeros(1000, int))
    clock = Clock()
    first = ReplaySource("m", str(p), clock=clock, loop=False)
    first.open()
    clock.now += 10.0
    assert len(first.read(clock.now)[0].t) == 101  # due by 10 s after the anchor's 0.1 s
    first.close()
    clock.now += 50.0  # closed for 50 s
    again = ReplaySource("m", str(p), clock=clock, loop=False)
    again.open()
    got = again.read(clock.now)[0].t
    assert got[0] >= clock.now - REOPEN_SKIP_S - 1e-9 and len(got) == 11  # (both ends)
    clock.now += 5.0
    assert len(again.read(clock.now)[0].t) == 50  # and goes on on the anchor
