"""The client commands (``watch``, ``doctor``) against something at the socket that is not
a healthy daemon: well-formed JSON of the wrong shape, a daemon that never answers, one that
is stopped (its backlog full), one that goes silent.  A clear line and an exit status, never
a traceback, never a wait without end."""

from __future__ import annotations

import json
import random
import socket
import threading
import time
from typing import Any

import pytest
from daemon_fixtures import stopped_listener

from mousedom import cli
from mousedom.client import Client, DaemonNotAnswering, NotADaemon
from mousedom.service import message_shapes
from mousedom.service.protocol import (
    error_message,
    ok_message,
    pose_message,
    source_message,
    version_message,
)
from mousedom.sources.base import SourceHealth

WEIRD: list[Any] = [None, 5, -1, "x", "", [], {}, [1, 2], {"a": 1}, True, 1e308, -1e308,
                    10**30, "\u202e", [[None]], 0, [[1, 2, 3]] * 3, [None, None, None]]  # fmt: skip


def _templates() -> dict[str, dict[str, Any]]:
    """One message of each class, made by the daemon's own builders."""
    health = SourceHealth(name="front", kind="evdev", connected=True, reports=12, last_t=1.0,
                          extra={"squal": 40})  # fmt: skip
    return {
        "VERSION": version_message(50.0, ["front", "left"], True, "lsq"),
        "POSE": pose_message(
            1.0,
            (0.1, 0.2, 0.3),
            (0.0, 0.0, 0.1),
            [[1e-6, 0, 0], [0, 1e-6, 0], [0, 0, 1e-6]],
            2,
            True,
            missing=("left",),
            gyro=(0.0, 1e-3, 1e-4, 0.5, 0.01),
        ),  # fmt: skip
        "SOURCE": source_message(
            health.as_dict(),
            age=0.01,
            residual=1e-5,
            excluded=False,
            live=True,
            state="tracking",
            reason=None,
            scale=1.001,
            scale_spread=0.002,
            scale_applied=False,
            scale_warning=None,
        ),  # fmt: skip
        "STATUS": {
            "class": "STATUS",
            "uptime": 3.0,
            "config": "/etc/mousedom/rig.yaml",
            "model": "lsq",
            "rate_hz": 50.0,
            "pose": {"x": 0.0, "y": 0.0, "theta": 0.0},
            "clients": 1,
        },  # fmt: skip
        "OK": ok_message("rate", hz=10.0),
        "ERROR": error_message("nope"),
    }


def _mutate(rng: random.Random, msg: dict[str, Any]) -> dict[str, Any]:
    m = dict(msg)
    for _ in range(rng.randint(1, 3)):
        key = rng.choice([k for k in m if k != "class"])
        if rng.random() < 0.3:
            del m[key]
        else:
            m[key] = rng.choice(WEIRD)
    return m


def test_the_daemons_own_messages_have_their_shapes():
    for cls, msg in _templates().items():
        assert message_shapes.problem(json.loads(json.dumps(msg))) is None, cls


def _fake(path: str, stream: list[dict[str, Any]], answer, until: float) -> threading.Thread:
    """A daemon at ``path`` that sends ``stream`` (VERSION first) and then POSE lines, and
    answers each command with ``answer(cmd)``."""
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    srv.bind(path)
    srv.listen(4)
    srv.settimeout(until - time.monotonic())

    def serve() -> None:
        try:
            conn, _ = srv.accept()
        except OSError:
            srv.close()
            return
        conn.settimeout(0.02)
        buf = b""
        try:
            for msg in stream:
                conn.sendall((json.dumps(msg) + "\n").encode())
            while time.monotonic() < until:
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    data = b""
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    conn.sendall((json.dumps(answer(json.loads(line))) + "\n").encode())
                conn.sendall((json.dumps(stream[-1]) + "\n").encode())
                time.sleep(0.02)
        except OSError:
            pass
        finally:
            conn.close()
            srv.close()

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    return th


@pytest.mark.parametrize("seed", range(24))
def test_watch_and_doctor_meet_messages_of_the_wrong_shape_with_one_line(tmp_path, capsys, seed):
    """A daemon (or something else at its socket) sending well-formed JSON of the wrong
    shape gave tracebacks in ``watch`` (21 of 24 runs: ``must be real number, not dict``,
    ``KeyError: 't'``) and ``doctor`` (``Unknown format code 'g'``).  Every line is held
    to its class's shape (``service.message_shapes``): either it shows, or one line says
    what is wrong with it and the command exits non-zero."""
    rng = random.Random(seed)
    t = _templates()
    kinds = ["VERSION", "POSE", "SOURCE", "STATUS", "OK"]
    bad = rng.choice(kinds)
    msgs = {k: (_mutate(rng, v) if k == bad else v) for k, v in t.items()}
    stream = [msgs["VERSION"], msgs["SOURCE"], msgs["POSE"]]

    def answer(cmd: dict[str, Any]) -> dict[str, Any]:
        reply = msgs["STATUS"] if cmd.get("cmd") == "status" else msgs["OK"]
        return {**reply, "id": cmd.get("id")}

    for argv in (["watch", "--count", "3", "--json"], ["watch", "--count", "3"],
                 ["doctor", "--timeout", "0.5"]):  # fmt: skip
        path = str(tmp_path / f"{argv[0]}{len(argv)}.sock")
        th = _fake(path, stream, answer, time.monotonic() + 5.0)
        code = cli.main([*argv, "--socket", path])
        th.join(6)
        err = capsys.readouterr().err
        assert "Traceback" not in err, err
        shaped = message_shapes.problem(json.loads(json.dumps(msgs[bad]))) is None
        if argv[0] == "watch" and not shaped and bad in ("VERSION", "POSE", "SOURCE", "OK"):
            assert code != 0 and "does not follow the protocol" in err, (code, err)


def test_a_stopped_daemon_is_said_to_be_stopped_not_waited_for(tmp_path):
    """A daemon stopped by SIGSTOP (or hung) whose listen backlog is full: connect() waited
    for ever in ``watch``, ``doctor`` and a second ``run``.  The client's connect and banner
    are bounded, and say what it is."""
    path = str(tmp_path / "s.sock")
    with stopped_listener(path):
        t = time.monotonic()
        with pytest.raises(DaemonNotAnswering, match="stopped, hung or overloaded"):
            Client(path, timeout=0.5)
        assert time.monotonic() - t < 2.0


def test_a_daemon_that_takes_the_connection_and_says_nothing(tmp_path, capsys):
    """Accepted but no banner (a daemon stopped after its accept): the client says the
    daemon does not answer; doctor's hint names the daemon's state, not another socket."""
    path = str(tmp_path / "s.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    srv.bind(path)
    srv.listen(4)
    try:
        with pytest.raises(DaemonNotAnswering, match="said nothing in 0.5 s"):
            Client(path, timeout=0.5)
        code = cli.main(["doctor", "--timeout", "0.5", "--socket", path])
        out = capsys.readouterr()
        assert code != 0
        assert "kill -CONT" in out.out + out.err, out
        assert "give the daemon's socket" not in out.out + out.err, out
    finally:
        srv.close()


def test_a_command_the_daemon_never_answers_times_out_though_poses_come(tmp_path):
    """Poses kept coming, each in time, and the command waited for its answer for ever
    (doctor's ``--timeout`` bounded nothing)."""
    t = _templates()
    path = str(tmp_path / "s.sock")
    th = _fake(path, [t["VERSION"], t["POSE"]], lambda cmd: t["POSE"], time.monotonic() + 5)
    with Client(path, timeout=0.5) as c:
        start = time.monotonic()
        with pytest.raises(TimeoutError, match="no answer to status"):
            c.status()
        assert time.monotonic() - start < 1.5
    th.join(6)


def test_watch_says_when_the_daemon_goes_silent(tmp_path, capsys, monkeypatch):
    """A daemon that stops after its banner: watch printed nothing and waited for ever.
    It sends each sensor's SOURCE every second, so a silence says it stopped."""
    from mousedom.commands import watch

    monkeypatch.setattr(watch, "SILENCE_S", 0.5)
    from test_client import _scripted

    t = _templates()

    def banner_then_silence(conn: socket.socket) -> None:
        conn.sendall((json.dumps(t["VERSION"]) + "\n").encode())
        line = conn.makefile("rb").readline()
        conn.sendall((json.dumps({**t["OK"], "id": json.loads(line)["id"]}) + "\n").encode())
        time.sleep(3)

    path, th = _scripted(tmp_path, banner_then_silence)
    start = time.monotonic()
    code = cli.main(["watch", "--socket", path])
    err = capsys.readouterr().err
    assert code != 0 and "sent nothing for 0.5 s" in err, (code, err)
    assert time.monotonic() - start < 2.5
    th.join(5)


def test_a_pose_of_the_wrong_shape_is_not_a_daemon(tmp_path):
    t = _templates()
    wrong = {**t["POSE"], "x": {"a": 1}}
    path = str(tmp_path / "s.sock")
    th = _fake(path, [t["VERSION"], wrong], lambda cmd: t["OK"], time.monotonic() + 5)
    with Client(path, timeout=2) as c:
        with pytest.raises(NotADaemon, match="a POSE whose 'x' is"):
            next(iter(c))
    th.join(6)
