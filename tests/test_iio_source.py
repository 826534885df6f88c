"""The IIO gyro source on a fake sysfs tree and a FIFO standing for /dev/iio:deviceN
(tests/iio_fakes.py): what open writes and close puts back, records round-tripped to the
same rates and stamps, the polled fallback, errors naming path and attribute, hotplug."""

from __future__ import annotations

import errno
import os
import re
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from iio_fakes import (
    GYRO_TYPE,
    INDEX,
    MPU6050_SCALE,
    TIMESTAMP_TYPE,
    Writer,
    add_gyro,
    attr,
    enabled,
    gyro_records,
    pack_records,
    stamps_ns,
)

from mousedom.config import GyroConfig
from mousedom.sources import iio_sysfs
from mousedom.sources.base import STAMP_AHEAD_S, SourceGone, SourceUnavailable
from mousedom.sources.iio import BUFFER_SCANS, GyroMode, GyroSamples, GyroSource, IioPaths

T0 = 5000.0  # seconds on the (test's) monotonic clock: records are stamped near it
SCALE = float(MPU6050_SCALE)


def source(root, clock=None, **cfg) -> GyroSource:
    cfg.setdefault("name", "mpu6050")
    kwargs = {"clock": clock} if clock else {}
    return GyroSource(GyroConfig(**cfg), IioPaths.under(str(root)), **kwargs)


def read_until(src: GyroSource, now: float, gone_ok: bool = False):
    """Everything readable now: (t, rate, gone)."""
    t, rate = [], []
    for _ in range(100):
        try:
            batches = src.read(now)
        except SourceGone:
            if not gone_ok:
                raise
            return np.concatenate(t or [[]]), np.concatenate(rate or [[]]), True
        if not batches:
            break
        for b in batches:
            assert isinstance(b, GyroSamples) and b.gyro == "gyro"
            assert b.t.dtype == np.float64 and b.rate.dtype == np.float64
            t.append(b.t)
            rate.append(b.rate)
    return np.concatenate(t or [[]]), np.concatenate(rate or [[]]), False


# ------------------------------------------------------------------ open and close


def test_open_writes_clock_elements_and_buffer_then_close_puts_them_back(tmp_path):
    sysdir = add_gyro(tmp_path)
    (sysdir / "scan_elements" / "in_accel_x_en").write_text("1\n")  # someone's earlier choice
    (sysdir / "buffer" / "watermark").write_text("64\n")  # (iio_generic_buffer -w 64)
    src = source(tmp_path, sample_hz=200)
    src.open()
    assert src.mode is GyroMode.BUFFERED and src.fileno() >= 0 and not src.paced
    assert attr(sysdir, "current_timestamp_clock") == "monotonic"
    assert enabled(sysdir) == {"in_anglvel_z", "in_timestamp"}
    assert attr(sysdir, "buffer/enable") == "1"
    assert int(attr(sysdir, "buffer/length")) >= BUFFER_SCANS
    assert attr(sysdir, "buffer/watermark") == "1"  # each record wanted as it comes
    assert attr(sysdir, "sampling_frequency") == "200"
    assert src.layout is not None and src.layout.size == 16  # be:s16 + s64: padded to 16
    assert src.scale == SCALE and src.offset == 0.0
    h = src.health.as_dict()
    assert h["connected"] and h["kind"] == "iio" and h["mode"] == "buffered"
    assert h["node"] == str(tmp_path / "dev" / "iio:device0") and h["record_bytes"] == 16
    assert src.identity() == os.path.realpath(sysdir)
    src.close()
    assert attr(sysdir, "buffer/enable") == "0"
    assert enabled(sysdir) == {"in_accel_x"}
    assert attr(sysdir, "current_timestamp_clock") == "realtime"
    assert attr(sysdir, "buffer/length") == "1" and attr(sysdir, "sampling_frequency") == "50"
    assert attr(sysdir, "buffer/watermark") == "64"
    assert src.fileno() == -1
    src.close()  # twice is fine


def test_found_by_path_sysfs_dev_node_or_link(tmp_path):
    add_gyro(tmp_path, 0, "bmi160")
    sysdir = add_gyro(tmp_path, 3, "mpu6050")
    os.symlink("iio:device3", tmp_path / "dev" / "mousedom-gyro")
    for path in ("/sys/bus/iio/devices/iio:device3", "/dev/iio:device3", "/dev/mousedom-gyro",
                 str(sysdir)):  # fmt: skip
        src = source(tmp_path, name=None, path=path)
        src.open()
        assert src.device is not None and src.device.sysdir.name == "iio:device3", path
        src.close()


def test_a_stale_buffer_is_turned_off_first_and_left_off(tmp_path):
    sysdir = add_gyro(tmp_path)
    (sysdir / "buffer" / "enable").write_text("1\n")  # a reader died with it on
    src = source(tmp_path)
    src.open()
    src.close()
    assert attr(sysdir, "buffer/enable") == "0"


# ------------------------------------------------------------------ the data plane


@pytest.mark.parametrize(
    "kind, raw",
    [
        ("be:s16/16>>0", [0, 1, -1, 32767, -32768, 1234]),  # the MPU-6050's
        ("le:s16/16>>0", [0, 1, -1, 32767, -32768, -4321]),
        ("le:s24/32>>8", [0, -(2**23), 2**23 - 1, 5, -5, 77]),  # 32-bit storage, shifted
        ("be:s12/16>>4", [0, -2048, 2047, 3, -3, 100]),
        ("le:u16/16>>0", [0, 65535, 1, 2, 3, 32768]),
    ],
)
def test_records_round_trip_to_the_same_rates_and_stamps(tmp_path, kind, raw):
    add_gyro(tmp_path, types={"in_anglvel_z": kind}, offset="-2")
    src = source(tmp_path)
    src.open()
    ns = stamps_ns(T0, len(raw))
    w = Writer(tmp_path / "dev" / "iio:device0")
    w.write(gyro_records(raw, ns, kind, junk=True))
    t, rate, _ = read_until(src, T0 + 0.1)
    assert t.tolist() == (ns.astype(np.float64) / 1e9).tolist()
    assert rate.tolist() == [(r - 2.0) * SCALE for r in raw]
    assert src.health.reports == len(raw) and src.health.last_t == t[-1]
    w.close()
    src.close()


def test_upside_down_x_axis_with_its_own_scale_and_offset(tmp_path):
    sysdir = add_gyro(tmp_path, axis_scale={"x": "0.5"}, offset="10", axis_offset={"x": "1"})
    src = source(tmp_path, axis="x", sign=-1)
    src.open()
    assert enabled(sysdir) == {"in_anglvel_x", "in_timestamp"}
    assert (src.scale, src.offset) == (0.5, 1.0)  # the axis' own before the shared
    w = Writer(tmp_path / "dev" / "iio:device0")
    w.write(gyro_records([3, -5], stamps_ns(T0, 2), axis="x"))
    _, rate, _ = read_until(src, T0)
    assert rate.tolist() == [-2.0, 2.0]  # -1 * (raw + 1) * 0.5: CCW positive about body z
    w.close()
    src.close()


def test_all_three_axes_enabled_only_z_used(tmp_path, monkeypatch):
    """A driver whose scan mask keeps x, y and z together (available_scan_masks): the
    record is what the elements read back, not what was asked for."""
    sysdir = add_gyro(tmp_path)
    write = iio_sysfs.write_attr

    def stubborn(path, value, who):
        if path.name in ("in_anglvel_x_en", "in_anglvel_y_en") and value == "0":
            return
        write(path, value, who)

    monkeypatch.setattr(iio_sysfs, "write_attr", stubborn)
    for axis in "xy":
        (sysdir / "scan_elements" / f"in_anglvel_{axis}_en").write_text("1\n")
    src = source(tmp_path)
    src.open()
    assert src.layout is not None
    assert src.layout.names() == ("in_anglvel_x", "in_anglvel_y", "in_anglvel_z", "in_timestamp")
    assert [f.offset for f in src.layout.fields] == [0, 2, 4, 8] and src.layout.size == 16
    channels = [(INDEX[f"in_anglvel_{a}"], GYRO_TYPE) for a in "xyz"]
    channels.append((INDEX["in_timestamp"], TIMESTAMP_TYPE))
    ns = stamps_ns(T0, 3)
    rows = [(111, 222, z, t) for z, t in zip([7, -8, 9], ns, strict=True)]
    w = Writer(tmp_path / "dev" / "iio:device0")
    w.write(pack_records(channels, rows))
    _, rate, _ = read_until(src, T0)
    assert rate.tolist() == [7 * SCALE, -8 * SCALE, 9 * SCALE]
    w.close()
    src.close()


def test_records_split_anywhere_are_carried_over(tmp_path):
    add_gyro(tmp_path)
    src = source(tmp_path)
    src.open()
    raw = list(range(-20, 20))
    ns = stamps_ns(T0, len(raw))
    data = gyro_records(raw, ns)
    w = Writer(tmp_path / "dev" / "iio:device0")
    got = []
    for a, b in ((0, 5), (5, 16), (16, 17), (17, 300), (300, len(data))):
        w.write(data[a:b])
        got.append(read_until(src, T0)[1])
    assert np.concatenate(got).tolist() == [r * SCALE for r in raw]
    w.close()
    src.close()


def test_far_and_backward_stamps_are_bounded(tmp_path):
    add_gyro(tmp_path)
    src = source(tmp_path)
    src.open()
    ns = [int(T0 * 1e9), 2**63 - 1, int((T0 - 0.5) * 1e9), -(2**63)]
    w = Writer(tmp_path / "dev" / "iio:device0")
    w.write(gyro_records([1, 2, 3, 4], ns))
    t, rate, _ = read_until(src, T0 + 0.01)
    assert rate.tolist() == [1 * SCALE, 2 * SCALE, 3 * SCALE, 4 * SCALE]  # values kept
    assert np.all(np.diff(t) >= 0) and t.max() <= T0 + 0.01 + STAMP_AHEAD_S
    assert src.stamps_restamped == 2 and src.time_backwards >= 1
    assert "re-stamped" in (src.health.error or "")
    w.close()
    src.close()


@settings(max_examples=40, deadline=None)
@given(blob=st.binary(max_size=600))
def test_hostile_bytes_never_raise_anything_but_gone(tmp_path_factory, blob):
    root = tmp_path_factory.mktemp("hostile")
    add_gyro(root)
    src = source(root)
    src.open()
    w = Writer(root / "dev" / "iio:device0")
    w.write(blob)
    t, rate, _ = read_until(src, T0)
    assert len(t) == len(rate) == len(blob) // 16
    assert np.all(np.isfinite(t)) and np.all(np.diff(t) >= 0)
    w.close()
    _, _, gone = read_until(src, T0, gone_ok=True)
    assert gone and src.truncated_bytes == len(blob) % 16
    src.close()


# ------------------------------------------------------------------ hotplug


def test_writer_closing_is_the_unplug_then_reopen(tmp_path):
    sysdir = add_gyro(tmp_path)
    src = source(tmp_path)
    src.open()
    assert src.read(T0) == []  # no writer yet: not an unplug
    assert src.health.connected
    w = Writer(tmp_path / "dev" / "iio:device0")
    w.write(gyro_records([5, 6], stamps_ns(T0, 2)) + b"\1\2\3")  # and a cut record
    w.close()
    t, rate, gone = read_until(src, T0, gone_ok=True)
    assert gone and rate.tolist() == [5 * SCALE, 6 * SCALE]  # delivered before the error
    assert not src.health.connected and "device gone" in src.health.error
    assert src.truncated_bytes == 3
    assert attr(sysdir, "buffer/enable") == "0" and enabled(sysdir) == set()  # restored
    src.open()
    assert src.health.connected and attr(sysdir, "buffer/enable") == "1"
    w = Writer(tmp_path / "dev" / "iio:device0")
    w.write(gyro_records([9], stamps_ns(T0 + 1, 1)))
    assert read_until(src, T0 + 1)[1].tolist() == [9 * SCALE]
    w.close()
    src.close()


def test_tree_vanishing_is_gone_then_unavailable_until_it_is_back(tmp_path):
    sysdir = add_gyro(tmp_path)
    src = source(tmp_path)
    src.open()
    w = Writer(tmp_path / "dev" / "iio:device0")
    shutil.rmtree(sysdir)
    os.unlink(tmp_path / "dev" / "iio:device0")
    w.close()
    with pytest.raises(SourceGone):
        read_until(src, T0)
    with pytest.raises(SourceUnavailable, match="no IIO device is named 'mpu6050'"):
        src.open()
    add_gyro(tmp_path)
    src.open()
    assert src.health.connected
    src.close()


# ------------------------------------------------------------------ the polled fallback


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        self.t += 0.0005
        return self.t


@pytest.mark.parametrize(
    "tree, why",
    [
        ({"trigger": ""}, "trigger/current_trigger is empty"),
        ({"buffered": False}, "no scan_elements/in_anglvel_z_en"),
        ({"clock": None}, "kernels before 4.5"),
        ({"node": False}, "dev/iio:device0"),
    ],
)
def test_without_a_buffer_it_polls_the_raw_attribute(tmp_path, tree, why):
    sysdir = add_gyro(tmp_path, raw={"z": "-40"}, **tree)
    clock = Clock(T0)
    src = source(tmp_path, clock=clock, sample_hz=100)
    src.open()
    assert src.mode is GyroMode.POLLED and src.paced and src.fileno() == -1
    assert why in src.health.extra["polled_because"]
    assert src.health.extra["mode"] == "polled" and src.health.error is None
    assert attr(sysdir, "sampling_frequency") == "100"
    [b] = src.read(T0)
    # stamped in the middle of the attribute's read, on the injected clock
    assert b.rate.tolist() == [-40 * SCALE] and b.t.tolist() == [T0 + 0.00075]
    assert src.read(T0 + 0.005) == []  # not due yet at 100 Hz
    (sysdir / "in_anglvel_z_raw").write_text("12\n")
    [b] = src.read(T0 + 0.02)
    assert b.rate.tolist() == [12 * SCALE]
    (sysdir / "in_anglvel_z_raw").write_text("oops\n")
    assert src.read(T0 + 0.04) == []
    assert src.health.dropped == 1
    assert "in_anglvel_z_raw: 'oops' is not an integer" in (src.health.error or "")
    (sysdir / "in_anglvel_z_raw").unlink()
    with pytest.raises(SourceGone, match="in_anglvel_z_raw: device gone"):
        src.read(T0 + 0.06)
    assert not src.health.connected
    assert attr(sysdir, "sampling_frequency") == "50"  # put back by the close on gone


def test_polled_needs_the_raw_attribute(tmp_path):
    sysdir = add_gyro(tmp_path, trigger="")
    (sysdir / "in_anglvel_z_raw").unlink()
    with pytest.raises(SourceUnavailable, match=r"in_anglvel_z_raw: missing, and no buffer"):
        source(tmp_path).open()


# ------------------------------------------------------------------ errors name what


def test_clock_that_cannot_be_set_is_refused_and_nothing_stays_changed(tmp_path, monkeypatch):
    sysdir = add_gyro(tmp_path)
    write = iio_sysfs.write_attr

    def denied(path, value, who):
        if path.name == "current_timestamp_clock":
            raise SourceUnavailable(f"{who}: {path}: permission denied writing {value!r}")
        write(path, value, who)

    monkeypatch.setattr(iio_sysfs, "write_attr", denied)
    src = source(tmp_path)
    with pytest.raises(SourceUnavailable) as e:
        src.open()
    msg = str(e.value)
    assert str(sysdir / "current_timestamp_clock") in msg and "realtime" in msg
    assert "refused" in msg and src.health.error == msg and not src.health.connected
    assert src.fileno() == -1 and attr(sysdir, "buffer/enable") == "0"
    assert enabled(sysdir) == set()


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda d: (d / "in_anglvel_scale").unlink(), "neither in_anglvel_z_scale nor"),
        (lambda d: (d / "in_anglvel_scale").write_text("abc\n"), "in_anglvel_scale: 'abc' is not"),
        (lambda d: (d / "in_anglvel_scale").write_text("nan\n"), "in_anglvel_scale: 'nan' is not"),
        (lambda d: (d / "in_anglvel_scale").write_text("0\n"), "in_anglvel_scale: a scale of 0"),
        (lambda d: (d / "in_anglvel_offset").write_text("1e999\n"), "in_anglvel_offset: '1e999'"),
        (
            lambda d: (d / "scan_elements" / "in_anglvel_z_type").write_text("le:s16/16>>0junk"),
            "scan_elements/in_anglvel_z_type: 'le:s16/16>>0junk' is not a scan type",
        ),
        (
            lambda d: (d / "scan_elements" / "in_timestamp_type").write_text("le:s64/48>>0"),
            "in_timestamp_type: 'le:s64/48>>0': storage of 48 bits",
        ),
        (
            lambda d: (d / "scan_elements" / "in_anglvel_z_index").write_text("-1"),
            "in_anglvel_z_index: '-1' is not a scan index",
        ),
        (
            lambda d: (d / "scan_elements" / "in_anglvel_z_type").write_text("le:s16/16X2>>0"),
            "in_anglvel_z_type: repeats 2 values a record; a rate channel holds one",
        ),
        (
            lambda d: (d / "scan_elements" / "in_timestamp_type").write_text("le:s32/32>>0"),
            "in_timestamp_type: not one 64-bit timestamp a record",
        ),
        (
            lambda d: (d / "scan_elements" / "in_timestamp_index").write_text("6"),
            "have the same scan index 6",
        ),
    ],
)
def test_bad_attributes_are_refused_naming_path_and_attribute(tmp_path, change, words):
    sysdir = add_gyro(tmp_path)
    (sysdir / "in_anglvel_offset").write_text("0\n")
    change(sysdir)
    src = source(tmp_path)
    with pytest.raises(SourceUnavailable, match=re.escape(words)) as e:
        src.open()
    assert str(sysdir) in str(e.value) and "\n" not in str(e.value)
    assert attr(sysdir, "buffer/enable") == "0" and enabled(sysdir) == set()


def test_absent_ambiguous_and_mismatched_devices(tmp_path):
    with pytest.raises(SourceUnavailable, match=r"no IIO device is named 'mpu6050' \(IIO "
                       r"devices: none\)"):  # fmt: skip
        source(tmp_path).open()
    add_gyro(tmp_path, 0)
    add_gyro(tmp_path, 1)
    with pytest.raises(SourceUnavailable, match="2 IIO devices are named 'mpu6050'.*gyro.path"):
        source(tmp_path).open()
    with pytest.raises(SourceUnavailable, match="/dev/iio:device7: no such IIO device"):
        source(tmp_path, name=None, path="/dev/iio:device7").open()
    with pytest.raises(SourceUnavailable, match=r"iio:device1/name: 'mpu6050', not 'bmi160'"):
        source(tmp_path, name="bmi160", path="/sys/bus/iio/devices/iio:device1").open()


def test_permission_on_a_sysfs_attribute_names_it_and_the_rule(tmp_path, monkeypatch):
    sysdir = add_gyro(tmp_path)
    real_open = os.open

    def no_write(path, flags, *a):
        if flags & os.O_WRONLY and str(path).endswith("buffer/enable"):
            raise PermissionError(13, "Permission denied")
        return real_open(path, flags, *a)

    monkeypatch.setattr(os, "open", no_write)
    with pytest.raises(SourceUnavailable, match=r"buffer/enable: permission denied writing '1': "
                       r"install the udev rule"):  # fmt: skip
        source(tmp_path).open()
    monkeypatch.undo()
    assert enabled(sysdir) == set() and attr(sysdir, "current_timestamp_clock") == "realtime"


def test_enodev_from_the_node_is_gone(tmp_path, monkeypatch):
    """A real device unbound or unplugged fails the read with ENODEV (a FIFO cannot)."""
    add_gyro(tmp_path)
    src = source(tmp_path)
    src.open()
    fd = src.fileno()
    real_read = os.read

    def unplugged(f, n):
        if f == fd:
            raise OSError(errno.ENODEV, "No such device")
        return real_read(f, n)

    monkeypatch.setattr(os, "read", unplugged)
    with pytest.raises(SourceGone, match=r"iio:device0: device gone \(No such device\)"):
        src.read(T0)
    assert not src.health.connected and src.fileno() == -1


def test_a_node_in_use_elsewhere_is_refused_before_anything_changes(tmp_path, monkeypatch):
    sysdir = add_gyro(tmp_path)
    real_open = os.open

    def busy(path, flags, *a):
        if str(path).endswith("dev/iio:device0"):
            raise OSError(errno.EBUSY, "Device or resource busy")
        return real_open(path, flags, *a)

    monkeypatch.setattr(os, "open", busy)
    with pytest.raises(SourceUnavailable, match="iio:device0: in use by another reader"):
        source(tmp_path, sample_hz=400).open()
    monkeypatch.undo()
    assert attr(sysdir, "current_timestamp_clock") == "realtime"
    assert attr(sysdir, "sampling_frequency") == "50" and enabled(sysdir) == set()


@pytest.mark.parametrize("hz,quiet_until", [("4", 2.5), ("50", 0.5), ("1000 2000", 0.5)])
def test_a_slow_device_s_own_rate_sets_its_silence(tmp_path, hz, quiet_until):
    """Without gyro.sample_hz the silence rule was a fixed 0.5 s: a device sampling below
    20 Hz was declared gone every 0.5 s and reopened in a loop.  Its own sampling_frequency
    now counts as sample_hz would (ten periods, at least 0.5 s); one that is no number
    (an available-frequencies list) leaves the 0.5 s."""
    sysdir = add_gyro(tmp_path)
    (sysdir / "sampling_frequency").write_text(hz + "\n")
    src = source(tmp_path)
    src.open()
    assert src.silent_s == quiet_until
    w = Writer(tmp_path / "dev" / "iio:device0")  # a live device that sends nothing
    assert src.read(T0) == []
    assert src.read(T0 + quiet_until - 0.05) == []
    with pytest.raises(SourceGone, match=f"no sample for {quiet_until:g} s"):
        src.read(T0 + quiet_until + 0.05)
    w.close()
    src.close()
