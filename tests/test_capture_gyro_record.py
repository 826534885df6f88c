"""Issue 30 item 4: recording a gyro.  ``run --record`` keeps the samples the daemon fused
(a daemon in-process with a pipe-backed fake gyro); ``mousedom record`` of a rig with a
FIFO mouse and a fake IIO gyro (tests/iio_fakes.py) records both, and replays."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
from conftest import mousedom_env, run_mousedom
from iio_fakes import MPU6050_SCALE, Writer, add_gyro, attr, gyro_records, stamps_ns
from test_daemon import PipeSource
from test_evdev_fakes import motion_bytes

from mousedom.capture import open_capture
from mousedom.config import GyroConfig, load_config
from mousedom.service.daemon import Daemon
from mousedom.sources.base import Source, SourceGone
from mousedom.sources.iio import GyroSamples

RIG = """\
rate_hz: 50
model: lsq
mice:
  a: {evdev: {path: /dev/null}, cpi: 1000, mount: {x: 0.1, y: 0}}
  b: {evdev: {path: /dev/null}, cpi: 1000, mount: {x: -0.1, y: 0}}
gyro: {name: fakegyro, axis: z, sign: -1, sample_hz: 200}
"""


class PipeGyro(Source):
    """A gyro whose (t, rate, saturated) float64 records come through a pipe."""

    kind = "iio"

    def __init__(self) -> None:
        super().__init__("gyro")
        self.r, self.w = os.pipe()
        os.set_blocking(self.r, False)
        self._rest = b""

    def _open(self) -> None:
        pass

    def fileno(self) -> int:
        return self.r

    def read(self, now: float) -> list[GyroSamples]:  # type: ignore[override]
        try:
            data = os.read(self.r, 65536)
        except BlockingIOError:
            return []
        if not data:
            raise SourceGone("gyro: end of stream")
        data = self._rest + data
        n = len(data) // 24
        self._rest = data[24 * n :]
        rec = np.frombuffer(data[: 24 * n], dtype="<f8").reshape(-1, 3)
        sat = rec[:, 2] != 0
        return [GyroSamples("gyro", rec[:, 0].copy(), rec[:, 1].copy(),
                            sat if sat.any() else None)]  # fmt: skip

    def _read(self, now: float):
        raise TypeError("a gyro")

    def write(self, t, rate, saturated) -> None:
        os.write(self.w, np.column_stack([t, rate, saturated]).astype("<f8").tobytes())


def test_run_record_keeps_the_gyro_samples_that_were_fused(tmp_path):
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG)
    mice = {n: PipeSource(n) for n in "ab"}
    gyro = PipeGyro()

    def factory(sensor, clock):
        return gyro if isinstance(sensor, GyroConfig) else mice[sensor.name]

    out = tmp_path / "run.mdcap"
    d = Daemon(load_config(rig), str(tmp_path / "d.sock"), source_factory=factory,
               handle_signals=False, record=str(out))  # fmt: skip
    th = threading.Thread(target=d.run)
    th.start()
    now = time.monotonic()
    t = now + 0.005 * np.arange(40)
    rate = np.linspace(-0.3, 0.7, 40) + math.pi / 1e3  # bits a rounding would lose
    sat = np.zeros(40, bool)
    sat[[3, 4, 30]] = True  # read at the converter's limit
    try:
        started = time.monotonic() + 30  # (a daemon that fails to start: no hang)
        while (d.recording is None or not os.path.exists(d.server.path)) and (
            th.is_alive() and time.monotonic() < started
        ):
            time.sleep(0.01)
        assert d.recording is not None and os.path.exists(d.server.path)
        gyro.write(t, rate, sat)
        mice["a"].write([now + 0.01], [5.0], [-7.0])
        deadline = time.monotonic() + 5
        while d.recording.samples_kept < 40 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        d.request_stop()
        th.join(5)
    cap = open_capture(str(out))
    assert [dev.kind for dev in cap.devices] == ["evdev", "evdev", "iio"]
    dev = cap.devices[2]
    assert (dev.name, dev.rel_xy, dev.mouse) == ("fakegyro", False, None)
    assert dev.extra == {"source": "iio", "axis": "z", "sign": -1, "sample_hz": 200.0}
    got = [r for feed in cap.feeds() for b in feed.batches for r in b.gyro]
    got_t = np.concatenate([r.t for r in got])
    got_rate = np.concatenate([r.rate for r in got])
    assert got_t.tobytes() == t.tobytes() and got_rate.tobytes() == rate.tobytes()
    got_sat = [np.zeros(len(r.t), bool) if r.saturated is None else r.saturated for r in got]
    assert np.concatenate(got_sat).tolist() == sat.tolist()
    # and it replays with its gyro
    proc = run_mousedom("replay", "-c", str(rig), "--capture", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "gyro         40 samples, 200.0 Hz" in proc.stdout
    assert "3 saturated (left out)" in proc.stdout


def _open_writer(node, deadline: float) -> Writer:
    """The kernel's side of the fake /dev/iio:device0, once record has opened it."""
    while True:
        try:
            return Writer(node)
        except OSError:  # ENXIO: no reader yet
            assert time.monotonic() < deadline, "record never opened the gyro"
            time.sleep(0.02)


def test_record_a_rig_with_a_fake_iio_gyro_then_replay_it(tmp_path):
    root = tmp_path / "machine"
    sysdir = add_gyro(root)
    mouse = tmp_path / "left.fifo"
    os.mkfifo(mouse)
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "rate_hz: 100\nmodel: diff-drive\nmice:\n"
        f"  left: {{cpi: 800, mount: {{x: 0.1, y: 0.0, yaw: 0}}, evdev: {{path: {mouse}}}}}\n"
        "gyro: {name: mpu6050, axis: z, sign: -1, sample_hz: 200}\n"
    )
    out = tmp_path / "run.mdcap"
    p = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "record", "--root", str(root), "--config", str(cfg),
         "-o", str(out), "--status-interval", "0.2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=mousedom_env(),
    )  # fmt: skip
    try:
        m = os.open(mouse, os.O_WRONLY)  # waits for the reader
        g = _open_writer(root / "dev" / "iio:device0", time.monotonic() + 20)
        t0 = time.monotonic() - 1.6  # all 1.5 s of samples stamped before now (none re-stamped)
        raw = np.arange(-150, 150, dtype=np.int64) * 7
        raw[[10, 11, 200]] = [32767, 32767, -32768]  # the converter's limits: saturated
        ns = stamps_ns(t0, len(raw), hz=200.0)
        g.write(gyro_records(raw[:100].tolist(), ns[:100].tolist()))
        os.write(m, motion_bytes(t0, np.full(50, 3), np.zeros(50, int), dt=0.004))
        g.write(gyro_records(raw[100:].tolist(), ns[100:].tolist()))
        time.sleep(0.8)
        p.send_signal(signal.SIGINT)
        err = p.communicate(timeout=20)[1]
        g.close()
        os.close(m)
    finally:
        p.kill()
    assert p.returncode == 0, err
    assert "Traceback" not in err
    assert "gyro (iio " in err and "gyro 300 samples" in err
    assert attr(sysdir, "buffer/enable") == "0"  # the device left as found
    cap = open_capture(str(out))
    assert [d.kind for d in cap.devices] == ["evdev", "iio"]
    dev = cap.devices[1]
    assert dev.name == "mpu6050" and dev.extra["axis"] == "z" and dev.extra["sign"] == -1
    assert dev.extra["scale"] == float(MPU6050_SCALE) and dev.extra["mode"] == "buffered"
    assert dev.extra["node"] == str(root / "dev" / "iio:device0")
    got = [r for feed in cap.feeds() for b in feed.batches for r in b.gyro]
    t = np.concatenate([r.t for r in got])
    rate = np.concatenate([r.rate for r in got])
    # what the source gives: sign * raw * scale, stamped by the records' nanoseconds
    np.testing.assert_array_equal(rate, -1 * (raw.astype(np.float64) + 0.0) * float(MPU6050_SCALE))
    np.testing.assert_array_equal(t, ns.astype(np.float64) / 1e9)
    sat = np.concatenate([np.zeros(len(r.t), bool) if r.saturated is None else r.saturated
                          for r in got])  # fmt: skip
    assert np.flatnonzero(sat).tolist() == [10, 11, 200] and cap.stats[1].saturated == 3
    assert cap.stats[0].reports == 50
    proc = run_mousedom("replay", "-c", str(cfg), "--capture", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "gyro         300 samples, 200.0 Hz" in proc.stdout
    assert "3 saturated (left out)" in proc.stdout
    # convert keeps the marks
    conv = tmp_path / "conv.mdcap"
    proc = run_mousedom("convert", "--capture", str(out), "-o", str(conv))
    assert proc.returncode == 0, proc.stderr
    again = [r for feed in open_capture(str(conv)).feeds() for b in feed.batches for r in b.gyro]
    sat2 = np.concatenate([np.zeros(len(r.t), bool) if r.saturated is None else r.saturated
                           for r in again])  # fmt: skip
    assert sat2.tolist() == sat.tolist()
