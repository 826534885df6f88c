"""Helpers for the daemon's end-to-end tests: FIFO mice, a real-time feeder, the process.

Mice are FIFOs that the evdev source reads as raw ``struct input_event`` streams (its test
hook); the feeder writes simulated reports into them at their real times, stamped on
CLOCK_MONOTONIC as the kernel would.  The daemon runs as a real process on a real socket.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from test_evdev_fakes import report_bytes

from mousedom.fusion import sim

REPO = Path(__file__).resolve().parent.parent
RATE = 50.0


class FifoMouse:
    """A named pipe standing in for one mouse's /dev/input/eventN."""

    def __init__(self, path: Path) -> None:
        self.path = path
        os.mkfifo(path)
        self.fd: int | None = None

    def attach(self, timeout: float = 10.0) -> None:
        """Open the writing end once the daemon has opened the reading end."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK)
                break
            except OSError:  # ENXIO: no reader yet
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.02)
        os.set_blocking(fd, True)
        self.fd = fd

    def write(self, data: bytes) -> None:
        if self.fd is not None:
            try:
                os.write(self.fd, data)
            except BrokenPipeError:  # the daemon is gone (stopped by the test)
                self.unplug()

    def unplug(self, remove: bool = False) -> None:
        """Close the writing end (the reader sees end of file, as on ENODEV); ``remove``
        also deletes the FIFO, as the kernel deletes an unplugged mouse's node."""
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
        if remove:
            os.unlink(self.path)

    def replug(self) -> None:
        if not self.path.exists():
            os.mkfifo(self.path)
        self.attach()


class Feeder(threading.Thread):
    """Writes each mouse's reports into its FIFO when their (monotonic) time comes."""

    def __init__(
        self, mice: dict[str, FifoMouse], reports: dict, t0: float, step: float = 0.002
    ) -> None:
        super().__init__(daemon=True)
        self.mice, self.reports, self.t0, self.step = mice, reports, t0, step
        self.stopped = threading.Event()
        self.lock = threading.Lock()  # held while writing, so a test can unplug safely
        self.sent = {name: 0 for name in mice}

    def run(self) -> None:
        cursor = {name: 0 for name in self.mice}
        while not self.stopped.is_set():
            now = time.monotonic()
            done = True
            with self.lock:
                for name, mouse in self.mice.items():
                    rep = self.reports[name]
                    times = rep.t + self.t0
                    i = cursor[name]
                    j = int(np.searchsorted(times, now, side="right"))
                    if j < len(times):
                        done = False
                    if j > i:
                        if mouse.fd is not None:
                            mouse.write(report_bytes(times[i:j], rep.dx[i:j], rep.dy[i:j]))
                            self.sent[name] += j - i
                        cursor[name] = j
            if done:
                return
            time.sleep(self.step)

    def stop(self) -> None:
        self.stopped.set()
        self.join(5)


def write_rig_config(
    path: Path, rig, fifos: dict[str, Path], extra: str = "", rate_hz: float | None = None
) -> Path:
    from mousedom.fusion.sim import rig_yaml

    text = rig_yaml(rig)
    if rate_hz is not None:
        text = text.replace(f"rate_hz: {rig.rate_hz!r}", f"rate_hz: {rate_hz!r}", 1)
    lines = []
    for line in text.splitlines():
        lines.append(line)
        stripped = line.strip()
        if line.startswith("  ") and not line.startswith("    ") and stripped.endswith(":"):
            name = stripped[:-1]
            lines.append(f"    evdev: {{path: {fifos[name]}, grab: false}}")
    path.write_text("\n".join(lines) + "\n" + extra)
    return path


def wait_listening(path: Path, proc=None, timeout: float = 15.0, log=lambda: "") -> None:
    """Wait until a daemon accepts connections at ``path``: the socket file exists a moment
    before ``listen`` (bind, then owner and mode, then listen), so its existence alone is
    not readiness.  ``proc``: the daemon's process, whose exit ends the wait."""
    deadline = time.monotonic() + timeout
    while True:
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"daemon exited {proc.returncode}: {log()}")
        if path.exists():
            probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                probe.connect(str(path))
                return
            except OSError:
                pass
            finally:
                probe.close()
        if time.monotonic() > deadline:
            raise AssertionError(f"no listening socket at {path} after {timeout}s: {log()}")
        time.sleep(0.02)


class DaemonProcess:
    """``mousedom run`` as a real child process."""

    def __init__(
        self,
        config: Path,
        socket_path: Path,
        *args: str,
        env=None,
        config_args: bool = True,
        preexec=None,
        cwd: Path | None = None,
        log: Path | None = None,
    ) -> None:
        """``log``: where its stderr goes (default: beside the socket's directory, named
        after the socket)."""
        environ = dict(os.environ)
        environ["PYTHONPATH"] = str(REPO) + os.pathsep + environ.get("PYTHONPATH", "")
        environ.update(env or {})
        self.socket_path = socket_path
        self.stderr_path = log or socket_path.parent.parent / f"{socket_path.stem}.log"
        self._log = open(self.stderr_path, "w")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mousedom", "run"]
            + (["--config", str(config)] if config_args else [])
            + ["--socket", str(socket_path), *args],
            stdout=subprocess.DEVNULL,
            stderr=self._log,
            env=environ,
            preexec_fn=preexec,
            cwd=cwd,
        )

    def wait_socket(self, timeout: float = 15.0) -> None:
        wait_listening(self.socket_path, self.proc, timeout, self.log)

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.stderr_path.read_text()

    def signal(self, sig: int) -> None:
        self.proc.send_signal(sig)

    def stop(self, timeout: float = 5.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode


class Conn:
    """A protocol client on a real socket, reading line by line with a timeout."""

    def __init__(self, path: Path, timeout: float = 5.0) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(str(path))
        self.sock.settimeout(timeout)
        self.file = self.sock.makefile("rb")

    def read(self) -> dict:
        line = self.file.readline()
        if not line:
            raise EOFError("daemon closed the connection")
        return json.loads(line)

    def send(self, obj) -> None:
        data = obj if isinstance(obj, bytes) else (json.dumps(obj) + "\n").encode()
        self.sock.sendall(data)

    def until(self, cls: str, pred=lambda m: True, limit: int = 10000) -> dict:
        for _ in range(limit):
            m = self.read()
            if m["class"] == cls and pred(m):
                return m
        raise AssertionError(f"no {cls} in {limit} messages")

    def poses(self, seconds: float) -> list[dict]:
        out = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            m = self.read()
            if m["class"] == "POSE":
                out.append(m)
        return out

    def close(self) -> None:
        self.file.close()
        self.sock.close()


def rig_runner(tmp_path):
    """Generator behind the ``rig_run`` fixtures: yields ``start(trajectory, ...)`` that
    runs a daemon on a three-mouse FIFO rig driving ``trajectory``; stops all at the end."""
    started = []

    def start(
        trajectory, extra: str = "", rate_hz: float = RATE, env=None, args=(), preexec=None,
        rig=None, faulty=None,
    ):  # fmt: skip
        """``faulty``: the rig the mice really are (faults put on it); the config is
        written from ``rig`` (the healthy one the robot believes in)."""
        rig = rig or sim.three_mouse_rig()
        fifos = {m.name: tmp_path / f"{m.name}.fifo" for m in rig.mice}
        mice = {n: FifoMouse(p) for n, p in fifos.items()}
        config = write_rig_config(tmp_path / "rig.yaml", rig, fifos, extra, rate_hz=rate_hz)
        daemon = DaemonProcess(
            config, tmp_path / "run" / "mousedom.sock", *args, env=env, preexec=preexec
        )
        daemon.wait_socket()
        for m in mice.values():
            m.attach()
        result = sim.simulate(faulty or rig, trajectory, seed=3)
        feeder = Feeder(mice, result.reports, time.monotonic() + 0.1)
        feeder.start()
        ctx = type("Run", (), {})()
        ctx.rig, ctx.fifos, ctx.mice, ctx.config = rig, fifos, mice, config
        ctx.daemon, ctx.feeder, ctx.result, ctx.fifo_paths = daemon, feeder, result, fifos
        started.append(ctx)
        return ctx

    yield start
    for ctx in started:
        ctx.feeder.stop()
        ctx.daemon.stop()


@contextlib.contextmanager
def stopped_listener(path: str) -> Iterator[None]:
    """A Unix socket at ``path`` whose listener never accepts and whose backlog is full:
    what a daemon stopped by SIGSTOP (or hung) looks like to a client or a probe."""
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(0)
    held = []
    try:
        while True:
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.setblocking(False)
            try:
                s.connect(path)
            except BlockingIOError:
                s.close()
                break
            held.append(s)
        yield
    finally:
        for s in held:
            s.close()
        listener.close()
