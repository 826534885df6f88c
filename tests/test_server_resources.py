"""The server at the edge of the process's resources: more clients than it may open
descriptors for.  A real daemon (the demo rig, replayed) in a child process whose open-file
limit is low, clients on real sockets."""

from __future__ import annotations

import os
import resource
import socket
import time
from pathlib import Path

from daemon_fixtures import Conn, DaemonProcess

from mousedom.demo import DEMO_CAPTURE, DEMO_CONFIG

LIMIT = 40  # open files the daemon may hold


def _rig(tmp_path: Path, server: str) -> Path:
    text = DEMO_CONFIG.read_text().replace("replay: demo-rig.mdcap", f"replay: {DEMO_CAPTURE}")
    path = tmp_path / "rig.yaml"
    path.write_text(text + server)
    return path


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (LIMIT, LIMIT))


def test_out_of_descriptors_the_daemon_rests_says_so_once_and_accepts_again(tmp_path):
    """With ``max_clients`` above what the open-file limit allows, accept() fails with
    EMFILE while the listener stays readable: the loop retried at every wake, a full core,
    and logged 65,000 warnings a second.  Now the start says the limit is too low, the
    listener rests (one warning an episode), a healthy client keeps its poses, and once
    clients leave the waiting connections are taken."""
    config = _rig(tmp_path, "server: {max_clients: 100}\n")
    sock = tmp_path / "run" / "d.sock"
    daemon = DaemonProcess(config, sock, preexec=_limit)
    held: list[socket.socket] = []
    try:
        daemon.wait_socket()
        healthy = Conn(sock)
        healthy.until("VERSION")
        fds = Path(f"/proc/{daemon.proc.pid}/fd")
        deadline = time.monotonic() + 5.0
        # connect until the daemon holds all it may (the rest wait in the listen backlog)
        while len(os.listdir(fds)) < LIMIT and time.monotonic() < deadline:
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.setblocking(False)
            try:
                s.connect(str(sock))
            except OSError:  # the listen backlog is full: the daemon takes them in turn
                s.close()
                time.sleep(0.01)
                continue
            held.append(s)
        assert len(os.listdir(fds)) == LIMIT, len(held)
        time.sleep(0.5)
        cpu = _cpu_s(daemon.proc.pid)
        poses = healthy.poses(2.0)
        spent = _cpu_s(daemon.proc.pid) - cpu
        assert len(poses) > 0.75 * 2.0 * 50, len(poses)
        assert spent < 0.5, spent  # (it spun: 2 s of CPU in 2 s)
        log = daemon.log()
        assert "server.max_clients is 100, but this process may open" in log, log
        said = [line for line in log.splitlines() if "cannot accept connections" in line]
        assert len(said) == 1, said[:3]
        assert "Too many open files" in said[0], said
        # clients leave: the ones waiting in the backlog (or new ones) are served
        for s in held[:20]:
            s.close()
        del held[:20]
        late = Conn(sock, timeout=5.0)
        assert late.until("VERSION")["class"] == "VERSION"
        late.close()
        healthy.close()
    finally:
        for s in held:
            s.close()
        assert daemon.stop() == 0, daemon.log()
