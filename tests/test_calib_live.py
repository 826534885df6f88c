"""Interactive calibration from live mice: a real process, FIFOs as the evdev nodes
(the evdev source reads a FIFO as a raw input_event stream), Enter on a real stdin pipe."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import mousedom_env, run_mousedom

from mousedom.sources.events import encode_input_events

CPI = 1000
PUSH = 0.1  # metres: 3937 counts at 1000 cpi


def frames(t0: float, counts: list[int]) -> bytes:
    """One REL_Y report per entry, 8 ms apart, each closed by SYN_REPORT."""
    n = len(counts)
    t = np.repeat(t0 + 0.008 * np.arange(n), 2)
    typ = np.tile([2, 0], n)
    code = np.tile([1, 0], n)
    value = np.ravel(np.column_stack([counts, np.zeros(n, int)]))
    return encode_input_events(t, typ, code, value)


class Proc:
    def __init__(self, args, cwd, stdout=subprocess.PIPE, env: dict | None = None):
        self.p = subprocess.Popen(
            [sys.executable, "-m", "mousedom", *args],
            cwd=cwd,
            stdin=subprocess.PIPE,
            stdout=stdout,
            stderr=subprocess.PIPE,
            env={**mousedom_env(), **(env or {})},
        )
        self.err = b""

    def one_run(self, k: int, what: str, writes: dict[int, bytes]) -> None:
        """Run k + 1 (``what``: push, turn): Enter, each FIFO writer's bytes, Enter."""
        self.enter()
        self.wait_for("moving... press Enter to stop", times=k + 1)
        for fd, data in writes.items():
            os.write(fd, data)
        self.enter()
        self.wait_for(f"{what} {k + 1} recorded")

    def wait_for(self, needle: str, times: int = 1, timeout: float = 15.0) -> None:
        """Until ``needle`` has appeared ``times`` times on stderr."""
        end = time.monotonic() + timeout
        fd = self.p.stderr.fileno()
        while self.err.count(needle.encode()) < times:
            left = end - time.monotonic()
            if left <= 0 or self.p.poll() is not None and not select.select([fd], [], [], 0)[0]:
                raise AssertionError(f"no {needle!r} in stderr: {self.err.decode()}")
            if select.select([fd], [], [], min(left, 0.5))[0]:
                chunk = os.read(fd, 4096)
                if not chunk and self.p.poll() is not None:
                    continue
                self.err += chunk

    def enter(self, text: str = "\n") -> None:
        self.p.stdin.write(text.encode())
        self.p.stdin.flush()

    def end(self, writers: dict[str, int] | None = None) -> None:
        """Teardown: close the mice's FIFO writers, kill the process if it is still up."""
        for fd in (writers or {}).values():
            os.close(fd)
        if self.p.poll() is None:
            self.p.kill()


@pytest.fixture
def rig(tmp_path):
    fifos = {}
    for name in ("left", "right"):
        fifos[name] = tmp_path / f"{name}.fifo"
        os.mkfifo(fifos[name])
    (tmp_path / "rig.yaml").write_text(
        "calibration: rig.calib.yaml\nmice:\n"
        f"  left: {{cpi: 800, mount: {{x: 0, y: 0.1}}, evdev: {{path: {fifos['left']}}}}}\n"
        f"  right: {{cpi: 800, mount: {{x: 0, y: -0.1}}, evdev: {{path: {fifos['right']}}}}}\n"
    )
    return tmp_path, fifos


def test_live_cpi_runs_with_enter_and_counts_on_fifos(rig):
    tmp, fifos = rig
    proc = Proc(
        [
            "calibrate",
            "cpi",
            "--config",
            "rig.yaml",
            "--distance",
            str(PUSH),
            "--runs",
            "3",
            "--json",
            "--write",
        ],
        tmp,
    )
    writers = {}
    try:
        proc.wait_for("push 1: press Enter to start")
        writers = {n: os.open(f, os.O_WRONLY) for n, f in fifos.items()}
        os.write(writers["left"], frames(10.0, [-5] * 3))  # before the run: shown, not used
        expected = {"left": [], "right": []}
        for k in range(3):
            proc.enter()
            proc.wait_for("moving... press Enter to stop", times=k + 1)
            sign = -1 if k % 2 == 0 else 1
            total = {"left": 3937 + 20 * k, "right": 3937}
            for name, n in total.items():
                parts = [sign * 100] * (n // 100) + [sign * (n % 100)]
                os.write(writers[name], frames(20.0 + 5 * k, parts))
                expected[name].append(n)
            proc.enter()
            proc.wait_for(f"push {k + 1} recorded")
        out, err = proc.p.communicate(timeout=30)
        err = proc.err + err
        assert proc.p.returncode == 0, err.decode()
    finally:
        proc.end(writers)
    doc = json.loads(out)
    inches = PUSH / 0.0254
    for name, counts in expected.items():
        assert doc[name]["runs"] == 3
        assert doc[name]["cpi"] == pytest.approx(np.mean(counts) / inches, rel=1e-6)
    assert "15 counts arrived between runs and were not used" in err.decode()
    assert (tmp / "rig.calib.yaml").exists()


def test_live_quit_early_is_too_few_runs(rig):
    tmp, fifos = rig
    proc = Proc(["calibrate", "cpi", "--config", "rig.yaml", "--distance", "0.1"], tmp)
    try:
        proc.wait_for("push 1: press Enter")
        proc.enter("q\n")
        out, err = proc.p.communicate(timeout=30)
    finally:
        proc.end()
    assert proc.p.returncode == 2
    assert b"found 0 run(s), need at least 2" in proc.err + err
    assert b"Traceback" not in proc.err + err


def test_live_needs_evdev_mice(tmp_path):
    (tmp_path / "rig.yaml").write_text(
        "mice:\n  a: {cpi: 800, mount: {x: 0.1}, serial: {port: /dev/ttyUSB9}}\n"
        "  b: {cpi: 800, mount: {x: -0.1}, serial: {port: /dev/ttyUSB8}}\n"
    )
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "mousedom",
            "calibrate",
            "cpi",
            "--config",
            "rig.yaml",
            "--distance",
            "0.1",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=mousedom_env(),
        stdin=subprocess.DEVNULL,
        timeout=60,
    )
    assert p.returncode == 2 and "live calibration reads evdev mice" in p.stderr


def test_live_mouse_unplugged_mid_run_is_a_clear_error(rig):
    tmp, fifos = rig
    proc = Proc(["calibrate", "cpi", "--config", "rig.yaml", "--distance", "0.1"], tmp)
    writers = {}
    try:
        proc.wait_for("push 1: press Enter")
        writers = {n: os.open(f, os.O_WRONLY) for n, f in fifos.items()}
        proc.enter()
        proc.wait_for("moving... press Enter to stop")
        os.write(writers["left"], frames(1.0, [-100] * 5))
        os.close(writers.pop("left"))  # the writer going away is the unplug
        out, err = proc.p.communicate(timeout=30)
    finally:
        proc.end(writers)
    text = (proc.err + err).decode()
    assert proc.p.returncode == 2, text
    assert "mouse left went away" in text and "Traceback" not in text


def test_live_distance_turns(rig):
    """Two turns of 90 degrees by hand: left mouse backwards, right forwards (CCW)."""
    tmp, fifos = rig
    proc = Proc(
        ["calibrate", "distance", "--config", "rig.yaml", "--angle", "90", "--runs", "2", "--json"],
        tmp,
    )
    writers = {}
    counts = 4947  # 0.1 m * pi/2 at 800 cpi
    try:
        proc.wait_for("turn 1: press Enter to start")
        writers = {n: os.open(f, os.O_WRONLY) for n, f in fifos.items()}
        for k in range(2):
            sign = 1 if k == 0 else -1
            proc.one_run(k, "turn", {
                writers[name]: frames(30.0 + 5 * k, [s * 100] * (counts // 100)
                                      + [s * (counts % 100)])
                for name, s in (("left", sign), ("right", -sign))
            })  # fmt: skip
        out, err = proc.p.communicate(timeout=30)
        assert proc.p.returncode == 0, (proc.err + err).decode()
    finally:
        proc.end(writers)
    doc = json.loads(out)
    assert doc["runs"] == 2
    assert doc["distance"] == pytest.approx(2 * counts / 800 * 0.0254 / (np.pi / 2), abs=1e-6)


def test_live_mouse_not_found_is_named_once(tmp_path):
    """Regression: the message read 'mouse a: a: no input device matches ...'."""
    (tmp_path / "rig.yaml").write_text(
        "mice:\n  a: {cpi: 800, mount: {x: 0.1}, evdev: {name: 'no such mouse 7f3a'}}\n"
        "  b: {cpi: 800, mount: {x: -0.1}, evdev: {name: 'no such mouse 7f3b'}}\n"
    )
    p = run_mousedom(
        "calibrate", "cpi", "--config", str(tmp_path / "rig.yaml"), "--distance", "0.1",
        input="",
    )  # fmt: skip
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert "mousedom: error: mouse a: no input device matches name=" in p.stderr, p.stderr


@pytest.mark.parametrize("stdin", ["devnull", "file", "closed"])
def test_live_with_no_keyboard_on_stdin_is_one_line(rig, stdin):
    """/dev/null or a regular file as stdin: epoll refuses them (PermissionError, a
    traceback); a closed stdin: an AttributeError.  One line now, exit 2."""
    tmp, _ = rig
    (tmp / "keys.txt").write_text("\n\nq\n")
    cmd = [sys.executable, "-m", "mousedom", "calibrate", "cpi", "--config", "rig.yaml",
           "--distance", "0.1"]  # fmt: skip
    kw: dict = {"stdin": subprocess.DEVNULL}
    if stdin == "file":
        kw["stdin"] = open(tmp / "keys.txt", "rb")  # noqa: SIM115 (closed below)
    elif stdin == "closed":
        cmd = ["bash", "-c", " ".join(f"'{a}'" for a in cmd) + " <&-"]
    try:
        p = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, env=mousedom_env(),
                           timeout=60, **kw)  # fmt: skip
    finally:
        if stdin == "file":
            kw["stdin"].close()
    assert p.returncode == 2, p.stderr
    assert "live calibration reads Enter presses on stdin" in p.stderr, p.stderr
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1


def test_live_write_goes_on_when_stdout_s_reader_is_gone(rig):
    """`calibrate cpi --write | true`: the report's print raised BrokenPipeError, the CLI
    took it for a reader that had enough (exit 0) and the calibration was never written.
    It is written now, and the lost report is said on stderr."""
    tmp, fifos = rig
    r, w = os.pipe()
    os.close(r)  # stdout's reader: gone before a line is written
    p = Proc(["calibrate", "cpi", "--config", "rig.yaml", "--distance", str(PUSH), "--runs",
              "2", "--write"], tmp, stdout=w, env={"PYTHONUNBUFFERED": "1"})  # fmt: skip
    os.close(w)
    writers = {}
    try:
        p.wait_for("push 1: press Enter to start")
        writers = {n: os.open(f, os.O_WRONLY) for n, f in fifos.items()}
        for k in range(2):
            push = frames(20.0 + 5 * k, [(-1) ** k * 100] * 39 + [37])
            p.one_run(k, "push", {fd: push for fd in writers.values()})
        _, err = p.p.communicate(timeout=30)
    finally:
        p.end(writers)
    text = (p.err + err).decode()
    assert p.p.returncode == 0, text
    assert "the report was not shown" in text and "Traceback" not in text
    assert (tmp / "rig.calib.yaml").exists()


def test_live_ctrl_c_is_one_line_and_writes_nothing(rig):
    """Ctrl-C mid-run ended with exit 130 and no word at all; now one line."""
    import signal

    tmp, fifos = rig
    proc = Proc(["calibrate", "cpi", "--config", "rig.yaml", "--distance", "0.1", "--write"],
                tmp)  # fmt: skip
    writers = {}
    try:
        proc.wait_for("push 1: press Enter")
        writers = {n: os.open(f, os.O_WRONLY) for n, f in fifos.items()}
        proc.enter()
        proc.wait_for("moving... press Enter to stop")
        proc.p.send_signal(signal.SIGINT)
        _, err = proc.p.communicate(timeout=30)
    finally:
        proc.end(writers)
    text = (proc.err + err).decode()
    assert proc.p.returncode == 130, text
    assert text.rstrip().endswith("mousedom: interrupted") and "Traceback" not in text
    assert not (tmp / "rig.calib.yaml").exists()
