"""The daemon end to end: a real ``mousedom run`` process, FIFO mice, real sockets, signals.

Three simulated mice are written into FIFOs as raw input_event records at their real
times; the evdev source reads them (its FIFO hook) as it would read /dev/input nodes.
"""

from __future__ import annotations

import math
import os
import re
import signal
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import run_mousedom
from daemon_fixtures import RATE, Conn, rig_runner

from mousedom.fusion import sim
from mousedom.service.protocol import PROTO_MINOR


@pytest.fixture
def rig_run(tmp_path):
    yield from rig_runner(tmp_path)


def _rate(poses: list[dict]) -> float:
    return (len(poses) - 1) / (poses[-1]["t"] - poses[0]["t"])


def test_clients_rate_commands_and_sigterm(rig_run):
    run = rig_run(sim.straight(1.0, 0.1), extra="server: {queue_lines: 20, idle_timeout_s: 2}\n")
    sock = run.daemon.socket_path
    a, _stalled, slow = Conn(sock), Conn(sock), Conn(sock)
    banner = a.read()
    assert banner["class"] == "VERSION" and banner["rate_hz"] == RATE
    assert banner["sensors"] == ["front", "left", "right"] and banner["control"] is True
    slow.until("VERSION")
    slow.send({"cmd": "rate", "hz": 10, "id": 1})
    assert slow.until("OK") == {"class": "OK", "cmd": "rate", "hz": 10, "id": 1}

    # POSE at the configured rate, by stamps and by wall clock, while one client stalls.
    t_wall = time.monotonic()
    poses = a.poses(2.0)
    wall = time.monotonic() - t_wall
    assert _rate(poses) == pytest.approx(RATE, rel=0.10)
    # Real time by the wall clock too, but only as a floor: a loaded machine delays a
    # read, never adds poses (the exact rate is the stamps' one, above).
    assert len(poses) / wall > 0.75 * RATE
    assert all(p["updating"] and p["used"] == 3 and p["missing"] == [] for p in poses)
    # Driving forward: x never goes back (a window may see no motion when the real-time
    # feeder is starved on a loaded machine, so equal is allowed), and it does advance.
    xs = [p["x"] for p in poses[15:]]
    assert np.all(np.diff(xs) >= 0) and xs[-1] - xs[0] > 0.05 * (len(xs) - 1) / RATE
    assert abs(poses[-1]["vx"] - 0.1) < 0.01 and abs(poses[-1]["omega"]) < 0.05
    slow_poses = slow.poses(1.0)  # queued while the other client was read: 10 Hz by stamps
    assert len(slow_poses) >= 10
    assert np.diff([p["t"] for p in slow_poses]) == pytest.approx(0.1, abs=1e-3)

    # status: STATUS then one SOURCE per sensor
    a.send({"cmd": "status", "id": "s"})
    st = a.until("STATUS")
    assert st["id"] == "s" and st["model"] == "lsq" and st["clients"] in (2, 3)
    sources = [a.until("SOURCE") for _ in range(3)]
    assert {s["name"] for s in sources} == {"front", "left", "right"}
    for s in sources:
        assert s["connected"] and not s["excluded"] and s["kind"] == "evdev"
        assert s["age"] is not None and s["age"] < 0.1
        assert s["rate_hz"] == pytest.approx(125, rel=0.2)

    # reset, then the pose starts again from the origin
    a.send({"cmd": "reset"})
    ok = a.until("OK")
    assert ok["cmd"] == "reset" and ok["pose"] == {"x": 0.0, "y": 0.0, "theta": 0.0}
    after = a.until("POSE")
    assert abs(after["x"]) < 0.01 and after["cov"][0][0] < 1e-6

    # fix of x only: x jumps, y and theta stay
    before = a.until("POSE")
    a.send({"cmd": "fix", "x": 5.0})
    ok = a.until("OK")
    assert ok["pose"]["x"] == 5.0 and ok["pose"]["y"] == pytest.approx(before["y"], abs=1e-3)
    after = a.until("POSE")
    assert 5.0 <= after["x"] < 5.05

    # bad commands: one ERROR each, and the pose goes on undisturbed
    before = a.until("POSE")
    a.send(b'{"cmd": "fix", "x": "far"}\n{oops\n{"cmd": "jump"}\n' + b"z" * 5000 + b"\n")
    errors = [a.until("ERROR") for _ in range(4)]
    assert "x must be a number" in errors[0]["message"]
    assert "invalid JSON" in errors[1]["message"]
    assert "unknown command 'jump'" in errors[2]["message"]
    assert "line too long" in errors[3]["message"]
    after = a.until("POSE")
    assert 0 <= after["x"] - before["x"] < 0.02

    # the client that never read has been dropped; the others never waited for it
    deadline = time.monotonic() + 8
    while True:
        a.send({"cmd": "status"})
        st = a.until("STATUS")
        if st["dropped_clients"] >= 1 or time.monotonic() > deadline:
            break
        a.poses(0.5)
    assert st["dropped_clients"] == 1 and st["clients"] == 2
    # It took nothing for idle_timeout_s (its owed lines never overflow: POSE and SOURCE
    # lines waiting for it are replaced by newer ones, see docs/protocol.md).
    assert "idle: took nothing for 2 s" in run.daemon.log()

    # SIGTERM: exit 0 within a second, socket removed
    t = time.monotonic()
    run.daemon.signal(signal.SIGTERM)
    rc = run.daemon.proc.wait(5)
    assert rc == 0 and time.monotonic() - t < 1.0
    assert not sock.exists()
    with pytest.raises(EOFError):
        while True:
            a.read()


def test_sighup_reload_good_and_broken_with_sd_notify(rig_run, tmp_path):
    notify_path = str(tmp_path / "notify")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(notify_path)
    notify.settimeout(5)
    env = {"NOTIFY_SOCKET": notify_path, "WATCHDOG_USEC": "200000"}
    run = rig_run(sim.straight(1.0, 0.1), env=env)
    ready = notify.recv(4096).decode()
    assert ready.startswith("READY=1\nSTATUS=3/3 sensors live")
    assert notify.recv(4096) == b"WATCHDOG=1"
    messages: list[str] = []  # drained as systemd would, so that no ping is lost
    drain = threading.Thread(target=_drain, args=(notify, messages), daemon=True)
    drain.start()

    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    poses = c.poses(0.6)
    assert _rate(poses) == pytest.approx(RATE, rel=0.1)

    # A good config with half the rate: the rate changes, the pose carries on.
    text = run.config.read_text()
    run.config.write_text(text.replace(f"rate_hz: {RATE!r}", "rate_hz: 25.0"))
    x_before = c.until("POSE")["x"]
    run.daemon.signal(signal.SIGHUP)
    time.sleep(0.5)
    poses = c.poses(1.0)
    assert _rate(poses[2:]) == pytest.approx(25.0, rel=0.1)
    assert x_before <= poses[0]["x"] < x_before + 0.1  # kept, not reset to 0
    assert "reloaded" in run.daemon.log()

    # A broken config: logged with file and line, the running one stays.
    run.config.write_text(text.replace("model: lsq", "model: [lsq"))
    run.daemon.signal(signal.SIGHUP)
    time.sleep(0.5)
    poses = c.poses(1.0)
    assert _rate(poses) == pytest.approx(25.0, rel=0.1)
    assert all(p["updating"] for p in poses)
    log = run.daemon.log()
    assert "reload failed, keeping the running config" in log and f"{run.config}:" in log
    assert run.daemon.proc.poll() is None

    assert "RELOADING=1" in messages
    assert any(m.startswith("READY=1\nSTATUS=reload failed") for m in messages)
    assert messages.count("WATCHDOG=1") >= 10  # every 0.1 s
    assert run.daemon.stop() == 0
    drain.join(5)
    assert messages[-1] == "STOPPING=1"
    notify.close()


def _drain(sock: socket.socket, into: list[str]) -> None:
    sock.settimeout(1.0)
    try:
        while True:
            into.append(sock.recv(4096).decode())
    except (TimeoutError, OSError):
        pass


def test_sensor_vanishes_and_returns(rig_run):
    """Degraded operation: lsq goes on with two mice; with one it holds the pose."""
    run = rig_run(sim.arc(2.0, 1.0, 0.1))
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    c.poses(0.3)

    with run.feeder.lock:
        run.mice["left"].unplug(remove=True)
    p = c.until("POSE", lambda m: m["missing"] == ["left"])
    src = c.until("SOURCE", lambda m: m["name"] == "left")
    assert src["connected"] is False and src["excluded"] is True and src["error"]
    degraded = c.poses(0.4)
    assert all(q["updating"] and q["used"] == 2 for q in degraded[2:])
    assert degraded[-1]["x"] > p["x"]  # still tracking with two mice

    # the mouse comes back: the daemon reopens it and uses it again
    with run.feeder.lock:
        run.mice["left"].replug()
    p = c.until("POSE", lambda m: m["missing"] == [] and m["used"] == 3, limit=500)
    assert c.until("SOURCE", lambda m: m["name"] == "left")["connected"] is True

    # two gone: one mouse cannot give lsq its rank; the pose is held, not invented
    with run.feeder.lock:
        run.mice["left"].unplug(remove=True)
        run.mice["right"].unplug(remove=True)
    c.until("POSE", lambda m: sorted(m["missing"]) == ["left", "right"])
    held = c.poses(0.5)[3:]
    assert held and not any(q["updating"] for q in held)
    assert len({(q["x"], q["y"], q["theta"]) for q in held}) == 1
    assert all(q["vx"] == 0 and q["omega"] == 0 for q in held)
    assert "left: lost" in run.daemon.log()
    assert run.daemon.stop() == 0


def test_pose_tracks_the_simulated_motion_and_records_it(rig_run, tmp_path):
    """The pose after a quarter turn and a leg matches the simulator's truth; --record
    keeps every report, flushed on SIGINT, and replays to the same pose."""
    traj = sim.sequence(sim.turn(math.pi / 2, 1.5), sim.straight(0.2, 0.2))
    record = tmp_path / "run.mdcap"
    run = rig_run(traj, args=("--record", str(record)))
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    run.feeder.join(run.result.duration + 10)  # every report written
    sent = [[float(r.dx.sum()), float(r.dy.sum())] for r in run.result.reports.values()]
    deadline = time.monotonic() + 10
    while True:  # until every count sent is in, and fused into some window
        c.send({"cmd": "status"})
        st = c.until("STATUS")
        fused = np.allclose(st["counts_out"], st["counts_in"], atol=1e-6)
        if (st["counts_in"] == sent and fused) or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert st["counts_in"] == sent
    pose = st["pose"]
    truth = run.result.truth(run.result.duration)[0]
    assert pose["theta"] == pytest.approx(truth[2], abs=0.02)
    assert pose["x"] == pytest.approx(truth[0], abs=0.01)
    assert pose["y"] == pytest.approx(truth[1], abs=0.01)
    os.kill(run.daemon.proc.pid, signal.SIGINT)
    assert run.daemon.proc.wait(2) == 0

    from mousedom.capture import open_capture

    cap = open_capture(str(record))
    got = {d.mouse: 0 for d in cap.devices}
    sums = {d.mouse: np.zeros(2) for d in cap.devices}
    for feed in cap.feeds():
        for batch in feed.batches:
            for mo in batch.motion:
                name = cap.devices[mo.device].mouse
                got[name] += len(mo.t)
                sums[name] += (mo.dx.sum(), mo.dy.sum())
    assert got == run.feeder.sent  # every report that was fed is in the recording
    for name, rep in run.result.reports.items():
        assert tuple(sums[name]) == (rep.dx.sum(), rep.dy.sum())
    out = run_mousedom("replay", "--config", str(run.config), "--capture", str(record))
    assert out.returncode == 0, out.stderr
    m = re.search(
        r"final pose\s+x ([-+.\d]+) m\s+y ([-+.\d]+) m\s+theta ([-+.\d]+) rad", out.stdout
    )
    assert m, out.stdout
    assert [float(v) for v in m.groups()] == pytest.approx(list(truth), abs=2e-3)


def test_the_replay_of_a_recording_has_the_daemons_windows(rig_run, tmp_path):
    """``run --record`` writes where the daemon's window grid began (header grid_start),
    and replay anchors its windows there: every POSE the daemon published is a row of the
    replay of its own recording, with the same pose.  Replay anchored at the first report
    instead, a fraction of a window later: no POSE time was a replay row (0 of 370)."""
    from mousedom.capture import open_capture
    from mousedom.capture.posecsv import read_csv

    traj = sim.sequence(sim.straight(0.2, 0.2), sim.turn(math.pi / 2, 1.0), sim.pause(0.2))
    record = tmp_path / "run.mdcap"
    run = rig_run(traj, args=("--record", str(record)))
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    poses = []
    end = time.monotonic() + run.result.duration + 1.0
    while time.monotonic() < end:
        m = c.read()
        if m["class"] == "POSE":
            poses.append(m)
    os.kill(run.daemon.proc.pid, signal.SIGINT)
    assert run.daemon.proc.wait(5) == 0
    assert open_capture(str(record)).grid_start() is not None
    out = tmp_path / "replay.csv"
    proc = run_mousedom("replay", "--config", str(run.config), "--capture", str(record),
                        "-o", str(out))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    rows = read_csv(out.read_text())
    by_t = {round(float(t), 5): k for k, t in enumerate(rows["t"])}
    # every window published is a row, the idle ones after the last report too: the
    # recording's last sync was the last second's checkpoint, and its replay lacked those
    missing = [p["t"] for p in poses if round(p["t"], 5) not in by_t]
    assert not missing, (len(missing), len(poses), missing[:3], missing[-3:])
    moving = [p for p in poses if p["used"] and (p["vx"] or p["omega"])]
    assert len(moving) > 50
    matched = [(p, by_t.get(round(p["t"], 5))) for p in moving]
    assert all(k is not None for _, k in matched), [p["t"] for p, k in matched if k is None][:5]
    # The same pose in the windows whose reports all came before they closed (a report the
    # feeder wrote late, on a loaded machine, is the daemon's late report, not replay's)
    same = [max(abs(p[c] - rows[c][k]) for c in ("x", "y", "theta")) < 1e-5 for p, k in matched]
    assert np.mean(same) > 0.9, np.mean(same)


def test_demo_runs_the_bundled_capture_in_real_time(tmp_path):
    """``mousedom run --demo``: the real daemon on the bundled simulated capture."""
    from daemon_fixtures import DaemonProcess

    sock = tmp_path / "run" / "demo.sock"
    daemon = DaemonProcess(Path("unused"), sock, "--demo", config_args=False)
    try:
        daemon.wait_socket()
        c = Conn(sock)
        banner = c.until("VERSION")
        assert banner["sensors"] == ["front", "left", "right"]
        t = time.monotonic()
        poses = c.poses(1.5)
        wall = time.monotonic() - t
        assert len(poses) / wall > 0.75 * banner["rate_hz"]  # a floor: see above
        assert all(p["updating"] and p["used"] == 3 for p in poses)
        moved = math.hypot(poses[-1]["x"] - poses[0]["x"], poses[-1]["y"] - poses[0]["y"])
        turned = abs(poses[-1]["theta"] - poses[0]["theta"])
        assert moved > 0.05 or turned > 0.05  # the demo rig drives around
        assert "demo: a simulated rig" in daemon.log()
    finally:
        assert daemon.stop() == 0


def test_two_mice_on_one_device_the_second_is_refused(tmp_path):
    """Two rules resolving to one device would split (or double) its counts: the daemon
    opens the first, keeps the second out with a message naming both, and goes on."""
    from daemon_fixtures import DaemonProcess, FifoMouse, write_rig_config

    rig = sim.three_mouse_rig()
    names = [m.name for m in rig.mice]  # front, left, right
    fifos = {n: tmp_path / f"{n}.fifo" for n in names}
    mice = {n: FifoMouse(p) for n, p in fifos.items() if n != "right"}
    link = tmp_path / "also-left"
    link.symlink_to(fifos["left"])  # the same FIFO by another name
    fifos["right"] = link
    config = write_rig_config(tmp_path / "rig.yaml", rig, fifos)
    daemon = DaemonProcess(config, tmp_path / "run" / "mousedom.sock")
    try:
        daemon.wait_socket()
        for m in mice.values():
            m.attach()
        c = Conn(daemon.socket_path)
        status = c.until("SOURCE", lambda m: m["name"] == "right")
        assert not status["live"]
        assert f"{fifos['left']} is already open as left" in status["error"]
        pose = c.until("POSE", lambda m: m["missing"] == ["right"])
        assert pose["used"] == 2 and pose["updating"]
        assert "right:" in daemon.log() and "already open as left" in daemon.log()
        c.close()
    finally:
        assert daemon.stop() == 0


def test_hostile_lines_from_any_client_never_stop_the_daemon(rig_run):
    """Lines that once killed the daemon (issue 11): an id that cannot be echoed as JSON
    (1e999 parses to inf), 2000 "[" (recursion in the JSON parser), a 5000-digit integer.
    Each gets an ERROR; the daemon, this client and the other clients go on."""
    run = rig_run(sim.straight(1.0, 0.1))
    sock = run.daemon.socket_path
    bystander, attacker = Conn(sock), Conn(sock)
    bystander.until("VERSION")
    attacker.until("VERSION")
    attacker.send(b'{"cmd":"status","id":1e999}\n')
    assert "id must be" in attacker.until("ERROR")["message"]
    attacker.send(b"[" * 2000 + b"\n")
    assert "nested deeper" in attacker.until("ERROR")["message"]
    attacker.send(b'{"cmd":"status","id":' + b"9" * 5000 + b"}\n")
    assert attacker.until("ERROR")["class"] == "ERROR"
    attacker.send({"cmd": "status", "id": "still here"})
    assert attacker.until("STATUS")["id"] == "still here"
    assert len(bystander.poses(0.3)) >= 5
    assert run.daemon.proc.poll() is None


def _alias_bomb(levels: int = 8) -> str:
    text = "a0: &a0 [x, x, x, x, x, x, x, x, x]\n"
    for i in range(1, levels + 1):
        text += f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n"
    return text


def test_hostile_reloads_keep_the_running_config_and_sigterm_works(rig_run):
    """Issue 11: SIGHUP with a deeply nested config exited (RecursionError); with an alias
    bomb the daemon published nothing and ignored SIGTERM.  Now each reload is refused with
    file and line, the pose goes on, and SIGTERM still stops the daemon at once."""
    run = rig_run(sim.straight(1.0, 0.1))
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    good = run.config.read_text()
    for bad, words in (
        ("x: " + "[" * 3000 + "]" * 3000 + "\n", "nest"),
        (_alias_bomb(), "aliases expand"),
        ("x: " + "9" * 5000 + "\n", "integer of 5000"),
    ):
        run.config.write_text(good + bad)
        run.daemon.signal(signal.SIGHUP)
        deadline = time.monotonic() + 5
        while "reload failed" not in run.daemon.log() and time.monotonic() < deadline:
            c.poses(0.1)
        log = run.daemon.log()
        assert "reload failed, keeping the running config" in log and words in log, log
        assert f"{run.config}:" in log
        assert len(c.poses(0.3)) >= 5 and run.daemon.proc.poll() is None
        run.daemon.stderr_path.write_text("")  # the next round reads only its own lines
    t = time.monotonic()
    run.daemon.signal(signal.SIGTERM)
    assert run.daemon.proc.wait(5) == 0 and time.monotonic() - t < 1.0


def test_a_reload_that_changes_the_rate_never_steps_pose_time_back(rig_run):
    run = rig_run(sim.straight(2.0, 0.1))
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    text = run.config.read_text()
    times = [p["t"] for p in c.poses(0.3)]
    for rate in (200.0, 10.0, 100.0):  # up, down and up again
        run.config.write_text(text.replace(f"rate_hz: {RATE!r}", f"rate_hz: {rate!r}"))
        run.daemon.signal(signal.SIGHUP)
        times += [p["t"] for p in c.poses(0.4)]
    assert "reloaded" in run.daemon.log()
    assert np.all(np.diff(times) > 0), np.diff(times).min()


def test_a_recording_that_cannot_grow_stops_and_the_daemon_goes_on(rig_run, tmp_path):
    """`run --record` on a full disk exited rc 1 with a traceback; now the recording stops
    with one logged line and the pose goes on (a file size limit stands in for the disk)."""
    import resource

    def small_files() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    out = tmp_path / "run.mdcap"
    run = rig_run(sim.straight(3.0, 0.1), args=("--record", str(out)), preexec=small_files)
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    deadline = time.monotonic() + 10
    while "recording" not in run.daemon.log() or "stopped" not in run.daemon.log():
        assert time.monotonic() < deadline, run.daemon.log()
        c.poses(0.2)
    assert "File too large" in run.daemon.log() and "Traceback" not in run.daemon.log()
    assert len(c.poses(0.5)) >= 10 and run.daemon.proc.poll() is None
    assert 0 < out.stat().st_size <= 20_000


def test_a_lifted_mouse_is_excluded_in_pose_and_source(rig_run):
    """Issue 16 end to end: one of three FIFO mice goes silent while the robot drives (a
    lift); POSE names it excluded, the pose follows the truth, and SOURCE says why."""
    import dataclasses

    rig = sim.three_mouse_rig()
    lifted = dataclasses.replace(rig.mice[0], lost=((1.0, 3.5),))
    faulty = dataclasses.replace(rig, mice=(lifted, *rig.mice[1:]))
    run = rig_run(sim.straight(1.2, 0.3), rig=rig, faulty=faulty)
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    pose = c.until("POSE", lambda m: m["excluded"] == ["front"], limit=20000)
    assert pose["used"] == 2 and pose["consistent"] and pose["updating"]
    late = c.until("POSE", lambda m: m["t"] - pose["t"] > 1.0, limit=20000)
    assert late["excluded"] == ["front"]
    truth_x = 0.3 * (late["t"] - pose["t"]) + pose["x"]
    assert late["x"] == pytest.approx(truth_x, abs=0.01)  # still driving at 0.3 m/s
    # (the first window of a lift holds part of the motion: "inconsistent"; the windows
    # after it are empty: "silent while others move")
    c.send({"cmd": "status"})
    c.until("STATUS")
    front = next(s for s in (c.until("SOURCE") for _ in range(3)) if s["name"] == "front")
    assert front["state"] == "excluded" and front["reason"] == "silent while others move"
    assert front["excluded"] is True and front["connected"] is True


def test_a_wrong_cpi_is_in_source_and_logged_once(rig_run):
    """Issue 31 item 3 end to end: one of three FIFO mice reads 13 % short (its CPI as
    configured is 15 % off the truth); within seconds of driving SOURCE carries its learnt
    scale and the warning; the others' scales are 1; the journal has the warning once, not
    at each renewal (twice a second).  Its scale is beyond the 10 % limit, so the mouse is
    held out (ScaleLearner.beyond), and SOURCE and the warning say so."""
    import dataclasses

    rig = sim.three_mouse_rig()
    short = dataclasses.replace(rig.mice[1], cpi_x=450 * 0.87, cpi_y=450 * 0.87)
    faulty = dataclasses.replace(rig, mice=(rig.mice[0], short, rig.mice[2]))
    drive = sim.sequence(sim.straight(0.5, 0.3), sim.arc(0.5, math.pi / 2, 0.3),
                         sim.turn(-math.pi / 2, 1.0))  # fmt: skip
    run = rig_run(drive, rig=rig, faulty=faulty)
    c = Conn(run.daemon.socket_path)
    assert c.until("VERSION")["proto_minor"] == PROTO_MINOR
    first = c.until("SOURCE", lambda m: m["name"] == "front")
    assert {"scale", "scale_spread", "scale_applied", "scale_warning"} <= set(first)
    left = c.until("SOURCE", lambda m: m["name"] == "left" and m["scale_warning"], limit=20000)
    assert left["scale"] == pytest.approx(1 / 0.87, rel=0.01) and left["scale_spread"] < 0.01
    assert left["scale_applied"] is True
    warning = left["scale_warning"]
    assert warning.startswith("mouse left reads 13 % less than the others: check its cpi "
                              "(learnt scale 1."), warning  # fmt: skip
    # (learnt from reports read in real time: the last digit may be either side)
    assert float(warning.split("learnt scale ")[1].split()[0]) == pytest.approx(1.149, abs=0.003)
    others = [c.until("SOURCE", lambda m, n=n: m["name"] == n) for n in ("front", "right")]
    for s in others:
        assert s["scale"] == pytest.approx(1.0, abs=0.01) and s["scale_warning"] is None
        assert s["scale_applied"] is False
    c.poses(2.0)  # four renewals more, each still warning
    held = c.until("SOURCE", lambda m: m["name"] == "left")
    assert held["state"] == "excluded" and held["scale_warning"].endswith(
        "; beyond scale_limit: held out"
    ), held
    said = [line for line in run.daemon.log().splitlines() if "mouse left reads" in line]
    assert len(said) == 1 and said[0].startswith("WARNING mousedom.service.scales: mouse left")


def test_a_reload_from_a_fifo_or_device_is_refused_and_never_blocks(rig_run, tmp_path):
    """Issue 26: SIGHUP with the config or the calibration file replaced by a FIFO blocked
    the daemon in open() (no POSE, SIGTERM ignored) until something wrote to it.  Now the
    file is opened non-blocking and checked: the reload is refused naming what the file is,
    the pose goes on, SIGTERM stops the daemon at once."""
    cal = tmp_path / "cal.yaml"
    cal.write_text("mice: {}\n")
    run = rig_run(sim.straight(1.5, 0.1), extra=f"calibration: {cal}\n")
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    good = run.config.read_text()
    for victim, what in ((run.config, "FIFO"), (cal, "FIFO"), (run.config, "character device")):
        victim.unlink()
        if what == "FIFO":
            os.mkfifo(victim)
        else:
            os.symlink("/dev/zero", victim)
        run.daemon.signal(signal.SIGHUP)
        deadline = time.monotonic() + 5
        while "reload failed" not in run.daemon.log() and time.monotonic() < deadline:
            c.poses(0.1)
        log = run.daemon.log()
        assert "reload failed, keeping the running config" in log, log
        assert f"{victim}" in log and f"is a {what}" in log, log
        assert len(c.poses(0.3)) >= 5 and run.daemon.proc.poll() is None
        victim.unlink()
        if victim == run.config:
            victim.write_text(good)
        else:
            victim.write_text("mice: {}\n")
        run.daemon.stderr_path.write_text("")
    t = time.monotonic()
    run.daemon.signal(signal.SIGTERM)
    assert run.daemon.proc.wait(5) == 0 and time.monotonic() - t < 1.0


def test_after_a_stall_every_reading_client_gets_the_latest_pose_and_stays(rig_run):
    """Issue 26: after the loop stalled 6-9 s the daemon closed the backlog of windows at
    once, queued every POSE to every client, and dropped all 20 healthy readers together.
    Now each client's queue holds only the latest POSE beyond its kernel buffer, and the
    daemon's own stall does not count against anyone."""
    run = rig_run(sim.straight(20.0, 0.05), extra="server: {queue_lines: 20}\n")
    clients = [Conn(run.daemon.socket_path) for _ in range(20)]
    for c in clients:
        c.until("VERSION")
        c.poses(0.05)
    run.daemon.signal(signal.SIGSTOP)
    time.sleep(7.0)
    run.daemon.signal(signal.SIGCONT)
    time.sleep(1.0)  # the backlog (350 windows) closes at once
    counts, lasts, walls = [], [], []
    for c in clients:  # each reads what the kernel held, then the freshest, then the rate
        poses = c.poses(0.4)
        counts.append(len(poses))
        lasts.append(poses[-1]["t"])
        walls.append(time.monotonic())
    assert max(counts) < 200, counts  # not the backlog: what 32 KiB holds, and fresh ones
    # Each ends its read on a pose as fresh as the one before it, a read later.
    lag = [(lasts[k] - lasts[0]) - (walls[k] - walls[0]) for k in range(len(clients))]
    assert max(map(abs, lag)) < 0.15, lag
    for c in clients:  # all still connected, at the rate
        assert len(c.poses(0.3)) >= 5
    assert "dropping" not in run.daemon.log(), run.daemon.log()


def test_the_running_loop_imports_nothing(rig_run):
    """Every module the loop uses is imported before it listens: an import in the loop
    (numpy.ma, at np.median's first call in the first scale solve, was 8 ms) stalls every
    mouse's window behind it.  A drive long enough for the scale learner's solves, the
    once-a-second SOURCE messages and a client's commands, with Python's import log on."""
    traj = sim.sequence(sim.turn(math.pi / 2, 1.0), sim.straight(0.3, 0.2), sim.arc(0.3, 1.0))
    run = rig_run(traj, env={"PYTHONPROFILEIMPORTTIME": "1"})
    c = Conn(run.daemon.socket_path)
    c.until("VERSION")
    run.feeder.join(run.result.duration + 10)
    c.send({"cmd": "status"})
    st = c.until("STATUS")
    assert st["pose"]["theta"] != 0.0  # the drive was fused
    c.until("SOURCE")
    assert run.daemon.stop() == 0
    log = run.daemon.log()
    listening = log.index("listening on ")
    late = [ln for ln in log[listening:].splitlines() if ln.startswith("import time:")]
    assert late == [], "\n".join(late)


def test_a_replayed_rig_wakes_about_once_a_window(tmp_path):
    """Replay sources (``run --demo``) have no descriptor: the loop reads them on its own
    schedule.  Its plan took them for mice with no last report, so it gave up on a window
    one period after its end, when a still replayed mouse's silence had not yet closed it
    (the count function's ``late_report_s``): from then on it woke with a zero timeout
    until it did, 83 wakes a window and 17 % of a core for the idle demo at 50 Hz.  Their
    last report plans their silence as an evdev mouse's does."""
    from daemon_fixtures import DaemonProcess

    sock = tmp_path / "run" / "demo.sock"
    daemon = DaemonProcess(Path("unused"), sock, "--demo", config_args=False)
    try:
        daemon.wait_socket()
        c = Conn(sock)
        c.until("VERSION")
        c.send({"cmd": "rate", "hz": 0})
        c.poses(0.5)  # (the start's first windows)

        def status() -> dict:
            c.send({"cmd": "status"})
            return c.until("STATUS")

        a = status()
        time.sleep(3.0)
        b = status()
        windows, wakes = b["poses"] - a["poses"], b["wakes"] - a["wakes"]
        assert windows > 0.75 * 3.0 * a["rate_hz"], (windows, a)
        # a wake per window, one per second for SOURCE and the status commands: under 2
        assert wakes < 2 * windows, (wakes, windows)
    finally:
        daemon.stop()


def _catches_sighup(pid: int) -> bool:
    """Whether the process has a handler for SIGHUP (/proc's SigCgt mask, bit 0)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & 1)
    return False


def test_a_sighup_while_the_daemon_starts_is_a_reload_not_its_end(tmp_path):
    """Python's default for SIGHUP ends the process: one in the first half second of `run`
    (imports, config, sensors) killed the daemon with no word (exit -1).  From the moment
    `mousedom run` catches it (cli.main's first step), SIGHUPs every 20 ms until the
    socket listens are kept: the daemon comes up, reloads once its handlers are in, and
    stops cleanly."""
    import subprocess
    import sys

    from conftest import mousedom_env

    from mousedom.demo import DEMO_CONFIG

    cfg = tmp_path / "rig.yaml"
    cfg.write_text(DEMO_CONFIG.read_text().replace(
        "demo-rig.mdcap", str(DEMO_CONFIG.with_suffix(".mdcap"))))  # fmt: skip
    sock = tmp_path / "d.sock"
    proc = subprocess.Popen([sys.executable, "-m", "mousedom", "run", "--config", str(cfg),
                             "--socket", str(sock)], env=mousedom_env(),
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 20
        while not _catches_sighup(proc.pid):  # (the interpreter's own start: no handler)
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.002)
        sent = 0
        while not sock.exists():
            assert proc.poll() is None, f"died on SIGHUP: rc {proc.returncode}"
            assert time.monotonic() < deadline, "never listened"
            proc.send_signal(signal.SIGHUP)
            sent += 1
            time.sleep(0.02)
        c = Conn(sock)
        assert c.read()["class"] == "VERSION"
        c.until("POSE")
        c.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert sent >= 3, sent  # (some came before the daemon's own handlers)
    assert "reloaded" in err and "Traceback" not in err, err


def test_run_holds_sighup_from_its_first_step_and_other_commands_do_not():
    """cli.main catches SIGHUP before anything else for `run` (the daemon's reload); any
    other command keeps Python's default (a terminal's hangup ends it)."""
    import subprocess
    import sys

    from conftest import mousedom_env

    code = (
        "import os, signal, sys\n"
        "signal.signal(signal.SIGHUP, signal.SIG_DFL)\n"  # (as a shell gives it; not nohup's)
        "from mousedom import cli, hangup\n"
        "cli.main(sys.argv[1:])\n"  # (fails at once: no such config)
        "os.kill(os.getpid(), signal.SIGHUP)\n"
        "print('alive', hangup.pending())\n"
    )
    for argv, alive in ((["run", "-c", "/nonexistent/rig.yaml"], True),
                        (["-v", "run", "-c", "/nonexistent/rig.yaml"], True),
                        (["check-config", "-c", "/nonexistent/rig.yaml"], False)):  # fmt: skip
        p = subprocess.run([sys.executable, "-c", code, *argv], env=mousedom_env(),
                           capture_output=True, text=True, timeout=60)  # fmt: skip
        if alive:
            assert p.returncode == 0 and p.stdout.strip() == "alive True", (argv, p)
        else:
            assert p.returncode == -signal.SIGHUP, (argv, p)


def test_a_daemon_leaving_does_not_remove_another_daemons_socket(tmp_path):
    """An operator removed daemon A's socket file while it ran and started daemon B at
    the same path (docs/daemon.md: a socket with a live daemon behind it is not
    replaced).  A's SIGTERM took B's socket from under it: B ran on, unreachable.  A
    removes the socket file only where it is still the one it made."""
    from daemon_fixtures import DaemonProcess

    sock = tmp_path / "run" / "demo.sock"
    a = DaemonProcess(Path("unused"), sock, "--demo", config_args=False)
    b = None
    try:
        a.wait_socket()
        sock.unlink()
        b = DaemonProcess(Path("unused"), sock, "--demo", config_args=False,
                          log=tmp_path / "b.log")  # fmt: skip
        b.wait_socket()
        assert a.stop() == 0
        assert sock.is_socket()
        assert Conn(sock).until("VERSION")["sensors"] == ["front", "left", "right"]
        assert "not the socket this daemon made any more; not removing it" in a.log()
        assert b.stop() == 0
        assert not sock.exists()  # (b's own: removed at its exit)
    finally:
        a.stop()
        if b is not None:
            b.stop()


def test_a_client_reading_flat_out_at_the_shortest_queue_is_answered_every_status(rig_run):
    """``server.queue_lines`` at its least for the rig (4 x (sensors + 2): 20 for three
    mice): a client that sends 3,000 status commands in one write and reads as fast as it
    can gets every answer and stays.  A status answer is its STATUS and a SOURCE per
    sensor, and the SOURCE lines and POSE waiting go ahead of it; at 2-4 lines such a
    client was dropped for a full queue, and at 1 no command was answered."""
    import threading

    from mousedom.config.load import queue_lines_needed

    least = queue_lines_needed(3)
    run = rig_run(sim.straight(20.0, 0.05), extra=f"server: {{queue_lines: {least}}}\n")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.connect(str(run.daemon.socket_path))
    sock.settimeout(20.0)
    n = 3000
    writer = threading.Thread(target=sock.sendall, args=(b'{"cmd": "status"}\n' * n,))
    writer.start()
    statuses, buf, closed = 0, b"", False
    deadline = time.monotonic() + 60.0
    while statuses < n and time.monotonic() < deadline:
        data = sock.recv(65536)
        if not data:
            closed = True
            break
        *lines, buf = (buf + data).split(b"\n")
        statuses += sum(1 for line in lines if line.startswith(b'{"class":"STATUS"'))
    writer.join(10)
    sock.close()
    assert (statuses, closed) == (n, False), (statuses, closed)
    assert "queue full" not in run.daemon.log()
