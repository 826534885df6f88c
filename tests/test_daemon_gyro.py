"""The daemon with a gyro read by the real IIO source (issue 30): a fake sysfs tree laid out
as the kernel publishes an MPU-6050 and a FIFO standing for /dev/iio:device0, fed records
in real time with three mice; POSE and SOURCE say the gyro; ``run --record`` keeps its
samples, and replaying the recording ends where the daemon ended (daemon = replay, to a few
milliradians: the replay's window grid starts at the first report, the daemon's when it
started, and a turn's windows split differently)."""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import run_mousedom
from daemon_fixtures import Conn, wait_listening
from iio_fakes import MPU6050_SCALE, Writer, add_gyro, gyro_records
from test_daemon import PipeSource

from mousedom.config import GyroConfig, load_config
from mousedom.fusion import sim, simgyro
from mousedom.service.daemon import Daemon
from mousedom.sources.iio import GyroSource
from mousedom.sources.iio_sysfs import IioPaths

SCALE = float(MPU6050_SCALE)


def _config_text(rig: sim.Rig) -> str:
    """The rig's config, each mouse given a device (the test's factory stands in for
    it) and the gyro its IIO name."""
    text = sim.rig_yaml(rig).replace("    flip: false\n",
                                     "    flip: false\n    evdev: {path: /dev/null}\n")  # fmt: skip
    return text.replace("gyro:\n", "gyro:\n  name: mpu6050\n")


def _feed(result: sim.SimResult, base: float, mice: dict, node) -> dict[str, int]:
    """Write every report and gyro sample at its time (stamps offset by ``base``), as the
    kernel hands them over; the counts of each mouse written."""
    items = [(float(t) + base, name, (dx, dy)) for name, r in result.reports.items()
             for t, dx, dy in zip(r.t, r.dx, r.dy, strict=True)]  # fmt: skip
    g = result.gyro
    assert g is not None
    raw = np.round(g.rate / SCALE).astype(int)
    items += [(float(t) + base, "", (int(v), 0)) for t, v in zip(g.t, raw, strict=True)]
    items.sort(key=lambda item: item[0])
    writer = Writer(node)
    try:
        for t, name, (a, b) in items:
            delay = t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if name:
                mice[name].write([t], [a], [b])
            else:
                writer.write(gyro_records([a], [round(t * 1e9)]))
    finally:
        time.sleep(0.3)  # the last windows close before the writer goes (an unplug)
        writer.close()
    return {name: len(r.t) for name, r in result.reports.items()}


def _gyro_rig(tmp_path: Path, root: Path, gyro: simgyro.SimGyro):
    """A three-mouse rig with ``gyro``, its config written and loaded, and the factory
    that gives the daemon pipes for the mice and the real IIO source under ``root`` for
    the gyro: (rig, config path, config, factory, the mice's pipes)."""
    rig = dataclasses.replace(sim.three_mouse_rig(cpi=800.0), gyro=gyro)
    config_path = tmp_path / "rig.yaml"
    config_path.write_text(_config_text(rig))
    config = load_config(str(config_path))
    mice = {m.name: PipeSource(m.name) for m in config.mice}

    def factory(sensor, clock):
        if isinstance(sensor, GyroConfig):
            return GyroSource(sensor, IioPaths.under(str(root)), clock=clock)
        return mice[sensor.name]

    return rig, config_path, config, factory, mice


def test_the_daemon_fuses_a_real_iio_gyro_and_replays_to_the_same_pose(tmp_path):
    root = tmp_path / "iio"
    add_gyro(root)
    node = root / "dev" / "iio:device0"
    rig, config_path, config, factory, mice = _gyro_rig(
        tmp_path, root, simgyro.SimGyro(bias=math.radians(0.5))
    )
    record = tmp_path / "run.mdcap"
    d = Daemon(config, str(tmp_path / "d.sock"), source_factory=factory,
               handle_signals=False, record=str(record))  # fmt: skip
    th = threading.Thread(target=d.run)
    th.start()
    traj = sim.sequence(sim.pause(0.6), sim.straight(0.2, 0.25), sim.turn(1.2, 1.5),
                        sim.pause(0.3))  # fmt: skip
    result = sim.simulate(rig, traj, seed=7)
    try:
        deadline = time.monotonic() + 10
        while d.recording is None or not os.path.exists(d.server.path):
            assert time.monotonic() < deadline, "the daemon did not start"
            time.sleep(0.01)
        wait_listening(Path(d.server.path), None, 10)  # (the file is there before listen)
        c = Conn(d.server.path)
        sources = [c.until("SOURCE") for _ in range(4)]
        gyro_source = next(s for s in sources if s["name"] == "gyro")
        assert gyro_source["kind"] == "iio" and gyro_source["mode"] == "buffered"
        feeder = threading.Thread(target=_feed,
                                  args=(result, time.monotonic() + 0.3, mice, node))  # fmt: skip
        feeder.start()
        pose = c.until("POSE")
        assert set(pose["gyro"]) == {"bias", "bias_sigma", "agree", "scale"}
        feeder.join(30)
    finally:
        d.request_stop()
        th.join(10)
    assert not th.is_alive()
    # the gyro's bias was learnt at the start, standing still
    assert d.publisher._last_gyro[1] == pytest.approx(math.radians(0.5), abs=math.radians(0.1))
    final = d.tracker.pose
    truth = result.truth(result.motion.starts[-1])[0]
    assert final[2] == pytest.approx(truth[2], abs=0.02)
    out = tmp_path / "replay.csv"
    p = run_mousedom("replay", "--config", str(config_path), "--capture", str(record),
                     "-o", str(out))  # fmt: skip
    assert p.returncode == 0, p.stderr
    with open(out, newline="") as f:
        rows = [r for r in csv.DictReader(line for line in f if not line.startswith("#"))]
    last = rows[-1]
    assert "gyro_bias" in last
    # (the daemon's reads come as the loop wakes: under load a sample may reach its window
    # late and count in the next, as a mouse's report may)
    assert [float(last[k]) for k in ("x", "y", "theta")] == pytest.approx(final, abs=3e-3)
    assert float(last["theta"]) == pytest.approx(truth[2], abs=0.01)


def test_a_buffered_gyro_unplugged_without_a_word_from_its_poll_is_gone_and_comes_back(
    tmp_path,
):
    """Since Linux 4.x an IIO buffer's poll returns no event once its device is
    unregistered; only a read says ENODEV.  The FIFO's writer stays open here, so that the
    node goes as silent as the kernel's (no data, no hang-up), while the device's sysfs
    folder goes.  The daemon, which read the gyro only when its descriptor was readable,
    kept it live for good and fused its silence as "no turn".  Now it is gone within its
    silence bound (SOURCE says so, POSE names it missing), and once the device is back the
    daemon's retry reattaches it and its samples count again."""
    import shutil

    from mousedom.sources.iio import SILENT_S

    root = tmp_path / "iio"
    sysdir = add_gyro(root)
    node = root / "dev" / "iio:device0"
    _, _, config, factory, _ = _gyro_rig(tmp_path, root, simgyro.SimGyro())
    d = Daemon(config, str(tmp_path / "d.sock"), source_factory=factory, handle_signals=False)
    th = threading.Thread(target=d.run)
    th.start()
    writer: Writer | None = None
    feeding = threading.Event()
    stop = threading.Event()

    def feed() -> None:  # 200 Hz records stamped now, while ``feeding`` is set
        while not stop.is_set():
            if feeding.is_set() and writer is not None:
                try:
                    writer.write(gyro_records([100], [round(time.monotonic() * 1e9)]))
                except BrokenPipeError:  # (no reader between the close and the reopen)
                    pass
            time.sleep(0.005)

    feeder = threading.Thread(target=feed)
    try:
        deadline = time.monotonic() + 10
        while not os.path.exists(d.server.path):
            assert time.monotonic() < deadline, "the daemon did not start"
            time.sleep(0.01)
        wait_listening(Path(d.server.path), None, 10)
        c = Conn(d.server.path)
        writer = Writer(node)  # (the daemon holds the node open for reading by now)
        feeder.start()
        feeding.set()
        c.until("SOURCE", lambda m: m["name"] == "gyro" and m["reports"] > 20)
        # unplugged: the device's folder goes and the node says nothing more
        feeding.clear()
        shutil.rmtree(sysdir)
        gone_at = time.monotonic()
        gone = c.until("SOURCE", lambda m: m["name"] == "gyro" and not m["connected"])
        took = time.monotonic() - gone_at
        assert took < SILENT_S + 2.0, took
        assert "went" in gone["error"], gone
        assert "gyro" in c.until("POSE", lambda m: "gyro" in m["missing"])["missing"]
        # back: the same rule finds it again at the daemon's next retry
        add_gyro(root, node=False)
        feeding.set()
        back = c.until("SOURCE", lambda m: m["name"] == "gyro" and m["connected"]
                       and m["live"] and m["reports"] > 0)  # fmt: skip
        assert back["error"] is None, back
        pose = c.until("POSE", lambda m: "gyro" not in m["missing"])
        assert pose["missing"] == []
    finally:
        stop.set()
        d.request_stop()
        th.join(10)
        if feeder.is_alive():
            feeder.join(5)
        if writer is not None:
            writer.close()
    assert not th.is_alive()
