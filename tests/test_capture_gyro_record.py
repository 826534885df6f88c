"""Issue 30 item 4: recording a gyro.  ``run --record`` keeps the samples the daemon fused
(a daemon in-process with a pipe-backed fake gyro); ``mousedom record`` of a rig with a
FIFO mouse and a fake IIO gyro (tests/iio_fakes.py) records both, and replays."""

from __future__ import annotations

import math
import os
import threading
import time

import numpy as np
from conftest import run_mousedom
from test_daemon import PipeSource

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
    """A gyro whose (t, rate) float64 records come through a pipe."""

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
        n = len(data) // 16
        self._rest = data[16 * n :]
        rec = np.frombuffer(data[: 16 * n], dtype="<f8").reshape(-1, 2)
        return [GyroSamples("gyro", rec[:, 0].copy(), rec[:, 1].copy())]

    def _read(self, now: float):
        raise TypeError("a gyro")

    def write(self, t, rate) -> None:
        os.write(self.w, np.column_stack([t, rate]).astype("<f8").tobytes())


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
    try:
        while d.recording is None or not os.path.exists(d.server.path):
            time.sleep(0.01)
        gyro.write(t, rate)
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
    # and it replays with its gyro
    proc = run_mousedom("replay", "-c", str(rig), "--capture", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "gyro         40 samples, 200.0 Hz" in proc.stdout
