"""SIGHUP on a real ``mousedom run`` process (FIFO mice, a real socket): what a reload
keeps (the pose's covariance), what it applies (the socket's group and mode), what it
tells the connected clients (a fresh VERSION when its sensors change) and what it does
not warn of (a socket path given with ``--socket``)."""

from __future__ import annotations

import grp
import os
import re
import signal
import time

import numpy as np
import pytest
from daemon_fixtures import Conn, rig_runner

from mousedom.fusion import sim


@pytest.fixture
def rig_run(tmp_path):
    yield from rig_runner(tmp_path)


def _wait_for_log(run, text: str, count: int = 1, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while run.daemon.log().count(text) < count:
        assert time.monotonic() < deadline, run.daemon.log()
        time.sleep(0.02)


def test_a_reload_carries_the_pose_covariance_on(rig_run):
    """A reload reset the covariance to zero (the pose kept, with a new tracker's
    uncertainty): the heading's variance fell 150 times, x's and y's 250 times in the
    first window after it.  On a moving rig it only grows, across the reload too."""
    run = rig_run(sim.arc(1.0, 3.0, 0.2))
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    poses = c.poses(1.5)
    run.daemon.signal(signal.SIGHUP)
    poses += c.poses(1.0)
    _wait_for_log(run, "reloaded")
    assert len(poses) > 80
    var = np.array([[p["cov"][k][k] for k in range(3)] for p in poses[5:]])
    # the heading's variance is a sum of each window's: it never goes down
    assert np.all(np.diff(var[:, 2]) >= -1e-6 * var[:-1, 2]), var[:, 2]
    # the position's turns with the heading's correlation, but never falls far
    assert np.all(var[1:, :2] >= 0.5 * var[:-1, :2]), var[:, :2]


def _other_group() -> int | None:
    """A group this process may give a file to, other than its own (root: any)."""
    mine = os.getegid()
    if os.geteuid() == 0:
        return next((g.gr_gid for g in grp.getgrall() if g.gr_gid != mine), None)
    return next((g for g in os.getgroups() if g != mine), None)


def test_a_reload_applies_the_socket_group_with_its_mode(rig_run):
    """A reload applied a new ``server.mode`` but not ``server.group``: 0600 with no group
    to 0660 with a group gave 0660 on the daemon's own group.  Now both, as at start; a
    group that does not exist holds both back (a new mode on the old group could open the
    socket to the wrong people), and a config without a group gives the file back the
    group it was made with."""
    gid = _other_group()
    if gid is None:
        pytest.skip("no group other than this process's to give the socket to")
    name = grp.getgrgid(gid).gr_name
    run = rig_run(sim.straight(2.0, 0.1), extra='server: {mode: "0600"}\n')
    sock = run.daemon.socket_path
    made = os.stat(sock)
    assert made.st_mode & 0o777 == 0o600 and made.st_gid != gid
    text = run.config.read_text()

    def reload(server: str, n: int) -> os.stat_result:
        run.config.write_text(text.replace('server: {mode: "0600"}', server))
        run.daemon.signal(signal.SIGHUP)
        _wait_for_log(run, "reloaded", n)
        return os.stat(sock)

    st = reload(f'server: {{mode: "0660", group: {name}}}', 1)
    assert (st.st_mode & 0o777, st.st_gid) == (0o660, gid)
    st = reload('server: {mode: "0666", group: no-such-group-here}', 2)
    assert (st.st_mode & 0o777, st.st_gid) == (0o660, gid)
    assert "server.group: no group named 'no-such-group-here'" in run.daemon.log()
    st = reload('server: {mode: "0640"}', 3)
    assert (st.st_mode & 0o777, st.st_gid) == (0o640, made.st_gid)
    Conn(sock).until("VERSION")  # still the daemon's listening socket
    assert "Traceback" not in run.daemon.log()


def _check_invariant(messages: list[dict], sensors: list[str]) -> list[list[str]]:
    """Every POSE's sensors used are the latest VERSION's less its missing and excluded
    (docs/protocol.md), and every SOURCE is of a sensor that VERSION names; the VERSIONs'
    sensor lists in order."""
    seen = []
    for m in messages:
        if m["class"] == "VERSION":
            sensors = m["sensors"]
            seen.append(sensors)
        elif m["class"] == "POSE":
            assert set(m["missing"]) <= set(sensors), (m, sensors)
            assert set(m["excluded"]) <= set(sensors), (m, sensors)
            assert m["used"] == len(sensors) - len(m["missing"]) - len(m["excluded"]), (
                m,
                sensors,
            )
        elif m["class"] == "SOURCE":
            assert m["name"] in sensors, (m, sensors)
    return seen


def _read(c: Conn, seconds: float) -> list[dict]:
    out = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        out.append(c.read())
    return out


def test_a_reload_that_changes_the_sensors_sends_a_fresh_version(rig_run):
    """A reload that removed a mouse left a connected client with a VERSION naming three
    sensors while POSE said used 2, missing and excluded empty, and the removed mouse's
    SOURCE lines just stopped.  Now a client gets a fresh VERSION (and each sensor's
    SOURCE) after the old config's POSE lines and before the new one's, and every POSE
    agrees with the VERSION before it: a mouse a reload adds back is missing from the
    windows that do not use it yet.  A reload that changes nothing VERSION says sends
    none."""
    run = rig_run(sim.straight(5.0, 0.2), extra="robust: false\n")
    text = run.config.read_text()
    no_right = re.sub(r"  right:\n(    .*\n)+", "", text)
    assert no_right != text
    c = Conn(run.daemon.socket_path)
    first = c.read()
    assert first["class"] == "VERSION" and first["sensors"] == ["front", "left", "right"]
    messages = _read(c, 0.6)

    run.config.write_text(no_right)
    run.daemon.signal(signal.SIGHUP)
    messages += _read(c, 0.8)
    _wait_for_log(run, "reloaded", 1)

    with run.feeder.lock:  # its writer goes; it comes back once the reload opens it
        run.mice["right"].unplug()
    run.config.write_text(text)
    run.daemon.signal(signal.SIGHUP)
    with run.feeder.lock:
        run.mice["right"].attach()
    messages += _read(c, 1.2)
    _wait_for_log(run, "reloaded", 2)

    run.daemon.signal(signal.SIGHUP)  # the same config: nothing for the clients to hear
    messages += _read(c, 0.6)
    _wait_for_log(run, "reloaded", 3)

    seen = _check_invariant(messages, first["sensors"])
    assert seen == [["front", "left"], ["front", "left", "right"]]
    poses = [m for m in messages if m["class"] == "POSE"]
    assert any(p["used"] == 2 and p["missing"] == [] for p in poses)  # right removed
    assert poses[-1]["used"] == 3  # and back
    # each fresh VERSION is followed by the SOURCE of every sensor it names
    for k, m in enumerate(messages):
        if m["class"] == "VERSION":
            after = messages[k + 1 : k + 1 + len(m["sensors"])]
            assert [s["name"] for s in after if s["class"] == "SOURCE"] == m["sensors"]
    # a client connecting now is told the same
    assert Conn(run.daemon.socket_path).read()["sensors"] == ["front", "left", "right"]


def test_a_socket_given_on_the_command_line_is_no_config_change(rig_run, tmp_path):
    """With `run --socket` in use and the config naming another path, every reload
    warned "server.socket changed: takes effect at the next restart" though the config
    had not changed: the config was compared with the path in use, not with itself."""
    other = tmp_path / "other" / "named.sock"
    run = rig_run(sim.straight(2.0, 0.1), extra=f"server: {{socket: {other}}}\n")
    text = run.config.read_text()
    run.daemon.signal(signal.SIGHUP)
    _wait_for_log(run, "reloaded", 1)
    assert "server.socket changed" not in run.daemon.log()
    # ... while a change of the config's value is still said to wait for a restart
    run.config.write_text(text.replace(str(other), str(tmp_path / "third.sock")))
    run.daemon.signal(signal.SIGHUP)
    _wait_for_log(run, "reloaded", 2)
    assert "server.socket changed: takes effect at the next restart" in run.daemon.log()
