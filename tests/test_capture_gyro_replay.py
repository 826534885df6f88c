"""Issue 30 item 4: captures with a gyro replayed.  A simulated rig's mice and gyro written
as a native capture replay to exactly the poses of one batch through the tracker; a gyro
the config lacks is ignored with a warning; a config's gyro that no capture holds is
replayed without it; the CSV's gyro columns and the summary's gyro line; convert."""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import pytest
from conftest import run_mousedom

from mousedom.capture import DeviceInfo, NativeWriter, assign, open_capture
from mousedom.capture.native import GYRO_VERSION
from mousedom.capture.posecsv import csv_columns, gyro_columns
from mousedom.capture.replay import Replay, read_csv
from mousedom.config import parse_config
from mousedom.fusion import sim
from mousedom.fusion.posebatch import PoseBatch
from mousedom.fusion.simgyro import SimGyro

GYRO_DEVICE = DeviceInfo(name="mpu6050", kind="iio", rel_xy=False,
                         extra={"node": "/dev/iio:device0", "axis": "z", "sign": 1})  # fmt: skip
FIELDS = ("t", "x", "y", "theta", "vx", "vy", "omega", "cov", "used", "ok", "counts", "state",
          "reason", "consistent", "gyro")  # fmt: skip


GYRO = SimGyro(bias=math.radians(0.4))


def simulated(seed: int = 4, gyro: SimGyro | None = GYRO):
    rig = dataclasses.replace(sim.three_mouse_rig(cpi=800.0, report_hz=250.0), gyro=gyro)
    traj = sim.sequence(sim.straight(0.4), sim.turn(math.pi / 2), sim.pause(0.5),
                        sim.arc(0.4, math.pi / 3))  # fmt: skip
    return rig, sim.simulate(rig, traj, seed=seed, t_start=1000.0)


def write_capture(path, rig, res, *, gyro: bool = True, step: float = 0.25, chunk=2000,
                  gyro_device: DeviceInfo = GYRO_DEVICE) -> None:  # fmt: skip
    """The simulation as ``mousedom record`` would have written it: every source in time
    slices, a sync point after each; the first time the simulation's start."""
    devices = [DeviceInfo(name=f"usb {m.name}", mouse=m.name, rel_xy=True) for m in rig.mice]
    if gyro:
        devices.append(gyro_device)
    start = float(res.motion.starts[0])
    # the last stamp of any source: a sync point past it would close empty windows after
    # it, which a batch of the same reports does not have
    end = max([float(r.t[-1]) for r in res.reports.values()]
              + ([float(res.gyro.t[-1])] if gyro else []))  # fmt: skip
    with NativeWriter(path, devices, time_base="monotonic", chunk_reports=chunk,
                      meta={"first_time": start}) as w:  # fmt: skip
        k = 0
        while start + k * step <= end:
            lo, hi = start + k * step, start + (k + 1) * step
            for i, m in enumerate(rig.mice):
                r = res.reports[m.name]
                sel = (r.t >= lo) & (r.t < hi)
                w.motion(i, r.t[sel], r.dx[sel].astype(int), r.dy[sel].astype(int))
            if gyro:
                g = res.gyro
                sel = (g.t >= lo) & (g.t < hi)
                w.gyro(len(rig.mice), g.t[sel], g.rate[sel], g.saturated[sel])
            w.sync(min(np.nextafter(hi, -np.inf), end))
            k += 1


def replay(cfg, path) -> tuple[PoseBatch, object, Replay]:
    r = Replay(cfg, assign(cfg, [(None, str(path))]))
    got: list[PoseBatch] = []
    summary = r.run(got.append)
    return PoseBatch.concat(got, len(cfg.mice)), summary, r


def assert_same_poses(a: PoseBatch, b: PoseBatch, exact: bool = True) -> None:
    assert len(a) == len(b)
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if x is None or y is None:
            assert x is None and y is None, name
            continue
        if exact and name == "cov":
            # The replay's end closes the last window on its own (Tracker.finish after
            # the pump), the batch with the others: its covariance may differ in the last
            # bit, with or without a gyro.
            np.testing.assert_array_equal(x[:-1], y[:-1], err_msg=name)
            np.testing.assert_allclose(x[-1], y[-1], rtol=1e-12, atol=0, err_msg=name)
        elif exact:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=name)
        else:
            np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), rtol=1e-9,
                                       atol=1e-12, err_msg=name)  # fmt: skip


@pytest.mark.parametrize(
    ("step", "chunk", "exact"), [(100.0, 1 << 20, True), (0.25, 2000, False), (0.013, 7, False)]
)
def test_replay_of_a_rig_with_a_gyro_is_the_batch_tracker(tmp_path, step, chunk, exact):
    """replay = tracker: a capture read in one piece gives the very poses of one batch of
    everything (sim.run_tracker), bit for bit; streamed in slices, chunks and sync points,
    the same poses but for the last bits of float sums taken in pieces (as the mice alone:
    the engine's streaming adds counts up in another order)."""
    rig, res = simulated()
    path = tmp_path / "g.mdcap"
    write_capture(path, rig, res, step=step, chunk=chunk)
    cfg = sim.rig_config(rig)
    assert cfg.gyro is not None
    got, summary, r = replay(cfg, path)
    want, _ = sim.run_tracker(res, cfg)
    assert got.gyro is not None and np.isfinite(got.gyro[-1]).all()
    assert_same_poses(got, want, exact)
    # the summary's gyro: every sample, and the bias it learnt (true 0.4 deg/s)
    assert summary.gyro is not None and summary.gyro.stats.reports == len(res.gyro.t)
    assert summary.gyro.samples_per_s == pytest.approx(200.0, rel=1e-3)
    assert summary.gyro.bias == pytest.approx(float(want.gyro[-1, 1]), rel=1e-9)
    assert math.degrees(summary.gyro.bias) == pytest.approx(0.4, abs=0.1)
    assert not summary.gyro_dropped and not r.warnings


def test_a_gyro_the_config_lacks_is_ignored_with_a_warning(tmp_path):
    rig, res = simulated()
    path = tmp_path / "g.mdcap"
    write_capture(path, rig, res)
    cfg = sim.rig_config(dataclasses.replace(rig, gyro=None))
    got, summary, r = replay(cfg, path)
    assert got.gyro is None and summary.gyro is None
    assert r.warnings == [
        f"{path}: device 'mpu6050' (/dev/iio:device0) is a gyro and <sim> has no gyro: "
        "section: its samples are ignored (add gyro: to fuse them)"
    ]
    # the mice alone, as a capture without the gyro replays
    plain = tmp_path / "plain.mdcap"
    write_capture(plain, rig, res, gyro=False)
    alone, _, _ = replay(cfg, plain)
    assert_same_poses(got, alone)


def test_a_config_gyro_that_no_capture_holds_is_replayed_without_it(tmp_path):
    """The tracker must not wait for a gyro that never comes: the config runs without its
    gyro, and says so."""
    rig, res = simulated()
    plain = tmp_path / "plain.mdcap"
    write_capture(plain, rig, res, gyro=False)
    cfg = sim.rig_config(rig)
    got, summary, r = replay(cfg, plain)
    assert r.config.gyro is None and summary.gyro_dropped and summary.gyro is None
    assert got.gyro is None
    assert r.warnings == [
        "<sim> has a gyro: section but no capture holds a gyro: replayed without it, "
        "from the mice alone"
    ]
    alone, _, _ = replay(sim.rig_config(dataclasses.replace(rig, gyro=None)), plain)
    assert_same_poses(got, alone)
    assert len(got) == len(alone) > 100


def test_csv_and_summary_of_a_replay_with_a_gyro(tmp_path):
    rig, res = simulated()
    path = tmp_path / "g.mdcap"
    write_capture(path, rig, res)
    cfg_path = tmp_path / "rig.yaml"
    cfg_path.write_text(sim.rig_yaml(rig))
    proc = run_mousedom("replay", "-c", str(cfg_path), "--capture", str(path), "-o", "-")
    assert proc.returncode == 0, proc.stderr
    header = proc.stdout.split("\n", 1)[0].split(",")
    names = tuple(m.name for m in rig.mice)
    assert header == csv_columns(names) + gyro_columns()
    assert header[-4:] == ["gyro_bias", "gyro_bias_sigma", "gyro_agree", "gyro_scale"]
    data = read_csv(proc.stdout)
    cfg = sim.rig_config(rig)
    want, _ = sim.run_tracker(res, cfg)
    np.testing.assert_array_equal(data["theta"], np.round(want.theta, 9))
    for column, k in (("gyro_bias", 1), ("gyro_bias_sigma", 2), ("gyro_agree", 3),
                      ("gyro_scale", 4)):  # fmt: skip
        np.testing.assert_allclose(data[column], want.gyro[:, k], rtol=1e-6, atol=0)
    # the summary's line for the gyro
    proc = run_mousedom("replay", "-c", str(cfg_path), "--capture", str(path))
    assert proc.returncode == 0, proc.stderr
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("gyro "))
    bias, sigma = math.degrees(want.gyro[-1, 1]), math.degrees(want.gyro[-1, 2])
    assert f"{len(res.gyro.t)} samples" in line and "200.0 Hz" in line
    assert f"bias {bias:+.3f} +- {sigma:.3f} deg/s" in line and "mpu6050" in line


def test_summary_escapes_the_control_characters_of_the_gyro_name(tmp_path):
    """The gyro's line printed the capture's device name raw, as the mice's rows did: an
    IIO name holding ESC sent the terminal a sequence (here a title and a cleared screen)."""
    rig, res = simulated()
    path = tmp_path / "g.mdcap"
    hostile = dataclasses.replace(GYRO_DEVICE, name="mpu\x1b]0;pwned\x07\x1b[2J")
    write_capture(path, rig, res, gyro_device=hostile)
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(sim.rig_yaml(rig))
    proc = run_mousedom("replay", "-c", str(cfg), "--capture", str(path))
    assert proc.returncode == 0, proc.stderr
    assert "\x1b" not in proc.stdout + proc.stderr and "\x07" not in proc.stdout + proc.stderr
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("gyro "))
    assert line.endswith(f"{path} (mpu\\x1b]0;pwned\\x07\\x1b[2J)"), line


def test_summary_says_when_the_gyro_was_left_out_or_ignored(tmp_path):
    rig, res = simulated()
    plain, with_gyro = tmp_path / "plain.mdcap", tmp_path / "g.mdcap"
    write_capture(plain, rig, res, gyro=False)
    write_capture(with_gyro, rig, res)
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(sim.rig_yaml(rig))
    proc = run_mousedom("replay", "-c", str(cfg), "--capture", str(plain))
    assert proc.returncode == 0, proc.stderr
    assert "gyro         none in the captures: replayed without it" in proc.stdout
    assert "no capture holds a gyro: replayed without it" in proc.stderr
    bare = tmp_path / "bare.yaml"
    bare.write_text(sim.rig_yaml(dataclasses.replace(rig, gyro=None)))
    proc = run_mousedom("replay", "-c", str(bare), "--capture", str(with_gyro), "-o", "-")
    assert proc.returncode == 0, proc.stderr
    assert "gyro" not in proc.stdout.split("\n", 1)[0]
    assert "is a gyro and" in proc.stderr and "its samples are ignored" in proc.stderr


def test_convert_keeps_the_gyro(tmp_path):
    rig, res = simulated()
    path = tmp_path / "g.mdcap"
    write_capture(path, rig, res)
    out = tmp_path / "copy.mdcap"
    proc = run_mousedom("convert", "--capture", str(path), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "1 gyro" in proc.stderr and f"{len(res.gyro.t)} gyro samples" in proc.stderr
    cap = open_capture(str(out))
    assert [d.kind for d in cap.devices] == ["evdev"] * 3 + ["iio"]
    assert struct.unpack("<HH", out.read_bytes()[8:12]) == GYRO_VERSION
    g = [r for feed in cap.feeds() for b in feed.batches for r in b.gyro]
    t = np.concatenate([r.t for r in g])
    rate = np.concatenate([r.rate for r in g])
    assert t.tobytes() == res.gyro.t.tobytes() and rate.tobytes() == res.gyro.rate.tobytes()
    cfg = sim.rig_config(rig)
    a, _, _ = replay(cfg, path)
    b, _, _ = replay(cfg, out)
    assert_same_poses(a, b)


def test_two_gyros_need_a_name(tmp_path):
    rig, res = simulated()
    path = tmp_path / "two.mdcap"
    devices = [DeviceInfo(name=m.name, mouse=m.name, rel_xy=True) for m in rig.mice]
    devices += [GYRO_DEVICE, dataclasses.replace(GYRO_DEVICE, name="bmi160", extra={})]
    with NativeWriter(path, devices) as w:
        for i, m in enumerate(rig.mice):
            r = res.reports[m.name]
            w.motion(i, r.t, r.dx.astype(int), r.dy.astype(int))
        w.gyro(3, res.gyro.t, res.gyro.rate)
        w.gyro(4, res.gyro.t, res.gyro.rate)
    yaml = sim.rig_yaml(rig)
    from mousedom.capture import CaptureError

    with pytest.raises(CaptureError, match="hold 2 gyros .*'mpu6050' .*'bmi160' .*gyro.name"):
        replay(parse_config(yaml, "rig.yaml", need_sources=False), path)
    named = parse_config(yaml + "  name: bmi160\n", "rig.yaml", need_sources=False)
    r = Replay(named, assign(named, [(None, str(path))]))
    assert r.gyro is not None and r.gyro.device == 4
