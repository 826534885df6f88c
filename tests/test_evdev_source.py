"""The evdev source's data plane on real kernel objects: pipes and FIFOs carrying
input_event bytes; unplug (the writer closes) and reattach; matching via a fake tree."""

from __future__ import annotations

import os
import struct
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_evdev_fakes import (  # noqa: F401 (a fixture, used by name)
    add_device,
    motion_bytes,
    paths,
    stamps_on_their_own_clock,
)

from mousedom.config import EvdevMatch, Mount, MouseConfig
from mousedom.errors import UserError
from mousedom.sources.base import SourceGone, SourceUnavailable
from mousedom.sources.evdev import CLOCK_MONOTONIC, EVIOCSCLOCKID, EvdevSource
from mousedom.sources.events import EV_KEY, EV_REL, EV_SYN, REL_X, SYN_DROPPED, encode_input_events

# Stamps on a clock of their own: the bound against the read's time is lifted here.
pytestmark = pytest.mark.usefixtures("stamps_on_their_own_clock")


def mouse(**match) -> MouseConfig:
    return MouseConfig("left", 800.0, 800.0, Mount(), evdev=EvdevMatch(**match))


def read_all(src: EvdevSource, until_gone: bool = True):
    """Read until SourceGone (the writer closed); return concatenated reports."""
    t, dx, dy = [], [], []
    for _ in range(10_000):
        try:
            batches = src.read(0.0)
        except SourceGone:
            return t, dx, dy, True
        for r in batches:
            t += r.t.tolist()
            dx += r.dx.tolist()
            dy += r.dy.tolist()
        if not until_gone and not batches:
            break
    return t, dx, dy, False


def test_ioctl_numbers_match_linux_input_h():
    """_IOW('E', 0xa0, int) from linux/input.h, and CLOCK_MONOTONIC from time.h."""
    assert EVIOCSCLOCKID == 0x400445A0
    assert CLOCK_MONOTONIC == 1


def test_pipe_stream_frames_split_anywhere_and_unplug(tmp_path):
    r, w = os.pipe()
    src = EvdevSource(mouse(path=f"/proc/self/fd/{r}"))
    src.open()
    os.close(r)  # the source reopened the pipe through /proc; only its end stays open
    assert src.health.connected and src.health.extra["clock"].startswith("as-written")
    data = motion_bytes(100.0, [1, -2, 3, 4], [5, 6, -7, 8])
    # Cut mid-record and mid-frame: the source must carry both over.
    os.write(w, data[:30])
    t, dx, dy, gone = read_all(src, until_gone=False)
    assert (t, gone) == ([], False)
    os.write(w, data[30:100])
    t1, dx1, dy1, _ = read_all(src, until_gone=False)
    os.write(w, data[100:])
    t2, dx2, dy2, _ = read_all(src, until_gone=False)
    assert dx1 + dx2 == [1, -2, 3, 4] and dy1 + dy2 == [5, 6, -7, 8]
    assert t1 + t2 == pytest.approx([100.0, 100.008, 100.016, 100.024], abs=1e-6)
    # Unplug: the writer closes after half a frame; its counts are kept, then SourceGone.
    os.write(w, motion_bytes(101.0, [9], [0])[:48])  # REL_X and REL_Y, no SYN_REPORT
    os.close(w)
    t3, dx3, dy3, gone = read_all(src)
    assert gone and dx3 == [9] and t3 == pytest.approx([101.0])
    assert not src.health.connected and "gone" in src.health.error
    assert src.health.extra["incomplete_frames"] == 1
    assert src.health.reports == 5
    assert src.fileno() == -1


def test_fifo_before_writer_is_not_unplug_and_reattach(tmp_path):
    fifo = tmp_path / "mouse.fifo"
    os.mkfifo(fifo)
    src = EvdevSource(mouse(path=str(fifo)))
    src.open()
    # No writer yet: a FIFO reads as EOF, but that is not an unplug.
    assert src.read(0.0) == []
    assert src.health.connected
    for session, base in enumerate((10.0, 20.0)):
        w = os.open(fifo, os.O_WRONLY)
        os.write(w, motion_bytes(base, [1, 2, 3], [0, 0, 1]))
        os.close(w)
        t, dx, dy, gone = read_all(src)
        assert gone and dx == [1, 2, 3] and dy == [0, 0, 1], session
        assert t[0] == pytest.approx(base)
        src.open()  # reattach: the same rule finds the FIFO again
        assert src.health.connected
    src.close()


def test_syn_dropped_mid_frame_through_a_pipe():
    r, w = os.pipe()
    src = EvdevSource(mouse(path=f"/proc/self/fd/{r}"))
    src.open()
    os.close(r)
    rows = [
        (1.0, EV_REL, REL_X, 1),
        (1.0, EV_SYN, 0, 0),
        (1.1, EV_REL, REL_X, 50),
        (1.1, EV_SYN, SYN_DROPPED, 0),
        (1.2, EV_REL, REL_X, 60),
        (1.2, EV_KEY, 0x110, 1),
        (1.2, EV_SYN, 0, 0),
        (1.3, EV_REL, REL_X, 2),
        (1.3, EV_SYN, 0, 0),
    ]
    a = np.array(rows, dtype=np.float64)
    os.write(w, encode_input_events(a[:, 0], a[:, 1], a[:, 2], a[:, 3].astype(np.int64)))
    os.close(w)
    t, dx, dy, gone = read_all(src)
    assert gone and dx == [1, 2] and t == pytest.approx([1.0, 1.3])
    assert src.health.dropped == 1
    assert src.health.extra["syn_dropped"] == 1
    assert src.health.extra["dropped_counts"] == [110, 0]
    assert src.health.skipped == 1


def test_big_burst_larger_than_one_read():
    """More events than one os.read takes: a writer thread fills the pipe while we read."""
    r, w = os.pipe()
    src = EvdevSource(mouse(path=f"/proc/self/fd/{r}"))
    src.open()
    os.close(r)
    n = 20_000
    rng = np.random.default_rng(1)
    dxs, dys = rng.integers(-20, 21, n), rng.integers(-20, 21, n)
    data = motion_bytes(0.0, dxs, dys, dt=0.000125)

    def writer():
        os.write(w, data)  # blocks while the pipe is full: the reader must keep up
        os.close(w)

    th = threading.Thread(target=writer)
    th.start()
    t, dx, dy, gone = read_all(src)
    th.join()
    assert gone and len(t) == n
    assert sum(dx) == int(dxs.sum()) and sum(dy) == int(dys.sum())
    assert np.all(np.diff(t) > 0)


@settings(max_examples=40, deadline=None)
@given(st.binary(max_size=24 * 30), st.lists(st.integers(1, 100), max_size=5))
def test_random_bytes_through_a_pipe_never_crash(data, sizes):
    r, w = os.pipe()
    src = EvdevSource(mouse(path=f"/proc/self/fd/{r}"))
    src.open()
    os.close(r)
    pos = 0
    out_x = 0
    for size in [*sizes, len(data)]:
        os.write(w, data[pos : pos + size])
        pos += size
        for b in src.read(0.0):
            out_x += int(b.dx.sum())
    os.close(w)
    t, dx, dy, gone = read_all(src)
    assert gone
    out_x += int(sum(dx))
    s = src.assembler.stats
    assert s.rel_x_in == out_x + s.dropped_dx
    assert src.truncated_bytes == len(data) % 24


def test_match_through_a_fake_machine_and_reattach(tmp_path):
    root = tmp_path / "m"
    add_device(root, 3, "Mouse A", phys="usb-1/input0", by_path=("pci-usb-0:1-event-mouse",))
    add_device(root, 4, "Mouse B", phys="usb-2/input0", by_path=("pci-usb-0:2-event-mouse",))
    src = EvdevSource(mouse(name="Mouse B"), paths(root))
    src.open()
    assert src.device.node == str(root / "dev/input/event4")
    w = os.open(src.device.node, os.O_WRONLY)
    os.write(w, motion_bytes(5.0, [7], [8]))
    os.close(w)
    _, dx, dy, gone = read_all(src)
    assert gone and (dx, dy) == ([7], [8])
    # Unplugged: the node is gone; open() says so (SourceUnavailable), nothing crashes.
    os.unlink(root / "dev/input/event4")
    with pytest.raises(SourceUnavailable, match="Mouse B"):
        src.open()
    assert not src.health.connected
    # It comes back as another node: the same rule reattaches.
    add_device(root, 9, "Mouse B", phys="usb-2/input0")
    src.open()
    assert src.device.node == str(root / "dev/input/event9")
    # A look-alike plugged in later is ambiguous: wait (SourceUnavailable), don't die.
    add_device(root, 10, "Mouse B", phys="usb-2/input0")
    src.close()
    with pytest.raises(SourceUnavailable, match="2 devices match"):
        src.open()


def test_ambiguous_at_first_open_is_unavailable_with_the_candidates(tmp_path):
    """Regression: the first open raised AmbiguousDevice (a UserError), which the daemon
    does not catch: one ambiguous rule stopped it at start.  Sources speak base.py's
    terms only, so it is SourceUnavailable with every candidate listed."""
    add_device(tmp_path, 1, "Same")
    add_device(tmp_path, 2, "Same")
    src = EvdevSource(mouse(name="Same"), paths(tmp_path))
    with pytest.raises(SourceUnavailable, match="2 devices match.*event1.*event2") as e:
        src.open()
    assert not isinstance(e.value, UserError)
    assert not src.health.connected and "event1" in src.health.error
    # The look-alike goes away: the same source attaches to the one left.
    os.unlink(tmp_path / "dev/input/event2")
    src.open()
    assert src.device.node == str(tmp_path / "dev/input/event1")
    src.close()


def test_daemon_keeps_running_while_a_rule_is_ambiguous(tmp_path):
    """The daemon (in-process, real socket) starts, reports the ambiguity in the mouse's
    health, keeps running, and attaches once the look-alike is unplugged."""
    from mousedom.config import parse_config
    from mousedom.service.daemon import Daemon

    add_device(tmp_path, 1, "Same")
    add_device(tmp_path, 2, "Same")
    cfg = parse_config(
        "mice:\n"
        "  a: {cpi: 800, mount: {x: 0, y: 0.1}, evdev: {name: Same}}\n"
        "  b: {cpi: 800, mount: {x: 0, y: -0.1}, evdev: {name: Same}}\n",
        str(tmp_path / "rig.yaml"),
    )
    d = Daemon(
        cfg,
        str(tmp_path / "sock"),
        source_factory=lambda m, clock: EvdevSource(m, paths(tmp_path)),
        handle_signals=False,
    )
    result: list = []
    th = threading.Thread(target=lambda: result.append(d.run()), daemon=True)
    th.start()
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not getattr(d, "_ready", False):
            time.sleep(0.02)
        assert th.is_alive() and d._ready, result
        errors = [s.source.health.error or "" for s in d.sensors.slots]
        assert all("2 devices match" in e and "event2" in e for e in errors), errors
        os.unlink(tmp_path / "dev/input/event2")  # unplug the look-alike
        while time.monotonic() < deadline and not all(s.live for s in d.sensors.slots[:1]):
            time.sleep(0.05)
        assert d.sensors.slots[0].live and d.sensors.slots[0].source.device.node.endswith("event1")
    finally:
        d.request_stop()
        th.join(10)
    assert result == [0]


def test_a_node_that_is_not_an_evdev_device(tmp_path):
    """A regular file where a node should be: python-evdev's ioctls fail -> unavailable."""
    add_device(tmp_path, 1, "Fake", fifo=False)
    src = EvdevSource(mouse(name="Fake"), paths(tmp_path))
    with pytest.raises(SourceUnavailable, match="event1: not an evdev device"):
        src.open()


def test_record_layout_is_native_struct():
    raw = motion_bytes(3.5, [1], [2])
    assert struct.unpack("@llHHi", raw[:24]) == (3, 500000, EV_REL, REL_X, 1)


class FakeInputDevice:
    """Stands in for python-evdev's InputDevice (no /dev/input here): its fd is a real
    pipe, so the data plane under test is the real one."""

    def __init__(self, fd: int, grab_error: int | None = None) -> None:
        self.fd, self.grab_error, self.grabs, self.closed = fd, grab_error, 0, False

    def grab(self) -> None:
        if self.grab_error:
            raise OSError(self.grab_error, os.strerror(self.grab_error))
        self.grabs += 1

    def close(self) -> None:
        self.closed = True
        os.close(self.fd)


def fake_node(tmp_path, **kw):
    add_device(tmp_path, 3, "Real Mouse", fifo=False, **kw)
    return str(tmp_path / "dev/input/event3")


def test_real_node_is_grabbed_and_switched_to_monotonic(tmp_path):
    node = fake_node(tmp_path)
    r, w = os.pipe()
    opened, ioctls = [], []

    def opener(path):
        opened.append(path)
        return FakeInputDevice(r)

    src = EvdevSource(
        mouse(name="Real Mouse"),
        paths(tmp_path),
        device_opener=opener,
        ioctl=lambda fd, req, arg: ioctls.append((fd, req, arg)),
    )
    src.open()
    dev = src._dev
    assert opened == [node] and dev.grabs == 1 and src.grabbed
    assert ioctls == [(r, 0x400445A0, struct.pack("i", 1))]
    assert src.health.extra["clock"] == "monotonic" and src.health.extra["grabbed"]
    os.write(w, motion_bytes(7.0, [4, -4], [1, 1]))
    os.close(w)
    t, dx, dy, gone = read_all(src)
    assert gone and dx == [4, -4] and dev.closed


def test_grab_false_and_busy_and_permission(tmp_path):
    fake_node(tmp_path)
    r, w = os.pipe()
    src = EvdevSource(
        mouse(name="Real Mouse", grab=False),
        paths(tmp_path),
        device_opener=lambda p: FakeInputDevice(r),
        ioctl=lambda *a: None,
    )
    src.open()
    assert src._dev.grabs == 0 and not src.grabbed
    src.close()
    os.close(w)
    r, w = os.pipe()
    busy = FakeInputDevice(r, grab_error=16)  # EBUSY: someone else holds the grab
    src = EvdevSource(
        mouse(name="Real Mouse"),
        paths(tmp_path),
        device_opener=lambda p: busy,
        ioctl=lambda *a: None,
    )
    with pytest.raises(SourceUnavailable, match="grabbed by another process"):
        src.open()
    assert busy.closed
    os.close(w)

    def denied(p):
        raise PermissionError(13, "Permission denied", p)

    src = EvdevSource(mouse(name="Real Mouse"), paths(tmp_path), device_opener=denied)
    with pytest.raises(SourceUnavailable, match="join group 'root'"):
        src.open()


def test_stamps_that_run_backwards_are_moved_forward_and_counted(tmp_path):
    """Regression: a stream whose stamps run backwards (a FIFO writer, a replug that
    restarts its clock) went through as is; `record` then wrote a capture that its own
    reader refuses ("time goes backwards").  Stamps leave the source non-decreasing; the
    counts are all kept and the moved reports counted."""
    r, w = os.pipe()
    src = EvdevSource(mouse(path=f"/proc/self/fd/{r}"))
    src.open()
    os.close(r)
    os.write(w, motion_bytes(10.0, [1, 2, 3], [4, 5, 6], dt=0.01))  # 10.00 .. 10.02
    os.write(w, motion_bytes(9.0, [7, 8], [9, 10], dt=0.5))  # 9.0, 9.5: behind
    os.write(w, motion_bytes(10.1, [11], [12]))
    os.close(w)
    t, dx, dy, gone = read_all(src)
    assert gone and dx == [1, 2, 3, 7, 8, 11] and dy == [4, 5, 6, 9, 10, 12]
    assert t == sorted(t) and t[3] == t[4] == t[2] and t[5] == pytest.approx(10.1)
    assert src.time_backwards == 2 and src.health.extra["time_backwards"] == 2
