"""``mousedom.client`` and ``mousedom watch`` against a real daemon; CLI errors of run/watch."""

from __future__ import annotations

import json
import math

import pytest
from conftest import mousedom_env, run_mousedom
from daemon_fixtures import RATE, rig_runner

from mousedom.client import (
    Client,
    ClientError,
    CommandError,
    DaemonNotRunning,
    NotADaemon,
    Pose,
    find_socket,
    poses,
    socket_candidates,
)
from mousedom.fusion import sim


@pytest.fixture
def rig_run(tmp_path):
    yield from rig_runner(tmp_path)


def test_client_iterates_poses_and_sends_commands(rig_run):
    run = rig_run(sim.straight(1.0, 0.2))
    with Client(str(run.daemon.socket_path), timeout=5) as c:
        assert c.version["class"] == "VERSION" and c.version["rate_hz"] == RATE
        assert c.rate(10)["hz"] == 10
        got = []
        for pose in c:
            assert isinstance(pose, Pose) and len(pose.cov) == 3
            got.append(pose)
            if len(got) == 8:
                break
        # (poses sent before the rate command took effect come first, at the full rate)
        gaps = [round(b.t - a.t, 3) for a, b in zip(got, got[1:], strict=False)]
        assert gaps[-4:] == [0.1] * 4
        assert c.reset(x=1.0, theta=math.pi / 2)["pose"] == {
            "x": 1.0,
            "y": 0.0,
            "theta": math.pi / 2,
        }
        fixed = c.fix(y=-2.0)["pose"]
        assert fixed["y"] == -2.0 and fixed["theta"] == pytest.approx(math.pi / 2, abs=0.05)
        status = c.status()
        assert status["class"] == "STATUS" and status["rate_hz"] == RATE
        with pytest.raises(CommandError, match="at least one of x, y, theta"):
            c.fix()
        with pytest.raises(CommandError, match="hz must be between"):
            c.rate(-1)
        # poses that arrived while commands waited for answers are not lost
        nxt = next(iter(c))
        assert nxt.t > got[-1].t
        assert set(c.sources) == {"front", "left", "right"}


def test_poses_generator(rig_run):
    run = rig_run(sim.straight(0.5, 0.2))
    it = poses(str(run.daemon.socket_path), rate_hz=25)
    first, second = next(it), next(it)
    assert second.t - first.t == pytest.approx(0.04, abs=1e-3)
    it.close()


def test_client_errors_are_the_standard_ones_python_users_catch(tmp_path):
    """No daemon: a ConnectionError (an OSError) with the OS's errno, and the client's own
    base class; something else at the socket: the same; an ERROR answer: a RuntimeError."""
    import errno

    with pytest.raises(ConnectionError, match="cannot connect.*is the daemon running") as info:
        Client(str(tmp_path / "none.sock"))
    assert isinstance(info.value, DaemonNotRunning) and isinstance(info.value, ClientError)
    assert info.value.errno == errno.ENOENT and not str(info.value).startswith("[Errno")
    with pytest.raises(OSError):
        Client(str(tmp_path / "none.sock"))
    # a socket whose server says something else
    path, th = _scripted(tmp_path, lambda conn: conn.sendall(b'{"class": "HELLO"}\n'))
    with pytest.raises(NotADaemon, match="not a mousedom socket"):
        Client(path, timeout=5)
    th.join(5)
    assert issubclass(NotADaemon, ConnectionError) and issubclass(CommandError, RuntimeError)


def test_watch_without_a_daemon_is_one_line(tmp_path):
    from conftest import run_mousedom

    p = run_mousedom("watch", "--socket", str(tmp_path / "none.sock"))
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.startswith("mousedom: error: ") and p.stderr.count("\n") == 1


def test_socket_discovery(tmp_path):
    """The first candidate that exists wins; with none, the default path."""
    import os

    env = {"XDG_RUNTIME_DIR": str(tmp_path / "xdg"), "TMPDIR": str(tmp_path / "t")}
    cands = socket_candidates(env)
    assert len(cands) == len(set(cands))
    assert str(tmp_path / "t" / f"mousedom-{os.getuid()}" / "mousedom.sock") in cands
    existing = [p for p in cands if os.path.exists(p)]
    if existing:  # a daemon runs on this machine: it is found first
        assert find_socket(env) == existing[0]
        return
    assert find_socket(env) == cands[0]
    os.makedirs(os.path.dirname(cands[-1]))
    open(cands[-1], "w").close()
    assert find_socket(env) == cands[-1]


def test_watch_prints_poses_and_stops_after_count(rig_run):
    run = rig_run(sim.straight(1.0, 0.2))
    out = run_mousedom("watch", "--socket", str(run.daemon.socket_path), "--count", "3", timeout=20)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("mousedom 0.1.0 at ") and "model lsq" in lines[0]
    pose_lines = [x for x in lines if x.startswith("t ")]
    assert len(pose_lines) == 3 and "3 used, updating" in pose_lines[0]
    assert any(x.startswith("source front") for x in lines)

    raw = run_mousedom(
        "watch", "--socket", str(run.daemon.socket_path), "--count", "2", "--json", timeout=20
    )
    assert raw.returncode == 0
    assert raw.stdout.count('"class": "POSE"') == 2
    # a rate the daemon refuses, or no number: one line, no traceback
    for rate, said in (("20000", "the daemon refused it: rate: hz must be between"),
                       ("nan", "--rate must be a number of at least 0")):  # fmt: skip
        bad = run_mousedom("watch", "--socket", str(run.daemon.socket_path), "--rate", rate,
                           timeout=20)  # fmt: skip
        assert bad.returncode == 2 and said in bad.stderr and "Traceback" not in bad.stderr
    # --count with --rate 0 (no POSE asked for) waited for ever: refused before it asks
    bad = run_mousedom("watch", "--socket", str(run.daemon.socket_path), "--rate", "0",
                       "--count", "1", timeout=20)  # fmt: skip
    assert bad.returncode == 2 and "--rate 0 asks for none" in bad.stderr, bad.stderr


def test_watch_without_daemon_says_so(tmp_path):
    out = run_mousedom("watch", "--socket", str(tmp_path / "no.sock"))
    assert out.returncode == 2
    assert "cannot connect" in out.stderr and "mousedom run" in out.stderr
    assert "Traceback" not in out.stderr


def test_run_config_errors_are_one_line(tmp_path):
    out = run_mousedom("run", "--config", str(tmp_path / "missing.yaml"))
    assert out.returncode == 2 and "missing.yaml: config file not found" in out.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text("rate_hz: 100\nmodel: lsq\nmice:\n  a: {cpi: -5}\n")
    out = run_mousedom("run", "--config", str(bad))
    assert out.returncode == 2 and f"{bad}:4" in out.stderr and "Traceback" not in out.stderr
    out = run_mousedom("run", "--demo", "--config", str(bad))
    assert out.returncode == 2 and "exclude each other" in out.stderr


def test_run_without_config_points_at_demo(tmp_path):
    import os

    if os.path.exists("/etc/mousedom/mousedom.yaml"):
        pytest.skip("a real config is installed on this machine")
    out = run_mousedom("run", env=mousedom_env())
    assert out.returncode == 2
    assert "/etc/mousedom/mousedom.yaml: config file not found" in out.stderr
    assert "mousedom run --demo" in out.stderr


def _watch_on_a_pty(socket_path, *args, env_extra=None, size=(100, 40)) -> str:
    """``mousedom watch`` on a real pseudo-terminal of the given size; its output."""
    import fcntl
    import os
    import pty
    import struct
    import subprocess
    import sys
    import termios

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", size[1], size[0], 0, 0))
    env = mousedom_env(**(env_extra or {}))
    proc = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "watch", "--socket", str(socket_path), *args],
        stdin=slave, stdout=slave, stderr=subprocess.PIPE, env=env,
    )  # fmt: skip
    os.close(slave)
    out = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:  # EIO: the other side closed
            break
        if not chunk:
            break
        out += chunk
    assert proc.wait(30) == 0, proc.stderr.read()
    os.close(master)
    return out.decode()


def test_watch_on_a_terminal_explains_itself(rig_run):
    """Issue 14 item 5, on a real pty: one redrawn screen per pose; the heading wrapped to
    (-180, 180] after a turn of 450 degrees (the daemon's theta is continuous); time since
    the watch began; labelled fields with units; sensor states in colour; the path."""
    import math
    import re

    run = rig_run(sim.turn(math.radians(450), 2.5), env={"TERM": "xterm"})
    text = _watch_on_a_pty(run.daemon.socket_path, "--count", "45", "--rate", "10",
                           env_extra={"TERM": "xterm"})  # fmt: skip
    screens = text.split("\x1b[H\x1b[J")[1:]
    assert len(screens) >= 45
    headings = [float(h) for h in re.findall(r"heading\s+([+-][\d.]+) deg", text)]
    assert headings and all(-180 < h <= 180 for h in headings)
    last = screens[-1]
    final = float(re.search(r"heading\s+([+-][\d.]+) deg", last).group(1))
    assert abs(final - 90.0) < 5.0, final  # 450 degrees is a quarter turn past a whole one
    times = [float(t) for t in re.findall(r"time\s+([\d.]+) s since the watch began", text)]
    assert times[0] < 0.2 and 3.5 < times[-1] < 6.0
    for label in ("position (odom)  x", "velocity (body)  forward", "m/s", "1 sigma",
                  "(std dev)", "3 used, updating", "path (o start, @ now)",
                  "reports/s", "last report", "scale"):  # fmt: skip
        assert label in last, label
    assert last.count("\x1b[32mtracking") == 3  # three sensors, green
    plain = _watch_on_a_pty(run.daemon.socket_path, "--count", "2",
                            env_extra={"TERM": "xterm", "NO_COLOR": "1"})  # fmt: skip
    assert "\x1b[32m" not in plain and "tracking" in plain


def test_watch_screen_pieces():
    """The pure view: wrapping, the sketch's start and end marks, states by word."""
    from mousedom.commands import _watchview as view

    assert view.wrap_degrees(math.radians(442)) == pytest.approx(82)
    assert Pose.from_message(
        {
            "t": 0,
            "x": 0,
            "y": 0,
            "theta": math.radians(442),
            "vx": 0,
            "vy": 0,
            "omega": 0,
            "cov": [[0] * 3] * 3,
            "used": 3,
            "updating": True,
            "missing": [],
        }
    ).heading_deg == pytest.approx(82)
    assert view.wrap_degrees(math.radians(-180)) == pytest.approx(180)
    assert view.wrap_degrees(math.radians(181)) == pytest.approx(-179)
    box = view.sketch([(0.0, 0.0), (0.5, 0.0), (1.0, 0.25)], 30, 8)
    start = next(i for i, row in enumerate(box[1:-1], 1) if "o" in row)  # inside the frame
    now = next(i for i, row in enumerate(box[1:-1], 1) if "@" in row)
    assert len(box) == 8 and start == len(box) - 2 and now < start  # y up: @ is higher
    assert box[start].index("o") < box[now].index("@")  # and further along x
    assert view.sketch([(0.0, 0.0)], 30, 8) == []  # no motion yet: no box
    assert view.source_state({"connected": False}) == "gone"
    assert view.source_state({"connected": True, "excluded": True}) == "excluded"
    assert view.source_state({"connected": True, "state": "suspect"}) == "suspect"


def test_run_without_socket_uses_the_runtime_directory_and_says_how_to_watch(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    env = mousedom_env(RUNTIME_DIRECTORY=str(tmp_path))
    proc = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "run", "--demo"],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    sock = tmp_path / "mousedom.sock"
    deadline = time.monotonic() + 15
    while not sock.exists():
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=5)
    assert proc.returncode == 0
    assert "watch it with: " in err and f"-m mousedom watch --socket {sock}" in err
    assert not sock.exists()


def test_watch_says_which_mice_the_fusion_left_out():
    """Issue 16: the POSE's excluded and suspect sensors, and a window the mice disagreed
    on, in words; a SOURCE's state and reason."""
    from mousedom.commands import _watchview as view

    pose = {"t": 5.0, "x": 0.1, "y": 0.0, "theta": 0.0, "vx": 0.3, "vy": 0.0, "omega": 0.0,
            "cov": [[1e-6, 0, 0], [0, 1e-6, 0], [0, 0, 1e-6]], "used": 2, "updating": True,
            "missing": [], "excluded": ["front"], "suspect": [], "consistent": True}  # fmt: skip
    assert "excluded: front" in view.pose_lines(pose, 0.0)[-1]
    assert view.pose_line(pose, 0.0).endswith("excluded: front")
    pose.update(excluded=[], suspect=["left", "right"], consistent=False)
    line = view.pose_line(pose, 0.0)
    assert "suspect: left, right" in line and "DISAGREE" in line
    src = {"name": "front", "connected": True, "state": "excluded",
           "reason": "silent while others move"}  # fmt: skip
    text = view.source_line(src)
    assert "excluded" in text and "(silent while others move)" in text


def _visible(text: str) -> str:
    import re

    return re.sub(r"\x1b\[[0-9;]*[A-Za-z]", "", text)


def _learnt(text: str, tail: str) -> float:
    """The percentage of a "+14.9 % applied" at the end of (or starting) a line."""
    import re

    m = re.search(r"([+-]\d+\.\d) %" + re.escape(tail), text)
    assert m, text
    return float(m.group(1))


def test_watch_shows_each_mouses_scale_and_the_warning_in_80_columns(rig_run):
    """Issue 31 item 3: on a real 80-column pty, a mouse whose CPI is 15 % off shows its
    learnt scale ("+14.9 % applied") and the learner's warning under its row (after its
    reason: held out, as beyond scale_limit), the others theirs ("+0.0 %"); no line of the
    screen is wider than the terminal.  Piped, each
    SOURCE line carries the scale and the warning too."""
    import dataclasses

    rig = sim.three_mouse_rig()
    short = dataclasses.replace(rig.mice[1], cpi_x=450 * 0.87, cpi_y=450 * 0.87)
    faulty = dataclasses.replace(rig, mice=(rig.mice[0], short, rig.mice[2]))
    drive = sim.sequence(sim.straight(0.5, 0.3), sim.arc(0.5, math.pi / 2, 0.3),
                         sim.turn(-math.pi / 2, 1.0), sim.pause(3.0))  # fmt: skip
    run = rig_run(drive, rig=rig, faulty=faulty, env={"TERM": "xterm"})
    with Client(str(run.daemon.socket_path), timeout=10) as c:  # until the warning is there
        for _ in c.messages():
            if (c.sources.get("left") or {}).get("scale_warning"):
                break
    text = _watch_on_a_pty(run.daemon.socket_path, "--count", "12", "--rate", "10",
                           env_extra={"TERM": "xterm"}, size=(80, 40))  # fmt: skip
    last = _visible(text.split("\x1b[H\x1b[J")[-1])
    wide = [line for scr in text.split("\x1b[H\x1b[J")  # no newline ends a screen
            for line in _visible(scr).splitlines() if len(line) > 80]  # fmt: skip
    assert wide == [], wide
    rows = {line.split()[0]: line for line in last.splitlines() if line.split()[:1]
            and line.split()[0] in ("front", "left", "right")}  # fmt: skip
    # the scale learnt live, from reports read in real time: the truth (1 / 0.87 = +14.94 %)
    # to within what the stamps' timing leaves (the last digit may be either side)
    assert _learnt(rows["left"], " applied") == pytest.approx(14.9, abs=0.3), rows
    assert rows["front"].endswith(" +0.0 %") and rows["right"].endswith(" +0.0 %"), rows
    # (its reason first where the mouse is held out: 15 % is beyond scale_limit)
    under = last.split(rows["left"])[1].splitlines()[1:5]
    notes = " ".join(line.strip() for line in under)
    assert "warning: " in notes, under
    warning = "warning: " + notes.split("warning: ", 1)[1]
    assert warning.startswith("warning: mouse left reads 13 % less than the others: check "
                              "its cpi (learnt scale 1."), under  # fmt: skip
    learnt = float(warning.split("learnt scale ")[1].split()[0])
    assert learnt == pytest.approx(1.149, abs=0.003) and " +- 0." in warning, under
    piped = run_mousedom("watch", "--socket", str(run.daemon.socket_path), "--count", "15",
                         timeout=20)  # fmt: skip
    left = [line for line in piped.stdout.splitlines() if line.startswith("source left")]
    assert left and _learnt(left[-1].split("scale ")[1], " applied") == pytest.approx(14.9, abs=0.3)
    assert "warning: mouse left reads 13 % less than the others" in left[-1]


def test_watch_sensor_table_pieces():
    """The pure view of the sensors: the scale as a deviation ("-" where none is learnt,
    as from an older daemon), notes wrapped under the row, 80 columns with SQUAL and
    names of 10 characters."""
    from mousedom.commands import _watchview as view

    assert view.scale_text({"scale": 1.029, "scale_applied": True}) == "+2.9 % applied"
    assert view.scale_text({"scale": 0.99996, "scale_applied": False}) == "+0.0 %"
    assert view.scale_text({"scale": None}) == view.scale_text({}) == "-"
    warning = "mouse abcdefghij reads 99 % more than the others: check its cpi " * 2
    src = [{"name": "abcdefghij", "connected": True, "state": "excluded", "rate_hz": 8000.0,
            "age": 123.0, "residual": 0.25, "dropped": 123456, "squal": 120, "scale": 0.5,
            "scale_applied": True, "reason": "silent while others move",
            "scale_warning": warning},
           {"name": "old", "connected": False, "error": "unplugged"}]  # fmt: skip
    lines = view.source_table(src, color=True, width=80)
    assert max(len(_visible(line)) for line in lines) <= 80
    assert lines[0].split() == ["sensor", "state", "reports/s", "last", "report", "residual",
                                "SQUAL", "scale"]  # fmt: skip
    row = ["abcdefghij", "excluded", "8000.0", "123", "s", "ago", "250.000", "mm", "120",
           "-50.0", "%", "applied"]  # fmt: skip
    assert _visible(lines[1]).split() == row
    assert lines[2] == "    123456 frames dropped (reports lost by the kernel or the link)"
    assert lines[3] == "    (silent while others move)"
    assert lines[4].startswith("    \x1b[33mwarning: mouse abcdefghij")  # a warning, in colour
    assert _visible(lines[-1]) == "    unplugged" and "\x1b[31mgone" in lines[-2]
    assert lines[-2].endswith("  -")
    # a name of 15 characters still fits
    src[0]["name"] = "abcdefghijklmno"
    assert max(len(_visible(line)) for line in view.source_table(src, True, 80)) <= 80


def test_poses_at_a_rate_start_after_its_answer(tmp_path):
    """POSE lines the daemon sent before it answered ``rate`` came at its own rate: the
    generator asked for 25 Hz gave a first step of 0.02 s (a 50 Hz daemon) when they were
    yielded.  A scripted daemon sends three before the answer."""
    import socket as _socket
    import threading

    path = str(tmp_path / "d.sock")
    srv = _socket.socket(_socket.AF_UNIX, _socket.SOCK_STREAM)
    srv.bind(path)
    srv.listen(1)

    def pose(t: float) -> bytes:
        msg = {"class": "POSE", "t": t, "x": t, "y": 0.0, "theta": 0.0, "vx": 0.0, "vy": 0.0,
               "omega": 0.0, "cov": [[0.0] * 3] * 3, "used": 1, "updating": True}  # fmt: skip
        return (json.dumps(msg) + "\n").encode()

    def talk() -> None:
        conn, _ = srv.accept()
        conn.sendall(b'{"class": "VERSION", "rate_hz": 50.0, "sensors": ["a"]}\n')
        request = json.loads(conn.makefile().readline())
        conn.sendall(pose(0.0) + pose(0.02) + pose(0.04))
        conn.sendall(
            json.dumps({"class": "OK", "cmd": "rate", "hz": 25.0, "id": request["id"]}).encode()
            + b"\n"
            + b'{"class": "SOURCE", "name": "a"}\n'
            + pose(0.08)
            + pose(0.12)
        )
        conn.close()

    th = threading.Thread(target=talk)
    th.start()
    got = [p.t for p in poses(path, rate_hz=25)]
    th.join(5)
    srv.close()
    assert got == [0.08, 0.12]


def test_a_version_after_a_reload_replaces_the_clients_and_its_sources(tmp_path):
    """A reload that changes the sensors sends a fresh VERSION, then each sensor's SOURCE
    (docs/protocol.md): the client's ``version`` is the latest, and a sensor the new one
    no longer names leaves ``sources``.  A scripted daemon."""
    import socket as _socket
    import threading

    path = str(tmp_path / "d.sock")
    srv = _socket.socket(_socket.AF_UNIX, _socket.SOCK_STREAM)
    srv.bind(path)
    srv.listen(1)

    def line(msg: dict) -> bytes:
        return (json.dumps(msg) + "\n").encode()

    def pose(t: float, used: int) -> bytes:
        return line({"class": "POSE", "t": t, "x": t, "y": 0.0, "theta": 0.0, "vx": 0.0,
                     "vy": 0.0, "omega": 0.0, "cov": [[0.0] * 3] * 3, "used": used,
                     "updating": True, "missing": []})  # fmt: skip

    def talk() -> None:
        conn, _ = srv.accept()
        conn.sendall(
            line({"class": "VERSION", "rate_hz": 50.0, "sensors": ["a", "b"]})
            + line({"class": "SOURCE", "name": "a"})
            + line({"class": "SOURCE", "name": "b"})
            + pose(0.02, 2)
            + line({"class": "VERSION", "rate_hz": 25.0, "sensors": ["a"]})
            + line({"class": "SOURCE", "name": "a"})
            + pose(0.06, 1)
        )
        conn.close()

    th = threading.Thread(target=talk)
    th.start()
    with Client(path, timeout=5) as c:
        got = []
        for p in c:
            got.append(p.used)
            if len(got) == 1:
                assert c.version["sensors"] == ["a", "b"] and set(c.sources) == {"a", "b"}
        assert got == [2, 1]
        assert c.version["sensors"] == ["a"] and c.version["rate_hz"] == 25.0
        assert set(c.sources) == {"a"}
    th.join(5)
    srv.close()


def _scripted(tmp_path, script):
    """A scripted daemon on a real Unix socket: ``script(conn)`` talks to one client."""
    import socket as _socket
    import threading

    path = str(tmp_path / "s.sock")
    srv = _socket.socket(_socket.AF_UNIX, _socket.SOCK_STREAM)
    srv.bind(path)
    srv.listen(1)

    def serve() -> None:
        conn, _ = srv.accept()
        try:
            script(conn)
        finally:
            conn.close()
            srv.close()

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    return path, th


_VERSION = b'{"class": "VERSION", "rate_hz": 50.0, "sensors": ["a"]}\n'
_POSE = (
    b'{"class": "POSE", "t": 1.0, "x": 0.0, "y": 0.0, "theta": 0.0, "vx": 0.0, "vy": 0.0,'
    b' "omega": 0.0, "cov": [[0,0,0],[0,0,0],[0,0,0]], "used": 1, "updating": true}\n'
)


@pytest.mark.parametrize("first", [b"[]\n", b"42\n", b'"VERSION"\n', b"null\n", b"{bad\n"])
def test_a_first_line_that_is_no_message_is_not_a_daemon(tmp_path, first):
    """A JSON line that is no object raised AttributeError (a traceback in watch and
    doctor)."""
    path, th = _scripted(tmp_path, lambda conn: conn.sendall(first))
    with pytest.raises(NotADaemon):
        Client(path, timeout=5)
    th.join(5)


def test_a_full_daemon_says_so_and_is_not_called_no_daemon(tmp_path):
    """A daemon at its client limit answers ERROR "too many clients" and closes: the client
    said "not a mousedom socket", and doctor hinted at the wrong socket."""
    from mousedom.client import DaemonRefused

    refusal = b'{"class": "ERROR", "message": "too many clients; try again later"}\n'
    path, th = _scripted(tmp_path, lambda conn: conn.sendall(refusal))
    with pytest.raises(DaemonRefused, match="the daemon refused: too many clients"):
        Client(path, timeout=5)
    th.join(5)


def test_a_last_line_cut_off_ends_the_iterator(tmp_path):
    """The daemon gone within a line: the iterator ends, as protocol.md says (it raised
    json's JSONDecodeError: a traceback in watch)."""
    path, th = _scripted(tmp_path, lambda conn: conn.sendall(_VERSION + _POSE + _POSE[:30]))
    with Client(path, timeout=5) as c:
        assert [p.t for p in c] == [1.0]
    th.join(5)


def test_the_daemon_gone_during_a_command_is_connection_lost(tmp_path):
    """EOFError escaped the client's error table (doctor and watch printed tracebacks)."""
    from mousedom.client import ConnectionLost

    def script(conn) -> None:
        conn.sendall(_VERSION)
        conn.makefile().readline()  # the command, then gone

    path, th = _scripted(tmp_path, script)
    with Client(path, timeout=5) as c:
        with pytest.raises(ConnectionLost, match="before answering status") as e:
            c.status()
        assert isinstance(e.value, ClientError) and isinstance(e.value, OSError)
    th.join(5)


def test_an_answer_with_id_true_is_no_answer_to_command_one(tmp_path):
    """True == 1 in Python: an OK with "id": true was taken for command 1's answer."""

    def script(conn) -> None:
        conn.sendall(_VERSION)
        request = json.loads(conn.makefile().readline())
        conn.sendall(b'{"class": "OK", "cmd": "status", "id": true}\n')
        conn.sendall(json.dumps({"class": "STATUS", "id": request["id"]}).encode() + b"\n")

    path, th = _scripted(tmp_path, script)
    with Client(path, timeout=5) as c:
        assert c.status()["class"] == "STATUS"
    th.join(5)


def test_a_pose_number_beyond_any_float_is_infinite_not_an_error():
    m = json.loads(_POSE)
    m["x"] = 10**400
    assert Pose.from_message(m).x == math.inf


def test_a_version_read_while_a_command_waits_is_the_clients_when_it_comes_up(tmp_path):
    """A reload's VERSION read while ``status()`` waited was kept at once: the old config's
    POSE queued before it was then yielded with ``version`` and ``sources`` of the new."""

    def script(conn) -> None:
        conn.sendall(b'{"class": "VERSION", "rate_hz": 50.0, "sensors": ["a", "b"]}\n'
                     b'{"class": "SOURCE", "name": "b"}\n')  # fmt: skip
        request = json.loads(conn.makefile().readline())
        conn.sendall(_POSE + b'{"class": "VERSION", "rate_hz": 50.0, "sensors": ["a"]}\n'
                     + _POSE.replace(b'"t": 1.0', b'"t": 2.0'))  # fmt: skip
        conn.sendall(json.dumps({"class": "STATUS", "id": request["id"]}).encode() + b"\n")

    path, th = _scripted(tmp_path, script)
    with Client(path, timeout=5) as c:
        c.status()
        seen = []
        for pose in c:
            seen.append((pose.t, tuple(c.version["sensors"]), set(c.sources)))
            if len(seen) == 2:
                break
    th.join(5)
    assert seen == [(1.0, ("a", "b"), {"b"}), (2.0, ("a",), set())]
