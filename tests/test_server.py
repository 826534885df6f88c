"""The Unix-socket server on real sockets: banner, commands, permissions, limits, stalls."""

from __future__ import annotations

import json
import logging
import os
import queue
import selectors
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace

import pytest
from conftest import mousedom_env
from daemon_fixtures import stopped_listener

from mousedom.config import ServerConfig
from mousedom.errors import UserError
from mousedom.service import server as server_module
from mousedom.service.protocol import encode, error_message, ok_message
from mousedom.service.server import Server
from mousedom.service.socketfile import default_socket_path

NOBODY = 65534


class Harness:
    """A Server driven by its own selector loop in a thread; work is posted to that thread."""

    def __init__(self, path: str, settings: ServerConfig) -> None:
        self.sel = selectors.DefaultSelector()
        self.commands: list[tuple[int, str, dict]] = []
        self.server = Server(path, settings, self.sel, self._on_command, self._on_connect)
        self.server.open()
        self.jobs: queue.Queue = queue.Queue()
        self.wake_r, self.wake_w = os.pipe()
        self.sel.register(self.wake_r, selectors.EVENT_READ, lambda m: os.read(self.wake_r, 512))
        self.stop = False
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _on_connect(self, client):
        return [{"class": "VERSION", "control": client.control}]

    def _on_command(self, client, cmd):
        self.commands.append((client.uid, cmd.name, cmd.args))
        if cmd.name == "rate":
            client.set_rate(cmd.args["hz"])
        return [ok_message(cmd.name, cmd.id)]

    def _loop(self) -> None:
        while not self.stop:
            events = self.sel.select(0.05)
            self.server.tick(time.monotonic())
            for key, mask in events:
                key.data(mask)
            self.server.serve_backlog()
            if self.server.backlog_ready():  # (as the daemon's loop: no sleep before a turn)
                os.write(self.wake_w, b"x")
            while not self.jobs.empty():
                self.jobs.get()()

    def call(self, fn) -> None:
        done = threading.Event()
        self.jobs.put(lambda: (fn(), done.set()))
        os.write(self.wake_w, b"x")
        assert done.wait(5)

    def close(self) -> None:
        self.call(self.server.close)
        self.stop = True
        os.write(self.wake_w, b"x")
        self.thread.join(5)


@pytest.fixture
def harness(tmp_path):
    made = []

    def make(path=None, **kw):
        path = path or str(tmp_path / "run" / "m.sock")
        h = Harness(path, replace(ServerConfig(), **kw))
        made.append(h)
        return h

    yield make
    for h in made:
        if h.thread.is_alive():
            h.close()


class Peer:
    def __init__(self, path: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(path)
        self.sock.settimeout(3)
        self.file = self.sock.makefile("rb")

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def read(self) -> dict:
        line = self.file.readline()
        assert line, "server closed the connection"
        return json.loads(line)

    def close(self) -> None:
        self.file.close()
        self.sock.close()


def test_banner_commands_and_errors(harness):
    h = harness(control_uids=(os.getuid(),))
    p = Peer(h.server.path)
    assert p.read() == {"class": "VERSION", "control": True}
    p.send(b'{"cmd": "fix", "x": 2.5, "id": "a"}\n')
    assert p.read() == {"class": "OK", "cmd": "fix", "id": "a"}
    p.send(b'{"cmd": "teleport"}\n{bad\n\n' + b"x" * 5000 + b"\n")
    assert "unknown command" in p.read()["message"]
    assert "invalid JSON" in p.read()["message"]
    assert "line too long (5000 > 4096 bytes)" in p.read()["message"]
    p.send(b'{"cmd": "status"}\n')
    assert p.read()["cmd"] == "status"
    # Only the two good commands reached the daemon: bad lines changed nothing.
    assert [c[1] for c in h.commands] == ["fix", "status"]
    p.close()


def test_socket_mode_and_group_come_from_config(harness, tmp_path):
    import grp

    group = grp.getgrgid(os.getgid()).gr_name
    h = harness(mode=0o640, group=group)
    st = os.stat(h.server.path)
    assert stat.S_ISSOCK(st.st_mode)
    assert stat.S_IMODE(st.st_mode) == 0o640
    assert st.st_gid == os.getgid()
    h.close()
    assert not os.path.exists(h.server.path)  # removed on close


def test_unknown_group_is_a_user_error(tmp_path):
    s = Server(
        str(tmp_path / "x.sock"),
        ServerConfig(group="no-such-group-here"),
        selectors.DefaultSelector(),
        lambda c, m: [],
        lambda c: [],
    )
    with pytest.raises(UserError, match="server.group: no group named 'no-such-group-here'"):
        s.open()
    assert not os.path.exists(tmp_path / "x.sock")


def test_stale_socket_is_replaced_but_a_live_one_is_not(harness, tmp_path):
    path = tmp_path / "run" / "m.sock"
    path.parent.mkdir()
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(path))
    stale.close()  # file left behind, nobody listening: a crashed daemon
    h = harness()
    with pytest.raises(UserError, match="another mousedom daemon is listening"):
        Server(str(path), ServerConfig(), selectors.DefaultSelector(), None, None).open()
    h.close()
    path.write_text("not a socket")
    with pytest.raises(UserError, match="exists and is not a socket"):
        Server(str(path), ServerConfig(), selectors.DefaultSelector(), None, None).open()


@pytest.mark.skipif(os.getuid() != 0, reason="needs root to connect as another uid")
def test_pose_moving_commands_need_a_listed_uid(harness):
    """SO_PEERCRED: a client running as nobody may ask status but not reset or fix."""
    shared = tempfile.mkdtemp(prefix="mousedom-test-")  # tmp_path's parents are 0700
    os.chmod(shared, 0o755)
    h = harness(os.path.join(shared, "m.sock"), control_uids=(0,), mode=0o666)
    script = (
        "import os, socket, sys\n"
        f"os.setgid({NOBODY}); os.setuid({NOBODY})\n"
        "s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); f = s.makefile('rb')\n"
        "print(f.readline().decode(), end='')\n"
        's.sendall(b\'{"cmd": "reset"}\\n{"cmd": "fix", "y": 1}\\n{"cmd": "status"}\\n\')\n'
        "for _ in range(3): print(f.readline().decode(), end='')\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", script, h.server.path], capture_output=True, text=True, timeout=10
    )
    assert out.returncode == 0, out.stderr
    lines = [json.loads(x) for x in out.stdout.splitlines()]
    assert lines[0] == {"class": "VERSION", "control": False}
    assert (
        lines[1]["class"] == "ERROR" and "reset: not allowed for uid 65534" in lines[1]["message"]
    )
    assert lines[2]["class"] == "ERROR" and "fix: not allowed" in lines[2]["message"]
    assert lines[3] == {"class": "OK", "cmd": "status"}
    assert [c[1] for c in h.commands] == ["status"]
    h.close()
    os.rmdir(shared)


@pytest.mark.parametrize("flood", [1, 7, 60])
def test_refusals_for_the_client_limit_are_logged_once_a_while_with_their_count(
    harness, caplog, monkeypatch, flood
):
    """Each refused connection logged its own WARNING: 3,000 connects wrote 392 lines. The
    first of a flood is logged; the rest are counted into the next line, at most one per
    REFUSED_LOG_S of running time; every one is still refused and counted."""
    monkeypatch.setattr(server_module, "REFUSED_LOG_S", 0.5)
    h = harness(max_clients=1)
    a = Peer(h.server.path)
    a.read()
    caplog.set_level(logging.WARNING, logger=server_module.__name__)

    def refuse(n):
        for _ in range(n):
            p = Peer(h.server.path)
            assert p.read() == error_message("too many clients; try again later")
            p.close()

    def said():
        return [r.getMessage() for r in caplog.records if "refusing" in r.getMessage()]

    refuse(flood)
    assert len(said()) == 1 and "more refused" not in said()[0]
    time.sleep(0.6)
    refuse(1)
    assert len(said()) == 2
    assert said()[1].endswith(f"; {flood - 1} more refused since the last such line") == (
        flood > 1
    ), said()
    assert h.server.refused == flood + 1
    a.close()


def test_client_limit(harness):
    h = harness(max_clients=2)
    a, b = Peer(h.server.path), Peer(h.server.path)
    a.read(), b.read()
    c = Peer(h.server.path)
    assert c.read() == error_message("too many clients; try again later")
    assert c.file.readline() == b""  # and closed
    assert h.server.refused == 1
    a.close()
    time.sleep(0.1)
    d = Peer(h.server.path)
    assert d.read()["class"] == "VERSION"


def test_stalled_client_is_dropped_and_others_keep_receiving(harness):
    """A client that reads nothing keeps only the latest POSE waiting (never a backlog), and
    goes once its output has waited idle_timeout_s of running time; the reader gets all."""
    h = harness(queue_lines=8, idle_timeout_s=0.6)
    stalled, reader = Peer(h.server.path), Peer(h.server.path)
    stalled.read(), reader.read()
    got = 0
    for k in range(600):  # ~250 kB: more than the kernel buffers
        line = encode({"class": "POSE", "k": k, "pad": "x" * 400})
        h.call(lambda line=line: h.server.broadcast_pose(0.0, line, 0.0))
        assert reader.read()["k"] == k
        got += 1
    assert got == 600 and h.server.dropped == 0  # not yet: it has not waited long enough
    held = [c for c in h.server.clients.values() if c.pose is not None]
    assert len(held) == 1 and json.loads(held[0].pose)["k"] == 599 and not held[0].queue
    deadline = time.monotonic() + 5
    while h.server.dropped == 0 and time.monotonic() < deadline:
        h.call(lambda: h.server.broadcast_pose(0.0, encode({"class": "POSE", "k": -1}), 0.0))
        assert reader.read()["k"] == -1
        time.sleep(0.05)
    assert h.server.dropped == 1 and len(h.server.clients) == 1
    # The stalled peer gets what was in the kernel buffer, then end of file.
    stalled.sock.settimeout(3)
    n = 0
    while stalled.file.readline():
        n += 1
    assert 0 < n < 600


@pytest.mark.parametrize("stall_s, windows, n_clients", [
    (9.0, 450, 5), (2.0, 30, 1), (60.0, 3000, 20), (0.5, 200, 3),
])  # fmt: skip
def test_after_a_stall_a_reading_client_gets_the_latest_pose_and_stays(
    harness, stall_s, windows, n_clients
):
    """Issue 26: after the loop stalled, the backlog of windows went to every client and
    all were dropped together.  Now each keeps only the latest POSE beyond what the kernel
    holds, the daemon's stall does not count against it, and a client that reads again
    gets that latest POSE next (after its owed SOURCE lines) and stays connected: for
    stalls of half a second to a minute, backlogs of 30 to 3000 windows, 1 to 20 clients."""
    h = harness(queue_lines=8, idle_timeout_s=1.0)
    clients = [Peer(h.server.path) for _ in range(n_clients)]
    for c in clients:
        c.read()
    stall = {"at": None}

    def backlog() -> None:
        # The daemon was stopped: its clock jumps, then the windows close at once.
        h.server.tick(time.monotonic() + stall_s)
        h.server.broadcast(encode({"class": "SOURCE", "name": "m"}))
        for k in range(windows):
            h.server.broadcast_pose(k * 0.02, encode({"class": "POSE", "k": k, "p": "x" * 300}),
                                    0.0)  # fmt: skip
        stall["at"] = h.server.running

    h.call(backlog)
    assert stall["at"] is not None and h.server.dropped == 0
    for c in clients:
        seen = []
        while True:
            m = c.read()
            seen.append(m)
            if m.get("k") == windows - 1:
                break
        assert any(m["class"] == "SOURCE" for m in seen)  # what it was owed
        assert len(seen) < 200  # what the kernel held, then the latest: not the backlog
    assert len(h.server.clients) == n_clients and h.server.dropped == 0


def test_client_rate_decimates_poses(harness):
    h = harness()
    p = Peer(h.server.path)
    p.read()
    p.send(b'{"cmd": "rate", "hz": 10}\n')
    assert p.read()["cmd"] == "rate"
    for k in range(100):  # 1 s of poses at 100 Hz
        t = k * 0.01
        h.call(lambda t=t: h.server.broadcast_pose(t, encode({"class": "POSE", "t": t}), 0.005))
    h.call(lambda: h.server.broadcast(encode({"class": "END"})))
    ts = []
    while (m := p.read())["class"] == "POSE":
        ts.append(m["t"])
    assert len(ts) == 10
    assert ts == pytest.approx([k / 10 for k in range(10)])
    p.send(b'{"cmd": "rate", "hz": 0}\n')
    assert p.read()["cmd"] == "rate"
    h.call(lambda: h.server.broadcast_pose(5.0, encode({"class": "POSE"}), 0.005))
    h.call(lambda: h.server.broadcast(encode({"class": "END"})))
    assert p.read()["class"] == "END"  # paused: no POSE in between


def test_default_socket_path():
    assert default_socket_path({"RUNTIME_DIRECTORY": "/run/mousedom"}, 1000) == (
        "/run/mousedom/mousedom.sock"
    )
    assert default_socket_path({}, 0) == "/run/mousedom/mousedom.sock"
    assert default_socket_path({"XDG_RUNTIME_DIR": "/run/user/1000"}, 1000) == (
        "/run/user/1000/mousedom/mousedom.sock"
    )
    assert (
        default_socket_path({"TMPDIR": "/var/tmp"}, 1000) == "/var/tmp/mousedom-1000/mousedom.sock"
    )


@pytest.mark.skipif(os.getuid() != 0, reason="needs root to make a directory for another uid")
def test_socket_directory_of_another_user_is_refused(tmp_path):
    d = tmp_path / "theirs"
    d.mkdir()
    os.chown(d, NOBODY, NOBODY)
    s = Server(str(d / "m.sock"), ServerConfig(), selectors.DefaultSelector(), None, None)
    with pytest.raises(UserError, match="belongs to uid 65534"):
        s.open()
    assert not (d / "m.sock").exists()


def test_a_client_rate_keeps_its_phase_and_restarts_after_falling_behind():
    """rate 10 Hz on a 50 Hz POSE stream: every fifth pose at a steady phase; after a
    pause (rate 0, then 10 again, or a gap in poses) the phase restarts at the next pose
    instead of sending a burst to catch up (issue 17, item 7)."""
    import socket as _socket

    from mousedom.config import ServerConfig
    from mousedom.service.server import Client

    a, b = _socket.socketpair(_socket.AF_UNIX, _socket.SOCK_STREAM)
    try:
        c = Client(a, ServerConfig(), control=False)
        c.set_rate(10.0)
        times = [round(0.02 * k, 6) for k in range(1, 26)]
        sent = [t for t in times if c.wants_pose(t, 0.01)]
        assert sent == pytest.approx([0.02, 0.12, 0.22, 0.32, 0.42])
        # the poses stop for 3 s (a stalled fusion, a paused rate): no catch-up burst
        later = [round(3.5 + 0.02 * k, 6) for k in range(0, 11)]
        resent = [t for t in later if c.wants_pose(t, 0.01)]
        assert resent == pytest.approx([3.5, 3.6, 3.7])
        c.set_rate(0)
        assert not any(c.wants_pose(4.0 + 0.02 * k, 0.01) for k in range(10))
        c.set_rate(10.0)
        assert c.wants_pose(5.0, 0.01) and not c.wants_pose(5.02, 0.01)
    finally:
        a.close()
        b.close()


def test_lines_that_carry_nothing_use_up_an_allowance(harness):
    """Blank lines get no reply, so no queue ever filled and a flood of them was never
    dropped; now they (and bad lines) draw on an allowance that refills slowly."""
    from mousedom.service.server import JUNK_BURST

    h = harness()
    flooder, fine = Peer(h.server.path), Peer(h.server.path)
    flooder.read(), fine.read()
    flooder.send(b"\n" * (JUNK_BURST - 8))
    fine.send(b"\n" * 4 + b'{"cmd": "status"}\n')
    assert fine.read()["cmd"] == "status"
    time.sleep(0.2)
    assert h.server.dropped == 0  # a burst is allowed
    try:
        flooder.send(b"\n" * 64)
    except OSError:
        pass
    deadline = time.monotonic() + 3
    while h.server.dropped == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert h.server.dropped == 1 and len(h.server.clients) == 1
    fine.send(b'{"cmd": "status"}\n')
    assert fine.read()["cmd"] == "status"


def test_refused_reset_lines_use_up_the_allowance_and_are_logged_once(harness, caplog):
    """A client without control that floods reset lines: each was answered with an ERROR
    and logged, and the client never dropped (24,550 in 5 s).  Refused, they carry
    nothing: they draw on the allowance, and the journal hears of the first only."""
    import logging

    from mousedom.service.server import JUNK_BURST

    h = harness()
    h.server.may_control = lambda uid, gid: False  # (as a uid not listed: see above)
    flooder = Peer(h.server.path)
    assert flooder.read()["control"] is False
    caplog.set_level(logging.WARNING, logger="mousedom")
    flooder.send(b'{"cmd": "reset"}\n' * 4)
    for _ in range(4):
        assert "not allowed" in flooder.read()["message"]
    try:
        flooder.send(b'{"cmd": "reset", "id": 1}\n' * (2 * JUNK_BURST))
    except OSError:
        pass
    deadline = time.monotonic() + 3
    while h.server.dropped == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert h.server.dropped == 1 and not h.server.clients
    assert [c[1] for c in h.commands] == []  # none reached the daemon
    denied = [r for r in caplog.records if "may not reset" in r.getMessage()]
    assert len(denied) == 1


def test_every_id_is_repeated_and_none_where_none_was_given(harness):
    """Every id the protocol takes comes back as it was sent; null is no id (its answers
    carry none, as docs/protocol.md says); an integer past 2**63 is refused saying so."""
    h = harness(control_uids=(os.getuid(),))
    p = Peer(h.server.path)
    p.read()
    for ident in (0, -7, 2**63 - 1, 1.5, "a", True, False):
        p.send(json.dumps({"cmd": "status", "id": ident}).encode() + b"\n")
        answer = p.read()
        assert "id" in answer and answer["id"] == ident and type(answer["id"]) is type(ident)
        p.send(json.dumps({"cmd": "nosuch", "id": ident}).encode() + b"\n")
        error = p.read()
        assert error["class"] == "ERROR" and error["id"] == ident and "id" in error
    p.send(b'{"cmd": "status"}\n{"cmd": "nosuch"}\n{"cmd": "status", "id": null}\n')
    assert "id" not in p.read() and "id" not in p.read() and "id" not in p.read()
    p.send(b'{"cmd": "status", "id": 18446744073709551616}\n')
    refused = p.read()
    assert "id" not in refused and "integer below 2**63" in refused["message"]


def test_one_client_gets_a_bounded_turn_per_wake(harness):
    """A client's lines beyond LINES_PER_TURN wait for the next wake (backlog); all are
    answered in order in the end."""
    from mousedom.service.server import LINES_PER_TURN

    h = harness(control_uids=(os.getuid(),))
    p = Peer(h.server.path)
    p.read()
    n = LINES_PER_TURN * 5
    p.send(b"".join(b'{"cmd": "status", "id": %d}\n' % k for k in range(n)))
    assert [p.read()["id"] for _ in range(n)] == list(range(n))


def test_a_reply_never_comes_before_the_pose_made_before_it(harness):
    """A lagging client with a POSE waiting, then a reply: the pose (made first) goes first.
    Otherwise a reset's OK would be followed by the pose from before the reset."""
    h = harness(control_uids=(os.getuid(),))
    p = Peer(h.server.path)
    p.read()
    p.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    for k in range(400):  # fill the kernel buffers: the latest pose then waits
        line = encode({"class": "POSE", "k": k, "pad": "x" * 300})
        h.call(lambda line=line: h.server.broadcast_pose(0.0, line, 0.0))
    h.call(lambda: h.server.broadcast_state("SOURCE m", encode({"class": "SOURCE", "n": 1})))
    (client,) = h.server.clients.values()
    assert client.pose is not None  # it waits, to be replaced
    p.send(b'{"cmd": "reset", "id": "r"}\n')
    time.sleep(0.3)
    order = []
    while True:
        m = p.read()
        order.append(m.get("k", m["class"]))
        if m["class"] == "OK":
            break
    assert order[-3:] == ["SOURCE", 399, "OK"], order[-5:]


def test_a_dropped_clients_late_event_cannot_touch_the_client_that_reuses_its_fd(harness):
    """Identity, not descriptor: a client dropped earlier in a wake (idle) frees its fd; a
    client accepted later in the same wake may get it; the first one's pending event must
    not drop or write to the second."""
    h = harness()
    a = Peer(h.server.path)
    a.read()
    (first,) = h.server.clients.values()
    handler = h.server._make_handler(first)
    h.call(lambda: h.server.drop(first, "test"))
    b = Peer(h.server.path)
    b.read()
    (second,) = h.server.clients.values()
    h.call(lambda: handler(selectors.EVENT_READ | selectors.EVENT_WRITE))
    assert h.server.clients.get(second.fd) is second
    h.call(lambda: h.server.broadcast_pose(0.0, encode({"class": "POSE", "k": 1}), 0.0))
    assert b.read() == {"class": "POSE", "k": 1}
    a.close()


def test_a_line_that_breaks_the_daemon_late_in_a_backlog_drops_only_its_client(tmp_path):
    """Lines past the first turn are answered from the backlog, with the same guard as a
    read: whatever a line raises, only its client goes."""
    sel = selectors.DefaultSelector()

    def on_command(client, cmd):
        if cmd.id == 20:
            raise RuntimeError("boom")
        return [ok_message(cmd.name, cmd.id)]

    server = Server(str(tmp_path / "m.sock"), ServerConfig(), sel, on_command,
                    lambda c: [{"class": "VERSION"}])  # fmt: skip
    server.open()
    bad, good = Peer(server.path), Peer(server.path)
    for _ in range(5):
        for key, mask in sel.select(0.05):
            key.data(mask)
    bad.read(), good.read()
    bad.send(b"".join(b'{"cmd": "status", "id": %d}\n' % k for k in range(30)))
    for _ in range(20):
        for key, mask in sel.select(0.05):
            key.data(mask)
        server.serve_backlog()
    assert len(server.clients) == 1
    good.send(b'{"cmd": "status", "id": 1}\n')
    for _ in range(5):
        for key, mask in sel.select(0.05):
            key.data(mask)
    assert good.read() == {"class": "OK", "cmd": "status", "id": 1}
    server.close()


def test_sending_does_not_excuse_not_reading(harness):
    """A client that never reads but sends a byte now and then is dropped once its output
    has waited idle_timeout_s: what it sends does not count as taking what it is sent."""
    h = harness(idle_timeout_s=0.6)
    p = Peer(h.server.path)
    p.read()
    p.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    deadline = time.monotonic() + 5
    while h.server.dropped == 0 and time.monotonic() < deadline:
        h.call(lambda: h.server.broadcast_pose(0.0, encode({"class": "POSE", "p": "x" * 500}),
                                               0.0))  # fmt: skip
        try:
            p.send(b"a")  # a line that never ends: no junk, no reply
        except OSError:
            break
        time.sleep(0.02)
    assert h.server.dropped == 1


@pytest.mark.skipif(os.getuid() != 0, reason="needs root to connect as another uid")
@pytest.mark.parametrize("mode, says", [
    (0o660, "join its group 'root' (sudo usermod -aG root $USER"),
    (0o600, "its mode lets no group in: set server.mode"),
])  # fmt: skip
def test_watch_on_a_socket_it_may_not_use_names_the_mode_and_group(harness, mode, says):
    """Issue 29: `watch` as a user the socket's mode keeps out said "Permission denied (is
    the daemon running?)" while it ran; now it names the mode, the group and what to do."""
    shared = tempfile.mkdtemp(prefix="mousedom-test-")  # tmp_path's parents are 0700
    os.chmod(shared, 0o755)
    h = harness(os.path.join(shared, "m.sock"), mode=mode)
    env = dict(os.environ, PYTHONPATH=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    out = subprocess.run(
        [sys.executable, "-c",
         # everything imported first: the interpreter's own files may be closed to nobody
         "import os, sys, grp, pwd, stat, locale, gettext, importlib, pkgutil, mousedom\n"
         "for m in pkgutil.walk_packages(mousedom.__path__, 'mousedom.'):\n"
         "    if not m.name.endswith('__main__'): importlib.import_module(m.name)\n"
         "from mousedom.cli import main\n"
         f"os.setgid({NOBODY}); os.setuid({NOBODY}); sys.argv[0] = 'mousedom'\n"
         "sys.exit(main())",
         "watch", "--count", "1", "--socket", h.server.path],
        capture_output=True, text=True, timeout=20, env=env,
    )  # fmt: skip
    assert out.returncode != 0, out
    assert f"permission denied: the socket is mode {mode:04o}, owner root, group root" in out.stderr
    assert says in out.stderr and "Traceback" not in out.stderr, out.stderr
    h.close()


def test_a_client_that_shuts_its_sending_side_keeps_reading(harness):
    """`echo status | nc -U SOCKET` shuts its side after the line and reads on: it gets
    its reply and the POSEs after it (a client is dropped only for not reading); the
    server stops watching its input (EOF stays readable: no busy loop).  A paused client
    (rate 0) that shuts its side goes at once: nothing more would reach it.  Closed later,
    it goes within a tick's check though nothing is sent to it (an idle daemon would
    otherwise leave it its slot for good); a client that closes outright goes at its EOF
    (test_client_limit)."""
    h = harness()
    p = Peer(h.server.path)
    p.read()
    p.send(b'{"cmd": "status", "id": 1}\n')
    p.sock.shutdown(socket.SHUT_WR)
    assert p.read() == {"class": "OK", "cmd": "status", "id": 1}
    deadline = time.monotonic() + 3
    while h.server.clients and any(c.reading for c in h.server.clients.values()):
        assert time.monotonic() < deadline, "the server never saw the EOF"
        time.sleep(0.01)
    (client,) = h.server.clients.values()
    assert client.sock not in h.sel.get_map()  # nothing to watch: input ended, all sent
    for k in range(5):
        h.call(lambda k=k: h.server.broadcast_pose(k, encode({"class": "POSE", "t": k}), 0.0))
    assert [p.read()["t"] for _ in range(5)] == [0, 1, 2, 3, 4]
    p.close()  # found within a tick's check (0.1 s), with nothing sent to it
    deadline = time.monotonic() + 3
    while h.server.clients:
        assert time.monotonic() < deadline, "a half-closed client kept its slot once closed"
        time.sleep(0.01)

    q = Peer(h.server.path)
    q.read()
    q.send(b'{"cmd": "rate", "hz": 0}\n')
    assert q.read()["cmd"] == "rate"
    q.sock.shutdown(socket.SHUT_WR)
    assert q.file.readline() == b""  # closed by the server
    assert not h.server.clients


def test_a_listener_with_a_full_backlog_is_live_not_stale(tmp_path):
    """A busy or stopped daemon's backlog fills: the probe's connect would wait (a second
    daemon hung at its start) or fail with EAGAIN, which is a live listener, not a stale
    file: the second daemon refuses, and the socket file stays."""
    from mousedom.service.socketfile import refuse_if_taken, remove_stale

    path = tmp_path / "m.sock"
    with stopped_listener(str(path)):
        for probe in (refuse_if_taken, remove_stale):
            t = time.monotonic()
            with pytest.raises(UserError, match="another mousedom daemon is listening"):
                probe(str(path))
            assert time.monotonic() - t < 1.0
        assert path.is_socket()


@pytest.mark.skipif(os.getuid() != 0, reason="needs root to probe as another uid")
def test_a_socket_the_probe_may_not_connect_to_is_not_taken_for_stale():
    """A daemon whose socket mode denies this user (server.mode "0060", the same user):
    the probe's EACCES was taken for a stale socket, which was unlinked, and the second
    daemon started while the first ran on, unreachable.  Only a refused connection is
    stale; this says it cannot tell and leaves the file."""
    shared = tempfile.mkdtemp(prefix="mousedom-test-")  # tmp_path's parents are 0700
    os.chmod(shared, 0o755)
    path = os.path.join(shared, "m.sock")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(4)
    os.chmod(path, 0o600)  # root's only
    script = (
        "import os\n"
        "from mousedom.errors import UserError\n"
        "from mousedom.service.socketfile import remove_stale\n"
        f"os.setgid({NOBODY}); os.setuid({NOBODY})\n"
        "try:\n    remove_stale(os.environ['SOCK'])\nexcept UserError as e:\n    print(e)\n"
    )
    try:
        out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                             timeout=30, env={**mousedom_env(), "SOCK": path})  # fmt: skip
        assert "cannot tell whether a daemon listens there (Permission denied)" in out.stdout, (
            out.stdout + out.stderr
        )
        assert os.path.exists(path)
    finally:
        listener.close()
        os.unlink(path)
        os.rmdir(shared)


def _read_all(
    sock: socket.socket, want: int, seconds: float, pace: float = 0.0
) -> tuple[int, bool]:
    """Read OK lines until ``want`` of them or EOF (or ``seconds``): (OKs, closed)."""
    sock.settimeout(seconds)
    got, buf, end = 0, b"", time.monotonic() + seconds
    while got < want and time.monotonic() < end:
        try:
            data = sock.recv(4096)
        except TimeoutError:
            break
        if not data:
            return got, True
        buf += data
        *lines, buf = buf.split(b"\n")
        got += sum(1 for line in lines if b'"class": "OK"' in line or b'"class":"OK"' in line)
        if pace:
            time.sleep(pace)
    return got, False


@pytest.mark.parametrize("n", [300, 1000, 3000])
def test_a_client_that_sends_thousands_of_commands_and_reads_slowly_is_answered(harness, n):
    """Back-pressure: the server stops answering a client whose owed queue is half full
    (its socket is not read meanwhile, so its sends block) rather than drop it as "not
    reading" when the answers overflow, as it did to a client that read flat out but had
    sent thousands of commands in one write."""
    h = harness(queue_lines=64)
    p = Peer(h.server.path)
    p.read()
    writer = threading.Thread(target=p.sock.sendall, args=(b'{"cmd": "status"}\n' * n,))
    writer.start()
    got, closed = _read_all(p.sock, n, 30.0, pace=0.001)
    writer.join(10)
    assert (got, closed) == (n, False)
    assert h.server.dropped == 0
    p.close()


@pytest.mark.parametrize("n", [1, 17, 2000])
def test_a_half_closed_client_at_rate_zero_gets_every_answer_it_is_owed(harness, n):
    """``printf '{"cmd":"rate","hz":0}\\n' + N status | nc -U``: the client shuts its sending
    side and reads.  At rate 0 it was dropped at its EOF, and the replies not yet sent were
    lost (12 of 100); now it goes once they are out."""
    h = harness()
    p = Peer(h.server.path)
    p.read()
    p.send(b'{"cmd": "rate", "hz": 0}\n' + b'{"cmd": "status"}\n' * n)
    p.sock.shutdown(socket.SHUT_WR)
    got, closed = _read_all(p.sock, n + 2, 10.0)  # (+ the rate's OK; then its EOF)
    assert (got, closed) == (n + 1, True)
    p.close()


@pytest.mark.parametrize("paused", [True, False])
@pytest.mark.parametrize("n", [0, 1, 40])
def test_a_last_command_without_its_newline_is_answered_at_eof(harness, n, paused):
    """``printf '{"cmd":"status"}' | nc -U``: the last command has no newline, and the
    client shuts its sending side and reads.  It was dropped unanswered; EOF ends it as
    a newline would (after ``n`` complete ones, at rate 0 or not)."""
    h = harness()
    p = Peer(h.server.path)
    p.read()
    head = b'{"cmd": "rate", "hz": 0}\n' if paused else b""
    p.send(head + b'{"cmd": "status"}\n' * n + b'{"cmd": "status"}')
    p.sock.shutdown(socket.SHUT_WR)
    want = n + 1 + paused
    got, closed = _read_all(p.sock, want + 1, 3.0 if paused else 1.0)
    assert got == want
    assert closed == paused  # (at rate 0 it goes once its answers are out; else it stays)
    p.close()


def test_a_line_cut_by_eof_past_max_line_is_one_error():
    """A last line longer than ``max_line`` without its newline is TooLong once, as any."""
    from mousedom.service.protocol import LineBuffer, TooLong

    rx = LineBuffer(8)
    assert rx.feed(b"ab\ncdefghijklmn") == [b"ab"]
    last = rx.finish()
    assert len(last) == 1 and isinstance(last[0], TooLong) and last[0].size == 12
    assert rx.finish() == []
    assert rx.feed(b"xy\r") == [] and rx.finish() == [b"xy"]


def test_the_answers_of_a_turn_stop_when_the_wakes_budget_is_spent(harness):
    """Client work per wake is bounded (docs/protocol.md, 4 ms): the budget is looked at
    before each line, and what is left waits in the backlog, in turn.  It was looked at
    only between clients, after the backlog: sixteen clients of sixteen status lines took
    up to 34 ms of one wake."""
    h = harness()
    peers = [Peer(h.server.path) for _ in range(3)]
    for p in peers:
        p.read()
    answered = []

    def turn(lines: int) -> None:
        """One wake's serve_backlog with a budget of ``lines`` answers."""
        before = len(h.commands)
        h.server.over_budget = lambda: len(h.commands) - before >= lines
        try:
            h.server.serve_backlog()
        finally:
            h.server.over_budget = lambda: True
        answered.append(len(h.commands) - before)

    # lines wait in the backlog: let the server read them with no budget at all
    h.call(lambda: setattr(h.server, "over_budget", lambda: True))
    for p in peers:
        p.send(b'{"cmd": "status"}\n' * 10)
    deadline = time.monotonic() + 5
    while sum(len(c.lines) for c in list(h.server.clients.values())) < 30:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    for _ in range(4):
        h.call(lambda: turn(4))
    counts: list[int] = []
    h.call(lambda: counts.extend(10 - len(c.lines) for c in h.server.clients.values()))
    h.call(lambda: setattr(h.server, "over_budget", lambda: False))
    assert answered == [4, 4, 4, 4]
    # in turn: each wake's budget went to the next client (the first again at the 4th)
    assert sorted(counts) == [4, 4, 8], counts
    for p in peers:
        p.close()


def test_a_folder_anyone_may_write_without_the_sticky_bit_is_refused(tmp_path):
    """Owned by root (or us) but mode 0777: anyone could remove the socket and put their
    own in its place, which the owner check was there to prevent.  /tmp's 1777 is fine."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    server = Server(str(shared / "m.sock"), ServerConfig(), selectors.DefaultSelector(),
                    lambda c, m: [], lambda c: [])  # fmt: skip
    with pytest.raises(UserError, match="anyone may write there .mode 0777, no sticky bit"):
        server.open()
    shared.chmod(0o1777)
    server.open()
    assert (shared / "m.sock").is_socket()
    server.close()
