"""Issue 29 item 1: ``mousedom watch`` fits the terminal (80x24 and up), names its frames,
and shows the heading as replay's summary and the client do."""

from __future__ import annotations

import math
import re
import shlex
import shutil
import subprocess
import sys
import time

import pytest
from conftest import mousedom_env
from daemon_fixtures import rig_runner

from mousedom.commands import _watchview as view
from mousedom.fusion import sim

ESC = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def _pose(theta: float = math.radians(-190.0)) -> dict:
    return {"t": 12.5, "x": -12.3456, "y": 105.5, "theta": theta, "vx": 0.3, "vy": -0.01,
            "omega": 0.5, "cov": [[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]], "used": 3,
            "updating": True, "missing": [], "excluded": ["left"], "suspect": ["right"],
            "consistent": False}  # fmt: skip


def _sources(n: int, warn: bool) -> dict:
    out = {}
    for i in range(n):
        name = f"mouse-number-{i:02d}"
        out[name] = {"name": name, "connected": True, "state": "suspect", "rate_hz": 125.0,
                     "age": 0.004, "residual": 1e-4, "dropped": 3 * i, "squal": 80,
                     "scale": 1.02, "scale_applied": True, "reason": "drifts from the others",
                     "scale_warning": ("mouse reads 2 % more than the others: check its cpi "
                                       * 2) if warn else None}  # fmt: skip
    return out


HEADER = ("mousedom 0.1.0 at /run/user/1000/a/rather/long/runtime/directory/mousedom.sock: "
          "model lsq, 100 Hz, sensors front, left, right")  # fmt: skip
PATH = [(0.01 * k, 0.5 * math.sin(0.05 * k)) for k in range(200)]


@pytest.mark.parametrize("size", [(80, 24), (120, 40), (80, 12)])
@pytest.mark.parametrize("n, warn", [(3, False), (3, True), (8, True)])
def test_the_screen_fits_and_always_shows_position_and_heading(size, n, warn):
    cols, rows = size
    for color in (False, True):
        lines = view.screen(HEADER, _pose(), _sources(n, warn), 0.0, PATH, size, color)
        assert len(lines) <= rows
        plain = [ESC.sub("", line) for line in lines]
        assert max(map(len, plain)) <= cols, [x for x in plain if len(x) > cols]
        pos = [x for x in plain if x.startswith("position (odom)")]
        assert len(pos) == 1 and "heading +170.00 deg" in pos[0], plain  # -190 -> +170
        assert any(
            x.startswith("velocity (body)  forward  +0.300 m/s  left  -0.010") for x in plain
        )
        assert plain[0].startswith("mousedom 0.1.0 at ")
        if color:
            assert all(line.count("\x1b[") % 2 == 0 or line.endswith(view.RESET) for line in lines)


def test_the_sketch_gives_way_first():
    """Room to spare: the sketch is drawn; shorter: it shrinks; shorter still: it goes,
    while every sensor row stays; only then is the table cut, with a line saying so."""
    src = _sources(3, False)
    tall = view.screen(HEADER, _pose(), src, 0.0, PATH, (120, 40), False)
    mid = view.screen(HEADER, _pose(), src, 0.0, PATH, (80, 24), False)
    short = view.screen(HEADER, _pose(), src, 0.0, PATH, (80, 16), False)
    assert "path (o start, @ now)" in tall and "path (o start, @ now)" in mid
    assert sum(x.startswith("|") for x in tall) > sum(x.startswith("|") for x in mid) > 0
    assert "path (o start, @ now)" not in short
    assert sum(x.startswith("mouse-number-") for x in short) == 3
    tiny = view.screen(HEADER, _pose(), _sources(8, True), 0.0, PATH, (80, 14), False)
    assert len(tiny) <= 14 and "a taller terminal shows them" in tiny[-1]
    assert any(x.startswith("position (odom)") for x in tiny)


def test_piped_lines_name_the_frames_and_wrap_the_heading():
    line = view.pose_line(_pose(math.radians(3 * 360 + 45)), 0.0)
    assert "odom x -12.3456 m  y +105.5000 m  heading +45.00 deg" in line
    assert "body forward +0.300 m/s  left -0.010 m/s  turn +28.65 deg/s" in line


def test_one_heading_definition_for_watch_replay_and_client():
    """replay's final pose keeps theta continuous (turns counted) and shows the heading
    through the same function as watch and Pose.heading_deg."""
    from mousedom import angles, client
    from mousedom.commands import replay

    assert replay.wrap_degrees is view.wrap_degrees is client.wrap_degrees is angles.wrap_degrees
    assert angles.wrap_degrees(math.pi) == 180.0 and angles.wrap_degrees(-math.pi) == 180.0
    assert angles.wrap_degrees(math.radians(-190)) == pytest.approx(170.0)


@pytest.fixture
def rig_run(tmp_path):
    yield from rig_runner(tmp_path)


def _tmux_watch(socket_path, size, tmp_path, wait_for: str) -> list[str]:
    """``mousedom watch`` in a real tmux of ``size``; the pane's text once ``wait_for``
    shows (tmux on its own server socket, killed at the end)."""
    cols, rows = size
    env = mousedom_env(TERM="xterm")
    server = ["tmux", "-S", str(tmp_path / f"tmux-{cols}x{rows}"), "-f", "/dev/null"]
    keep = " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items()
                    if k in ("PYTHONPATH", "PATH", "HOME"))  # fmt: skip
    cmd = (f"env {keep} TERM=xterm {shlex.quote(sys.executable)} -m mousedom watch "
           f"--socket {shlex.quote(str(socket_path))} --rate 10")  # fmt: skip
    subprocess.run([*server, "new-session", "-d", "-x", str(cols), "-y", str(rows), cmd],
                   check=True, env=env, timeout=10)  # fmt: skip
    try:
        subprocess.run([*server, "resize-window", "-x", str(cols), "-y", str(rows)],
                       env=env, timeout=10)  # fmt: skip
        deadline = time.monotonic() + 20
        pane: list[str] = []
        while time.monotonic() < deadline:
            time.sleep(0.5)
            got = subprocess.run([*server, "capture-pane", "-p"], capture_output=True,
                                 text=True, env=env, timeout=10)  # fmt: skip
            pane = got.stdout.rstrip("\n").split("\n")
            if any(wait_for in line for line in pane):
                time.sleep(0.5)  # a few more redraws: a scroll would show by now
                got = subprocess.run([*server, "capture-pane", "-p"], capture_output=True,
                                     text=True, env=env, timeout=10)  # fmt: skip
                return got.stdout.rstrip("\n").split("\n")
        raise AssertionError(f"no {wait_for!r} in the pane:\n" + "\n".join(pane))
    finally:
        subprocess.run([*server, "kill-server"], env=env, timeout=10)


@pytest.mark.skipif(shutil.which("tmux") is None, reason="needs tmux")
@pytest.mark.parametrize("size", [(80, 24), (120, 40)])
def test_watch_in_a_real_tmux_keeps_the_header_and_position_on_screen(rig_run, tmp_path, size):
    """The screen as the terminal holds it after many redraws: the header on the first
    row (nothing scrolled off the top), the position and heading shown, the path sketch
    there once the robot moved, no row past the pane."""
    cols, rows = size
    run = rig_run(sim.sequence(sim.straight(0.6, 0.3), sim.turn(math.radians(450), 2.0),
                               sim.pause(30.0)), env={"TERM": "xterm"})  # fmt: skip
    pane = _tmux_watch(run.daemon.socket_path, size, tmp_path, "path (o start, @ now)")
    assert len(pane) <= rows
    assert pane[0].startswith("mousedom "), pane
    pos = [x for x in pane if x.startswith("position (odom)  x ")]
    assert len(pos) == 1 and re.search(r"heading\s+[+-][\d.]+ deg", pos[0]), pane
    assert any(x.startswith("velocity (body)  forward") for x in pane)
    assert sum(x.split()[:1] in (["front"], ["left"], ["right"]) for x in pane) == 3, pane
    assert all(len(x) <= cols for x in pane)
