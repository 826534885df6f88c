"""sd_notify datagrams, received on a real AF_UNIX datagram socket."""

from __future__ import annotations

import os
import socket

import pytest

from mousedom.service.sdnotify import Notifier, watchdog_interval


@pytest.fixture
def listener(tmp_path):
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2)
    yield path, sock
    sock.close()


def test_ready_and_status_arrive_as_one_datagram(listener):
    path, sock = listener
    n = Notifier({"NOTIFY_SOCKET": path})
    assert n.enabled
    assert n.ready("4 sensors open")
    assert sock.recv(4096) == b"READY=1\nSTATUS=4 sensors open"
    assert n.watchdog()
    assert sock.recv(4096) == b"WATCHDOG=1"
    assert n.status("left: gone\nright: ok")  # a newline would start a new field
    assert sock.recv(4096) == b"STATUS=left: gone right: ok"
    assert n.sent == 3
    n.close()


def test_abstract_socket_name():
    name = f"mousedom-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(b"\0" + name.encode())
    sock.settimeout(2)
    try:
        n = Notifier({"NOTIFY_SOCKET": "@" + name})
        assert n.stopping()
        assert sock.recv(4096) == b"STOPPING=1"
    finally:
        sock.close()


def test_without_notify_socket_nothing_is_sent():
    n = Notifier({})
    assert not n.enabled
    assert not n.ready()
    assert n.sent == 0


def test_missing_listener_is_logged_not_raised(tmp_path, caplog):
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody")})
    assert not n.watchdog()
    assert "sd_notify" in caplog.text


def test_watchdog_interval_is_half_of_watchdog_usec():
    assert watchdog_interval({"WATCHDOG_USEC": "10000000"}) == 5.0
    assert watchdog_interval({"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": str(os.getpid())}) == 2.0
    assert watchdog_interval({"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "1"}) is None
    assert watchdog_interval({}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "x"}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "0"}) is None


def test_a_full_receiver_never_blocks_the_sender(listener):
    """The receiver's queue holds a few datagrams; the daemon must not wait for systemd."""
    import time

    path, sock = listener
    n = Notifier({"NOTIFY_SOCKET": path})
    t = time.monotonic()
    results = [n.watchdog() for _ in range(500)]  # nobody reads meanwhile
    assert time.monotonic() - t < 1.0
    assert results[0] and not results[-1]
    assert sock.recv(4096) == b"WATCHDOG=1"


@pytest.mark.parametrize("status", ["x" * 39_000, "é" * 3000, "ok " * 1365, "y" * 4088])
def test_a_long_status_is_cut_so_that_systemd_takes_the_datagram(listener, status):
    """systemd ignores a notify datagram over 4096 bytes (PIPE_BUF): a reload's READY=1
    sent with a STATUS naming 200 bad keys (39 kB) was lost, and systemd waited on."""
    path, sock = listener
    n = Notifier({"NOTIFY_SOCKET": path})
    assert n.notify(READY=1, STATUS=status)
    got = sock.recv(65536)
    assert len(got) <= 4096 and got.startswith(b"READY=1\nSTATUS=")
    text = got.decode()  # whole characters
    sent = text.removeprefix("READY=1\nSTATUS=")
    whole = len(f"READY=1\nSTATUS={status}".encode()) <= 4096
    assert sent == status if whole else (sent.endswith("...") and status.startswith(sent[:-3]))
    n.close()
