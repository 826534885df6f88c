"""A capture's gyro as the daemon's gyro (``gyro: replay:``): the samples come back as
recorded, paced on the clock with the mice of the same file, and the real daemon fuses them
(issue 30, item 4: captures replay their IIO samples everywhere a user looks)."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import run_mousedom
from test_capture_gyro_replay import (
    GYRO_DEVICE,
    assert_same_poses,
    replay,
    simulated,
    write_capture,
)

from mousedom.capture import CaptureError, DeviceInfo, NativeWriter, assign
from mousedom.capture.replay import Replay
from mousedom.capture.source import GyroReplaySource, ReplaySource
from mousedom.config import ConfigError, parse_config
from mousedom.fusion import sim
from mousedom.fusion.posebatch import PoseBatch
from mousedom.service.factory import make_source
from mousedom.sources.iio import GyroSamples


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _config_text(path: Path, gyro: str) -> str:
    """The simulated rig's mice (test_capture_gyro_replay.simulated), replayed from ``path``."""
    rig, _ = simulated()
    mice = "".join(
        f"  {m.name}: {{cpi: {m.cpi_x}, mount: {{x: {m.x!r}, y: {m.y!r}}}, "
        f"report_hz: {m.report_hz}, replay: {path}}}\n"
        for m in rig.mice
    )
    return f"mice:\n{mice}gyro: {gyro}\n"


def test_the_config_takes_a_capture_for_the_gyro(tmp_path):
    cfg = parse_config(_config_text(Path("run.mdcap"), "{replay: run.mdcap}"),
                       str(tmp_path / "c.yaml"))  # fmt: skip
    assert cfg.gyro is not None and cfg.gyro.replay == str(tmp_path / "run.mdcap")
    assert cfg.gyro.replay_device is None and cfg.gyro.name is None
    cfg = parse_config(
        _config_text(Path("run.mdcap"), "{replay: {file: /data/x.mdcap, device: mpu6050}}"),
        str(tmp_path / "c.yaml"),
    )
    assert cfg.gyro is not None
    assert (cfg.gyro.replay, cfg.gyro.replay_device) == ("/data/x.mdcap", "mpu6050")
    with pytest.raises(ConfigError, match=r"c\.yaml:\d+.*replay.*one source: name"):
        parse_config(_config_text(Path("x"), "{name: mpu6050, replay: x.mdcap}"),
                     str(tmp_path / "c.yaml"))  # fmt: skip
    with pytest.raises(ConfigError, match=r"c\.yaml:\d+: gyro\.sign: does not apply to a replayed"):
        parse_config(_config_text(Path("x"), "{replay: x.mdcap, sign: -1}"),
                     str(tmp_path / "c.yaml"))  # fmt: skip
    with pytest.raises(ConfigError, match=r"gyro.*needs name.*replay.*or ros2"):
        parse_config(_config_text(Path("x"), "{axis: z}"), str(tmp_path / "c.yaml"))


def test_the_samples_come_back_as_recorded_on_the_clock_and_loop_with_the_mice(tmp_path):
    rig, res = simulated()
    path = tmp_path / "g.mdcap"
    write_capture(path, rig, res, step=0.25, chunk=500)
    cfg = parse_config(_config_text(path, "{replay: g.mdcap}"), str(tmp_path / "c.yaml"))
    clock = Clock()
    gyro = make_source(cfg.gyro, clock, loop=True)
    mouse = make_source(cfg.mice[0], clock, loop=True)
    assert isinstance(gyro, GyroReplaySource) and isinstance(mouse, ReplaySource)
    gyro.open()
    clock.now += 0.2  # the mouse opens later, on the same anchor
    mouse.open()
    assert gyro.fileno() == -1 and gyro.paced
    first = float(res.motion.starts[0])
    span = max(float(res.gyro.t[-1]), max(float(r.t[-1]) for r in res.reports.values())) - first
    # the first pass, read in uneven steps: every sample once, restamped, the rate exact
    got_t, got_rate, steps = [], [], 0
    while clock.now < 100.0 + span:
        clock.now += 0.037 + 0.011 * (steps % 3)
        steps += 1
        for b in gyro.read(clock.now):
            assert isinstance(b, GyroSamples) and b.gyro == "gyro"
            got_t.append(b.t)
            got_rate.append(b.rate)
    t, rate = np.concatenate(got_t), np.concatenate(got_rate)
    n = len(res.gyro.t)
    np.testing.assert_array_equal(rate[:n], res.gyro.rate)
    np.testing.assert_allclose(t[:n], 100.0 + (res.gyro.t - first), rtol=0, atol=1e-9)
    assert np.all(np.diff(t) >= 0) and gyro.health.reports == len(t)
    # the second pass: both shifted by the same time (the file's span and one period)
    clock.now = 100.0 + 2 * span + 1.0
    g2 = np.concatenate([t[n:], *(b.t for b in gyro.read(clock.now))])  # (the first steps
    m_all = np.concatenate([b.t for b in mouse.read(clock.now)])  # overshot into it)
    m = res.reports["front"].t
    shift_gyro = g2[0] - (100.0 + res.gyro.t[0] - first)
    shift_mouse = m_all[len(m)] - (100.0 + m[0] - first)
    assert shift_gyro == pytest.approx(shift_mouse, abs=1e-9)
    assert span < shift_gyro < span + 0.01


def _one_mouse(capture: Path, gyro: str, tmp_path: Path):
    text = f"mice:\n  a: {{cpi: 800, mount: {{x: 0, y: 0}}, replay: {capture}}}\ngyro: {gyro}\n"
    return parse_config(text, str(tmp_path / "c.yaml"), need_model=False)


def test_the_gyro_is_picked_by_name_or_node_and_a_file_without_one_says_so(tmp_path):
    p = tmp_path / "two.mdcap"
    other = DeviceInfo(name="bmi160", kind="iio", rel_xy=False, extra={"node": "/dev/iio:device1"})
    devs = [DeviceInfo(name="m", mouse="a", rel_xy=True), GYRO_DEVICE, other]
    with NativeWriter(p, devs, time_base="monotonic") as w:
        w.motion(0, [1.0, 2.0], [1, 1], [0, 0])
        w.gyro(1, [1.0, 1.5], [0.5, 0.25])
        w.gyro(2, [1.2], [-1.0])
    clock = Clock()
    for cfg_gyro, want in (("{replay: {file: two.mdcap, device: mpu6050}}", [0.5, 0.25]),
                           ("{replay: {file: two.mdcap, device: /dev/iio:device1}}", [-1.0]),
                           ("{name: bmi160, replay: two.mdcap}", None)):  # fmt: skip
        text = f"mice:\n  a: {{cpi: 800, mount: {{x: 0, y: 0}}, replay: {p}}}\ngyro: {cfg_gyro}\n"
        if want is None:
            with pytest.raises(ConfigError, match="one source"):
                parse_config(text, str(tmp_path / "c.yaml"), need_model=False)
            continue
        cfg = parse_config(text, str(tmp_path / "c.yaml"), need_model=False)
        src = GyroReplaySource(cfg.gyro, clock=clock, loop=False)
        src.open()
        assert np.concatenate([b.rate for b in src.read(1e6)]).tolist() == want
        # `mousedom replay` of the same config takes the same gyro
        r = Replay(cfg, assign(cfg, []))
        assert r.gyro is not None and r.gyro.device == src._dev
    cfg = _one_mouse(p, "{replay: two.mdcap}", tmp_path)
    with pytest.raises(CaptureError, match=r"two\.mdcap: cannot tell which device is the gyro"):
        GyroReplaySource(cfg.gyro, clock=clock).open()
    alone = tmp_path / "mice.mdcap"
    with NativeWriter(alone, devs[:1], time_base="monotonic") as w:
        w.motion(0, [1.0], [1], [0])
    cfg = _one_mouse(p, "{replay: mice.mdcap}", tmp_path)
    with pytest.raises(CaptureError, match=r"mice\.mdcap: gyro\.replay: the capture holds no gyro"):
        GyroReplaySource(cfg.gyro, clock=clock).open()


def test_the_daemon_fuses_a_replayed_gyro(tmp_path):
    """``mousedom run`` on mice and gyro replayed from one capture: POSE carries the gyro's
    bias, SOURCE a gyro that reports, and the heading follows the recorded turn."""
    from daemon_fixtures import Conn, DaemonProcess

    rig, res = simulated()
    path = tmp_path / "g.mdcap"
    write_capture(path, rig, res, step=0.25, chunk=500)
    config = tmp_path / "c.yaml"
    config.write_text(_config_text(path, "{replay: g.mdcap}"))
    sock = tmp_path / "run" / "d.sock"
    sock.parent.mkdir()
    daemon = DaemonProcess(config, sock)
    try:
        daemon.wait_socket()
        c = Conn(sock)
        assert c.until("VERSION")["sensors"] == ["front", "left", "right"]
        source = c.until("SOURCE", lambda m: m["name"] == "gyro" and m["reports"] > 0)
        assert source["kind"] == "replay" and source["connected"]
        # read until the drive's quarter turn is under way: where the replay is in its
        # first pass when the client connects depends on the machine's load, so the wait is
        # bounded by the file's whole span rather than a fixed slice of it
        span = float(res.gyro.t[-1] - res.motion.starts[0])
        deadline = time.monotonic() + span + 3.0
        poses: list[dict] = []
        turned = 0.0
        while time.monotonic() < deadline and (turned <= 0.1 or len(poses) < 60):
            poses.append(c.until("POSE"))
            turned = max(turned, abs(poses[-1]["theta"]))
        with_gyro = [p for p in poses if "gyro" in p]
        assert len(with_gyro) > 0.9 * len(poses) > 50
        assert all(math.isfinite(p["gyro"]["bias"]) for p in with_gyro)
        assert turned > 0.1, (span, len(poses), poses[-1])
    finally:
        assert daemon.stop() == 0, daemon.log()


def test_a_capture_of_the_gyro_alone_replays_with_the_mice_of_another(tmp_path):
    """The gyro recorded to a file of its own (given as --capture FILE, or as the config's
    gyro.replay) replays with the mice's file as the one file holding both does."""
    rig, res = simulated()
    both = tmp_path / "both.mdcap"
    write_capture(both, rig, res)
    mice = tmp_path / "mice.mdcap"
    write_capture(mice, rig, res, gyro=False)
    alone = tmp_path / "gyro.mdcap"
    first = float(res.motion.starts[0])
    with NativeWriter(alone, [GYRO_DEVICE], time_base="monotonic",
                      meta={"first_time": first}) as w:  # fmt: skip
        w.gyro(0, res.gyro.t, res.gyro.rate)
    cfg = sim.rig_config(rig)
    want, _, _ = replay(cfg, both)
    for specs, config in (
        ([(None, str(mice)), (None, str(alone))], cfg),
        ([(None, str(mice))], dataclasses.replace(
            cfg, gyro=dataclasses.replace(cfg.gyro, replay=str(alone)))),
    ):  # fmt: skip
        r = Replay(config, assign(config, specs))
        assert r.gyro is not None and r.gyro.capture.path == str(alone)
        got: list[PoseBatch] = []
        r.run(got.append)
        assert_same_poses(PoseBatch.concat(got, len(cfg.mice)), want, exact=False)


def test_replay_will_not_write_over_the_gyros_capture(tmp_path):
    """-o naming the capture that holds the gyro alone is refused, as for the mice's."""
    rig, res = simulated()
    mice, alone = tmp_path / "mice.mdcap", tmp_path / "gyro.mdcap"
    write_capture(mice, rig, res, gyro=False)
    with NativeWriter(alone, [GYRO_DEVICE], time_base="monotonic") as w:
        w.gyro(0, res.gyro.t, res.gyro.rate)
    config = tmp_path / "c.yaml"
    config.write_text(_config_text(mice, "{use: both}"))
    before = alone.read_bytes()
    proc = run_mousedom("replay", "--config", str(config), "--capture", str(mice),
                        "--capture", str(alone), "-o", str(alone))  # fmt: skip
    assert proc.returncode != 0 and "gyro.mdcap" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
    assert alone.read_bytes() == before
