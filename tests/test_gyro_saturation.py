"""A gyro read at its converter's limit (issue 30, item 3: "a gyro that saturates is itself
excluded"): the IIO source marks the samples whose raw value is at either end of its
scan type, the tracker gives the windows holding them no gyro turn (their heading is the
mice's alone, on any rig), and the mark survives every capture path (record, the native
format, convert, replay, the daemon's gyro replay)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from iio_fakes import MPU6050_SCALE, Writer, add_gyro, gyro_records, stamps_ns
from test_capture_gyro import GYRO, MOUSE, _chunk, _file, _rate_payload, read_all

from mousedom.capture import CaptureError, NativeWriter
from mousedom.capture.native import GYRO_VERSION
from mousedom.capture.native_format import RATE_SATURATED
from mousedom.config import GyroConfig
from mousedom.fusion import sim, simgyro
from mousedom.fusion.drives import drive
from mousedom.sources.iio import GyroSource, IioPaths
from mousedom.sources.iio_layout import parse_scan_type

T0 = 5000.0


# ------------------------------------------------------------------ the source


def _ends(kind: str) -> tuple[int, int]:
    """The ends of a type's valid bits, worked out here from the ABI's words."""
    text = kind.split(":")[1]
    signed, bits = text[0] == "s", int(text[1:].split("/")[0])
    return (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if signed else (0, 2**bits - 1)


@pytest.mark.parametrize(
    "kind", ["be:s16/16>>0", "le:s16/16>>0", "le:s24/32>>8", "be:s12/16>>4", "le:u16/16>>0"]
)
def test_the_scan_type_gives_the_raw_range(kind):
    assert parse_scan_type(kind).raw_range == _ends(kind)


@pytest.mark.parametrize("kind", ["be:s16/16>>0", "le:s24/32>>8", "be:s12/16>>4", "le:u16/16>>0"])
def test_buffered_samples_at_either_end_of_the_raw_range_are_marked(tmp_path, kind):
    lo, hi = _ends(kind)
    raw = [0, lo, lo + 1, hi - 1, hi, 7, hi, lo]
    add_gyro(tmp_path, types={"in_anglvel_z": kind})
    src = GyroSource(GyroConfig(name="mpu6050"), IioPaths.under(str(tmp_path)))
    src.open()
    w = Writer(tmp_path / "dev" / "iio:device0")
    w.write(gyro_records(raw, stamps_ns(T0, len(raw)), kind, junk=True))
    [b] = src.read(T0 + 0.1)
    assert b.saturated is not None
    assert b.saturated.tolist() == [v in (lo, hi) for v in raw]
    held = sum(v in (lo, hi) for v in raw)  # (an unsigned channel's 0 is its low end)
    assert src.health.extra["raw_range"] == [lo, hi] and src.health.extra["saturated"] == held
    w.write(gyro_records([1, 2, 3], stamps_ns(T0 + 0.1, 3), kind))
    [b] = src.read(T0 + 0.2)
    assert b.saturated is None  # none at the limit: nothing to mark
    w.close()
    src.close()


@pytest.mark.parametrize(("tree", "known"), [({"trigger": ""}, True), ({"buffered": False}, False)])
def test_polled_samples_are_marked_where_the_device_publishes_a_scan_type(tmp_path, tree, known):
    sysdir = add_gyro(tmp_path, raw={"z": "32767"}, **tree)
    src = GyroSource(GyroConfig(name="mpu6050", sample_hz=100), IioPaths.under(str(tmp_path)),
                     clock=lambda: T0)  # fmt: skip
    src.open()
    [b] = src.read(T0)
    if known:
        assert b.saturated is not None and b.saturated.tolist() == [True]
        assert src.health.extra["raw_range"] == [-32768, 32767]
    else:  # no _type to read the range from: it cannot tell, and says so
        assert b.saturated is None and src.health.extra["raw_range"] is None
    (sysdir / "in_anglvel_z_raw").write_text("-12\n")
    [b] = src.read(T0 + 0.02)
    assert b.saturated is None
    src.close()


def test_a_polled_reading_no_gyro_makes_is_dropped_and_said(tmp_path):
    """A raw attribute far beyond any range (hostile, or a driver's bug) would be a turn of
    a billion radians in a window: dropped, counted, and said with what it read."""
    sysdir = add_gyro(tmp_path, raw={"z": str(10**15)}, buffered=False)
    src = GyroSource(GyroConfig(name="mpu6050", sample_hz=100), IioPaths.under(str(tmp_path)),
                     clock=lambda: T0)  # fmt: skip
    src.open()
    assert src.read(T0) == []
    assert src.health.dropped == 1 and "not a gyro's" in (src.health.error or "")
    (sysdir / "in_anglvel_z_raw").write_text("9" * 400 + "\n")  # past a float's range
    assert src.read(T0 + 0.02) == []
    assert src.health.dropped == 2 and "no reading of a converter" in (src.health.error or "")
    (sysdir / "in_anglvel_z_raw").write_text("-12\n")
    [b] = src.read(T0 + 0.04)
    assert b.rate.tolist() == [-12 * float(MPU6050_SCALE)]
    src.close()


# ------------------------------------------------------------------ the fusion


def _axle_rig(full_scale: float, seed: int) -> tuple[sim.Rig, sim.SimResult]:
    """Two mice on the axle of a diff-drive robot, a gyro whose range the drive's turns
    exceed (a sensitive range chosen for a slow robot, which then spins faster)."""
    left = sim.SimMouse("left", 0.0, 0.12, cpi_x=1000.0, cpi_y=1000.0, report_hz=500.0,
                        noise=0.3)  # fmt: skip
    right = dataclasses.replace(left, name="right", y=-0.12)
    gyro = simgyro.SimGyro(full_scale=full_scale, phase=0.0007 * seed)
    rig = sim.Rig((left, right), model="diff-drive", gyro=gyro)
    traj = sim.sequence(sim.pause(1.0), drive(20.0, seed=seed), sim.turn(2 * math.pi, rate=1.6))
    return rig, sim.simulate(rig, traj, seed=seed)


def _run(result, cfg, marked: bool = True):
    if not marked:
        result = dataclasses.replace(
            result,
            gyro=dataclasses.replace(result.gyro, saturated=np.zeros_like(result.gyro.saturated)),
        )
    batch, _ = sim.run_tracker(result, cfg)
    return batch


def _heading_error(result, batch) -> float:
    end = result.truth(batch.t[-1:])[0]
    return abs((batch.theta[-1] - end[2] + math.pi) % (2 * math.pi) - math.pi)


@pytest.mark.parametrize("seed", range(4))
def test_a_window_holding_a_saturated_sample_has_the_mice_heading_exactly(seed):
    """In every window the gyro saturated in, the heading moved exactly as the mice alone
    moved it; elsewhere the gyro is used."""
    rig, res = _axle_rig(full_scale=0.8, seed=seed)
    assert res.gyro.saturated.sum() > 20
    cfg = sim.rig_config(rig)
    with_gyro = _run(res, cfg)
    mice = _run(res, dataclasses.replace(cfg, gyro=None))
    assert with_gyro.t.tolist() == mice.t.tolist()
    g = res.gyro
    # the windows holding a saturated sample's span (from the sample before to it)
    starts = np.concatenate([[-math.inf], g.t[:-1]])[g.saturated]
    ends = g.t[g.saturated]
    lo = with_gyro.t - 1.0 / cfg.rate_hz
    held = np.array([bool(((starts < b) & (ends > a)).any()) for a, b in
                     zip(lo, with_gyro.t, strict=True)])  # fmt: skip
    assert held.sum() > 10
    assert np.isnan(with_gyro.gyro[held, 0]).all()  # no gyro turn there
    assert np.isfinite(with_gyro.gyro[~held & (with_gyro.t > g.t[0] + 0.1), 0]).all()
    d_gyro = np.diff(with_gyro.theta)[held[1:]]
    d_mice = np.diff(mice.theta)[held[1:]]
    np.testing.assert_allclose(d_gyro, d_mice, rtol=0, atol=1e-12)


def test_the_daemons_path_leaves_out_the_same_windows_as_replay():
    """The one-window path (the daemon's, samples pushed one at a time) gives what the
    array path (replay's) gives on a drive whose gyro saturates."""
    from mousedom.fusion.posebatch import PoseBatch
    from mousedom.fusion.tracker import Tracker

    rig, res = _axle_rig(full_scale=0.8, seed=5)
    cfg = sim.rig_config(rig)
    batch = _run(res, cfg)
    live = PoseBatch.concat(sim.run_tracker_live(res, Tracker(cfg, t0=0.0)), 2)
    assert len(live) == len(batch) and batch.gyro is not None and live.gyro is not None
    assert np.isnan(live.gyro[:, 0]).tolist() == np.isnan(batch.gyro[:, 0]).tolist()
    np.testing.assert_allclose(live.theta, batch.theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(live.x, batch.x, rtol=0, atol=1e-12)


def test_marked_saturation_keeps_the_heading_over_many_drives():
    """Over seeded drives that spin past the gyro's range: with the marks the end heading
    is no worse than the mice's alone (root mean square over the seeds); a clipped rate
    taken as a turn costs degrees."""
    marked, unmarked, mice = [], [], []
    for seed in range(16):
        rig, res = _axle_rig(full_scale=1.0, seed=seed)
        cfg = sim.rig_config(rig)
        marked.append(_heading_error(res, _run(res, cfg)))
        unmarked.append(_heading_error(res, _run(res, cfg, marked=False)))
        mice.append(_heading_error(res, _run(res, dataclasses.replace(cfg, gyro=None))))
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in
           (("marked", marked), ("unmarked", unmarked), ("mice", mice))}  # fmt: skip
    assert rms["marked"] <= rms["mice"], rms
    assert np.median(unmarked) > 5 * np.median(marked) and np.median(unmarked) > 0.02, rms


# ------------------------------------------------------------------ captures


@pytest.mark.parametrize(("step", "chunk"), [(100.0, 1 << 20), (0.25, 300)])
def test_replay_of_a_saturating_drive_is_the_tracker_fed_directly(tmp_path, step, chunk):
    """The marks go through the capture and the replay: the same poses as the tracker given
    the samples and marks directly, and the replayed gyro source gives the marks back."""
    from test_capture_gyro_replay import assert_same_poses, replay, write_capture

    from mousedom.capture.source import GyroReplaySource

    rig, res = _axle_rig(full_scale=0.8, seed=3)
    path = tmp_path / "s.mdcap"
    write_capture(path, rig, res, step=step, chunk=chunk)
    cfg = sim.rig_config(rig)
    got, summary, _ = replay(cfg, path)
    # (to the last bits of float sums: the end's two windows close apart from the others)
    assert_same_poses(got, _run(res, cfg), exact=False)
    assert summary.gyro is not None
    assert summary.gyro.stats.saturated == int(res.gyro.saturated.sum())
    src = GyroReplaySource(GyroConfig(replay=str(path)), loop=False, clock=lambda: 0.0)
    src.open()
    marks = [np.zeros(len(b.t), bool) if b.saturated is None else b.saturated
             for b in src.read(1e9)]  # fmt: skip
    assert np.concatenate(marks).tolist() == res.gyro.saturated.tolist()


def _sat_samples(seed: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = 100.0 + np.cumsum(rng.uniform(0.001, 0.01, n))
    sat = rng.random(n) < rng.choice([0.0, 0.01, 0.3])
    rate = np.where(sat, 4.36, rng.normal(0.0, 2.0, n))
    return t, rate, sat


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 3000), chunk=st.integers(1, 1200),
       compress=st.booleans())  # fmt: skip
def test_the_marks_round_trip_bit_exact(tmp_path_factory, seed, n, chunk, compress):
    p = tmp_path_factory.mktemp("sat") / "g.mdcap"
    t, rate, sat = _sat_samples(seed, n)
    with NativeWriter(p, [MOUSE, GYRO], compress=compress, chunk_reports=chunk) as w:
        for a in range(0, n, 997):
            w.gyro(1, t[a : a + 997], rate[a : a + 997], sat[a : a + 997])
            w.sync(float(t[min(a + 996, n - 1)]))
    cap, batches = read_all(p)
    got = [r for b in batches for r in b.gyro]
    assert np.concatenate([r.t for r in got]).tolist() == t.tolist()
    assert np.concatenate([r.rate for r in got]).tolist() == rate.tolist()
    marks = [np.zeros(len(r.t), bool) if r.saturated is None else r.saturated for r in got]
    assert np.concatenate(marks).tolist() == sat.tolist()
    assert cap.stats[1].saturated == int(sat.sum())
    assert cap.header["version"] == list(GYRO_VERSION)


def test_a_saturated_chunk_that_is_malformed_is_refused_at_its_offset(tmp_path):
    def payload(flags: bytes) -> bytes:
        return _rate_payload([2.0, 3.0], [4.36, 0.1]) + flags

    first = _chunk(5, 0, 1, _rate_payload([1.0], [0.0]))
    p = tmp_path / "hostile.mdcap"
    for chunk, needle in (
        (_chunk(RATE_SATURATED, 0, 2, payload(b"\x01\x02")), "gyro sample 1 is marked saturated 2"),
        (_chunk(RATE_SATURATED, 0, 2, payload(b"\x01")), "holds 33 bytes, not 34"),
        (_chunk(RATE_SATURATED, 0, 2, payload(b"")), "holds 32 bytes, not 34"),
    ):
        p.write_bytes(_file(GYRO_VERSION, [GYRO.as_dict()], first + chunk))
        offset = len(_file(GYRO_VERSION, [GYRO.as_dict()], first))
        with pytest.raises(CaptureError, match=rf"byte offset {offset}: .*{needle}"):
            read_all(p)
    one = _chunk(RATE_SATURATED, 0, 1, _rate_payload([1.0], [0.0]) + b"\x01")
    p.write_bytes(_file(GYRO_VERSION, [MOUSE.as_dict()], one))
    with pytest.raises(CaptureError, match="gyro samples for device 'left mouse'"):
        read_all(p)
    # the good one reads
    p.write_bytes(_file(GYRO_VERSION, [GYRO.as_dict()],
                        first + _chunk(RATE_SATURATED, 0, 2, payload(b"\x01\x00"))))  # fmt: skip
    _, batches = read_all(p)
    marks = [r.saturated for b in batches for r in b.gyro]
    assert marks[0] is None and marks[1].tolist() == [True, False]
