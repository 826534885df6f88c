"""The serial source over real ptys and a real TCP socket, with the test playing the
downsampler (the firmware itself plays it in test_firmware_sim.py)."""

from __future__ import annotations

import os
import select
import socket
import time
import tty

import numpy as np
import pytest

from mousedom.config import Mount, MouseConfig, SerialSource
from mousedom.sources import adns_protocol as P
from mousedom.sources.adns import AdnsSource
from mousedom.sources.adns_decode import packets_to_reports
from mousedom.sources.base import SourceGone, SourceUnavailable


def mouse(port, k=7, cpi=400):
    return MouseConfig(
        "floor", 400.0, 400.0, Mount(), serial=SerialSource(port, k=k, sensor_cpi=cpi)
    )


@pytest.fixture
def pty():
    master, slave = os.openpty()
    tty.setraw(master)
    path = os.ttyname(slave)
    yield master, path
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


def read_commands(fd, want, timeout=2.0):
    data, end = b"", time.monotonic() + timeout
    while time.monotonic() < end:
        r, _, _ = select.select([fd], [], [], 0.05)
        if r:
            data += os.read(fd, 4096)
            if len(P.parse_commands(data)) >= want:
                break
    return P.parse_commands(data)


def pump(src, timeout=1.0, until=None):
    """Read the source like the daemon's selector loop would."""
    out, end = [], time.monotonic() + timeout
    while time.monotonic() < end:
        r, _, _ = select.select([src.fileno()], [], [], 0.05)
        if r:
            out += src.read(time.monotonic())
            if until and until(out):
                break
    return out


def test_open_sends_settings(pty):
    master, path = pty
    src = AdnsSource(mouse(path))
    src.open()
    cmds = read_commands(master, 4)
    assert cmds == [
        (P.CMD_GET_VERSION, None),
        (P.CMD_SET_CPI, 400),
        (P.CMD_SET_K, 7),
        (P.CMD_GET_STATUS, None),
    ]
    assert src.health.connected
    src.close()


def test_packets_become_reports_and_health(pty):
    master, path = pty
    raw = []
    src = AdnsSource(mouse(path), on_raw=lambda t, b: raw.append((t, b)))
    src.open()
    read_commands(master, 4)
    wire = P.encode_packet(
        P.Status(0, 100, P.STATE_OK, P.REASON_ACK, 0x17, 0x09, 7, 400, 1250, 0, 0, 0)
    )
    for i, seq in enumerate([1, 2, 4, 5]):  # seq 3 is lost on the line
        wire += P.encode_packet(P.Motion(seq, 1000 + 8750 * i, 10, -20, 7, 60 + i, 0))
    os.write(master, wire)
    reports = pump(src, until=lambda r: sum(len(x) for x in r) >= 4)
    t = np.concatenate([r.t for r in reports])
    dx = np.concatenate([r.dx for r in reports])
    dy = np.concatenate([r.dy for r in reports])
    assert len(t) == 4 and dx.sum() == 40 and dy.sum() == 80  # REL_Y = -Delta_Y
    assert np.all(np.diff(t) >= 0) and t[-1] <= time.monotonic()
    h = src.health
    assert h.dropped == 1 and h.extra["lost_seq"] == 1
    assert h.extra["squal"] == 63 and h.extra["sensor"] == "ok" and h.extra["k"] == 7
    assert h.error is None
    # what was recorded replays to the same reports
    replayed, _ = packets_to_reports(raw, name="floor")
    np.testing.assert_array_equal(replayed.dx, dx)
    np.testing.assert_array_equal(replayed.t, t)
    src.close()


def test_settings_resent_after_firmware_restart(pty):
    master, path = pty
    src = AdnsSource(mouse(path))
    src.open()
    read_commands(master, 4)
    # the firmware restarted: back to its defaults, K=12 and 1600 CPI
    os.write(
        master,
        P.encode_packet(
            P.Status(0, 5, P.STATE_OK, P.REASON_BOOT, 0x17, 0x19, 12, 1600, 1250, 0, 0, 0)
        ),
    )
    pump(src, timeout=0.3)
    assert read_commands(master, 2) == [(P.CMD_SET_CPI, 400), (P.CMD_SET_K, 7)]
    src.close()


def test_missing_sensor_is_an_error_in_health(pty):
    master, path = pty
    src = AdnsSource(mouse(path))
    src.open()
    os.write(
        master,
        P.encode_packet(
            P.Status(0, 5, P.STATE_NO_SENSOR, P.REASON_BOOT, 0xFF, 0, 7, 400, 1250, 0, 0, 1)
        ),
    )
    pump(src, timeout=0.3)
    assert "Product_ID read 0xff" in src.health.error
    assert src.health.extra["sensor"] == "no-sensor"
    src.close()


def test_vanished_device_raises_source_gone(pty):
    master, path = pty
    src = AdnsSource(mouse(path))
    src.open()
    os.close(master)  # the USB adapter was pulled: the pty hangs up
    with pytest.raises(SourceGone):
        for _ in range(20):
            src.read(time.monotonic())
            time.sleep(0.01)
    assert not src.health.connected and src.health.error


def test_unavailable_port():
    src = AdnsSource(mouse("/dev/nonexistent-downsampler"))
    with pytest.raises(SourceUnavailable, match="nonexistent-downsampler"):
        src.open()
    assert not src.health.connected


def test_socket_url():
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    src = AdnsSource(mouse(f"socket://127.0.0.1:{port}"))
    src.open()
    conn, _ = server.accept()
    conn.settimeout(2)
    data = b""
    while len(P.parse_commands(data)) < 4:
        data += conn.recv(4096)
    conn.sendall(P.encode_packet(P.Motion(0, 1000, 3, 4, 7, 50, 0)))
    reports = pump(src, until=lambda r: len(r) > 0)
    assert reports and reports[0].dx.tolist() == [3] and reports[0].dy.tolist() == [-4]
    src.close()
    conn.close()
    server.close()


def test_a_reconnect_keeps_counters_and_replays_as_live(tmp_path):
    """The USB adapter is pulled mid-frame while the firmware runs on, and plugged back
    (a new pty behind the same link).  The counters go on from where they were, the
    packets sent while unplugged are lost by sequence, each loss counts once, and the
    bytes handed to on_raw (what ``mousedom record`` stores, with its reopen marker)
    replay to the very reports the source gave."""
    link = str(tmp_path / "ttyADNS")
    fds: list[int] = []

    def plug() -> int:
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        fds.extend((master, slave))
        if os.path.lexists(link):
            os.unlink(link)
        os.symlink(os.ttyname(slave), link)
        return master

    def frame(seq: int) -> bytes:
        return P.encode_packet(P.Motion(seq, 300_000 + 8750 * seq, 10, 0, 7, 80, 0))

    raw: list = []
    src = AdnsSource(mouse(link), on_raw=lambda t, b: raw.append((t, bytes(b))))
    got: list = []

    def send(master: int, seqs, reports: int) -> None:
        for seq in seqs:
            f = frame(seq)
            if seq == 5:
                f = f[:4] + bytes([f[4] ^ 1]) + f[5:]  # damaged on the line
            os.write(master, f)
        got.extend(pump(src, timeout=1.0, until=lambda r: sum(map(len, r)) >= reports))

    try:
        master = plug()
        src.open()
        send(master, range(20), 19)  # 0..19, 5 damaged
        os.write(master, frame(20)[:10])  # pulled while sending 20
        got.extend(pump(src, timeout=0.1))
        assert src.health.dropped == 1 and src.health.extra["crc_errors"] == 1
        for fd in fds:
            os.close(fd)
        fds.clear()
        with pytest.raises(SourceGone):
            for _ in range(50):
                got.extend(src.read(time.monotonic()))
                time.sleep(0.01)
        master = plug()  # 21..29 were sent while unplugged
        src.open()
        send(master, range(30, 40), 10)
        h = src.health
        assert sum(map(len, got)) == 29 and h.reports == 29
        assert h.extra["motion_packets"] == 29  # not back to 0 at the reconnect
        assert h.extra["crc_errors"] == 1 and h.extra["reopens"] == 1
        assert h.extra["lost_seq"] == 11 and h.dropped == 11  # 5, 20, 21..29: once each
        # replay of what on_raw saw, reopen marker included, equals live
        assert sum(1 for _, b in raw if not b) == 1  # the reopen marker
        t = np.concatenate([r.t for r in got])
        replayed, dec = packets_to_reports(raw, name="floor")
        np.testing.assert_array_equal(replayed.t, t)
        assert dec.parser.stats.as_dict() == src.decoder.parser.stats.as_dict()
    finally:
        src.close()
        for fd in fds:
            os.close(fd)


@pytest.mark.parametrize("line", ["silent", "noise", "echo"])
def test_a_port_that_is_no_downsampler_is_gone_not_a_still_mouse(pty, line):
    """A port with another device on it, a wrong baud rate, or an adapter with nothing
    behind it: no packet ever decodes.  The source stayed connected with no error, the
    mouse live and "tracking", and the robot read as standing still for good (doctor: all
    OK).  It is read at every wake (``probe``) until a first packet, and gone (SourceGone,
    the daemon's retry) after ANSWER_S without one."""
    import random

    from mousedom.sources.adns import ANSWER_S

    master, path = pty
    src = AdnsSource(mouse(path))
    src.open()
    assert src.probe
    rng = random.Random(7)
    start = time.monotonic()
    with pytest.raises(SourceGone, match="no ADNS-3080 downsampler answers") as gone:
        while time.monotonic() < start + 3 * ANSWER_S:
            if line == "noise":
                os.write(master, bytes(rng.randrange(256) for _ in range(64)))
            elif line == "echo":  # a loop-back plug: the host's commands come back
                r, _, _ = select.select([master], [], [], 0)
                if r:
                    os.write(master, os.read(master, 4096))
            assert src.read(time.monotonic()) == []  # (as the daemon: every wake)
            time.sleep(0.01)
    assert ANSWER_S <= time.monotonic() - start < ANSWER_S + 1.0
    assert ("bytes that are no packet" in str(gone.value)) == (line != "silent"), gone.value
    assert not src.health.connected


def test_a_downsampler_answering_is_read_on_its_readiness(pty):
    """The first packet ends the probing: the port's readiness wakes the daemon as before,
    and a later silence is not taken for a foreign port."""
    from mousedom.sources.adns import ANSWER_S

    master, path = pty
    src = AdnsSource(mouse(path))
    src.open()
    os.write(master, P.encode_packet(
        P.Status(0, 100, P.STATE_OK, P.REASON_ACK, 0x17, 0x09, 7, 400, 1250, 0, 0, 0)))  # fmt: skip
    pump(src, until=lambda out: not src.probe)
    assert not src.probe
    t = time.monotonic() + 2 * ANSWER_S
    assert src.read(t) == []  # long silent since: no verdict on a downsampler's silence
    src.close()


def test_a_daemon_does_not_fuse_a_port_that_is_no_downsampler(tmp_path):
    """End to end: a rig's one serial mouse on a port that sends noise.  Its POSEs were
    "updating" with the mouse used, the robot standing still; now the mouse is missing
    (not fused before its first packet, gone after ANSWER_S, reopened, and so on) and the
    pose is held, not updated."""
    import json
    import random
    import subprocess
    import sys

    from conftest import mousedom_env

    master, slave = os.openpty()
    tty.setraw(master)
    link = tmp_path / "ttyADNS"
    link.symlink_to(os.ttyname(slave))
    rig = tmp_path / "rig.yaml"
    rig.write_text("rate_hz: 20\nmodel: diff-drive\nmice:\n  floor:\n    cpi: 1600\n"
                   "    mount: {x: 0.1, y: 0.0, yaw: 0}\n"
                   f"    serial: {{port: {link}, k: 12, sensor_cpi: 1600}}\n")  # fmt: skip
    sock = tmp_path / "d.sock"
    log = tmp_path / "daemon.log"
    command = [sys.executable, "-m", "mousedom", "run", "--config", str(rig), "--socket", str(sock)]
    with open(log, "w") as err:
        proc = subprocess.Popen(command, stderr=err, env=mousedom_env())
    rng = random.Random(3)
    try:
        end = time.monotonic() + 15
        while not sock.exists():
            assert time.monotonic() < end and proc.poll() is None
            time.sleep(0.05)
        time.sleep(0.2)
        c = socket.socket(socket.AF_UNIX)
        c.connect(str(sock))
        c.settimeout(0.01)
        buf, poses, end = b"", [], time.monotonic() + 6.5  # (two rounds of open, gone)
        while time.monotonic() < end:
            os.write(master, bytes(rng.randrange(256) for _ in range(32)))
            try:
                buf += c.recv(65536)
            except TimeoutError:
                pass
        msgs = [json.loads(line) for line in buf.split(b"\n") if line]
        poses = [m for m in msgs if m["class"] == "POSE"]
        assert len(poses) > 40
        assert all(p["missing"] == ["floor"] and p["used"] == 0 for p in poses), poses[:3]
        assert not any(p["updating"] for p in poses)
        sources = [m for m in msgs if m["class"] == "SOURCE"]
        assert sources and all(not s["live"] for s in sources)
        assert any(s["error"] and "downsampler" in s["error"] for s in sources), sources[-1]
        c.close()
        # gone, retried, gone again: said once (a WARNING every 3 s for as long as it stays)
        said = [line for line in log.read_text().splitlines()
                if "WARNING" in line and "no ADNS-3080 downsampler answers" in line]  # fmt: skip
        assert len(said) == 1, said
    finally:
        proc.terminate()
        proc.wait(10)
        for fd in (master, slave):
            os.close(fd)
