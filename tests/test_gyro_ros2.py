"""A gyro from a ROS 2 sensor_msgs/Imu topic (issue 30, item 6: ``gyro: {ros2: ...}``).

The source against a Cyclone DDS writer of the message on loopback (``LOOPBACK``, as
tests/test_ros2.py): axis and sign, stamps on either clock, messages without an angular
velocity or with one no gyro reads; then the real daemon fusing it and ``run --record``
keeping its samples exactly.  tests/test_ros2_interop.py has it from an rclpy node on
Fast DDS, ROS 2's default middleware.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from conftest import dds_domain
from test_ros2 import LOOPBACK

from mousedom.config import ConfigError, GyroConfig, GyroRos2, parse_config

pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")


def _mice(extra: str) -> str:
    return "mice:\n  a: {cpi: 800, mount: {x: 0, y: 0}, replay: x.mdcap}\n" + extra


def test_the_config_names_a_topic_its_domain_and_clock(tmp_path):
    def gyro(text: str):
        return parse_config(_mice(f"gyro: {text}\n"), str(tmp_path / "c.yaml"),
                            need_model=False).gyro  # fmt: skip

    g = gyro("{ros2: /imu/data}")
    assert g is not None and g.ros2 == GyroRos2("/imu/data", None, "system")
    g = gyro("{ros2: {topic: /robot1/imu, domain_id: 7, stamps: monotonic}, axis: x, sign: -1}")
    assert g is not None and g.ros2 == GyroRos2("/robot1/imu", 7, "monotonic")
    assert (g.axis, g.sign) == ("x", -1)
    for text, words in (
        ("{ros2: imu}", r"gyro\.ros2: must be an absolute ROS 2 topic name"),
        ("{ros2: /imu/}", "must be an absolute ROS 2 topic"),
        ("{ros2: {topic: /a b}}", r"gyro\.ros2\.topic: must be an absolute"),
        ("{ros2: /imu, name: mpu6050}", r"gyro\.ros2: a gyro has one source: name"),
        ("{ros2: /imu, replay: x.mdcap}", "a gyro has one source: replay"),
        ("{ros2: {topic: /imu, domain_id: 300}}", "between 0 and 232"),
        ("{ros2: {topic: /imu, stamps: receipt}}", "must be one of system, monotonic, got"),
        ("{ros2: {topc: /imu}}", "did you mean topic"),
    ):
        with pytest.raises(ConfigError, match=words):
            gyro(text)


# ------------------------------------------------------------------ the source


@pytest.fixture
def dds(monkeypatch):
    """A domain of its own (conftest.dds_domain) on loopback only, for this process's Cyclone."""
    monkeypatch.setenv("CYCLONEDDS_URI", LOOPBACK)
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    return dds_domain()


class ImuWriter:
    """A Cyclone DDS writer of sensor_msgs/Imu on ``rt<topic>``, as a driver's would be."""

    def __init__(self, domain: int, topic: str = "/imu/data") -> None:
        from cyclonedds.pub import DataWriter
        from cyclonedds.qos import Policy, Qos
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        from mousedom.service import ros2msgs as msgs
        from mousedom.service.ros2out import participant

        self.msgs = msgs
        p = participant(domain)
        qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)),
                  Policy.Durability.Volatile, Policy.History.KeepLast(1000))  # fmt: skip
        self.w = DataWriter(p, Topic(p, "rt" + topic, msgs.idl_types()[msgs.IMU], qos=qos), qos)

    def matched(self) -> None:
        deadline = time.monotonic() + 10
        while not self.w.get_matched_subscriptions():
            assert time.monotonic() < deadline, "the reader never matched"
            time.sleep(0.02)

    def write(self, stamp: float, w: tuple[float, float, float], no_rate: bool = False) -> None:
        sec = math.floor(stamp)
        self.w.write(self.msgs.build(self.msgs.IMU, {
            "header": {"stamp": {"sec": sec, "nanosec": round((stamp - sec) * 1e9) % 10**9},
                       "frame_id": "imu_link"},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
            "orientation_covariance": [0.0] * 9,
            "angular_velocity": dict(zip("xyz", w, strict=True)),
            "angular_velocity_covariance": [-1.0 if no_rate else 0.0] + [0.0] * 8,
            "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 9.81},
            "linear_acceleration_covariance": [0.0] * 9,
        }))  # fmt: skip


def _read_all(src, n: int):
    t, rate = [], []
    deadline = time.monotonic() + 10
    while len(t) < n and time.monotonic() < deadline:
        for b in src.read(time.monotonic()):
            t += b.t.tolist()
            rate += b.rate.tolist()
        time.sleep(0.01)
    return np.array(t), np.array(rate)


MOUNTS = [("z", 1, "system"), ("x", -1, "monotonic"), ("y", 1, "system")]


@pytest.mark.parametrize(("axis", "sign", "stamps"), MOUNTS)
def test_the_imus_angular_velocity_comes_as_samples_on_the_monotonic_clock(dds, axis, sign, stamps):
    from mousedom.service.ros2imu import Ros2ImuSource

    src = Ros2ImuSource(GyroConfig(ros2=GyroRos2("/imu/data", dds, stamps), axis=axis,
                                   sign=sign))  # fmt: skip
    src.open()
    assert src.paced and src.fileno() == -1 and src.health.extra["domain_id"] == dds
    w = ImuWriter(dds)
    w.matched()
    rng = np.random.default_rng(7)
    lead = time.time() - time.monotonic() if stamps == "system" else 0.0
    base = time.monotonic() - 0.5  # stamped a little before now
    sent_t, sent_rate = [], []
    for i in range(60):
        vec = tuple(rng.normal(0.0, 1.0, 3))
        t = base + 0.005 * i
        if i == 10:
            w.write(t + lead, vec, no_rate=True)  # no angular velocity in it (REP-145)
            continue
        if i == 20:
            w.write(t + lead, (math.nan, math.nan, math.nan))  # no gyro's rate
            continue
        w.write(t + lead, vec)
        sent_t.append(t)
        sent_rate.append(sign * vec["xyz".index(axis)])
    t, rate = _read_all(src, len(sent_t))
    assert rate.tolist() == sent_rate  # exactly the values sent, axis and sign applied
    np.testing.assert_allclose(t, sent_t, rtol=0, atol=2e-3)  # (the clocks' lead, re-read)
    assert np.all(np.diff(t) >= 0)
    ex = src.health.extra
    assert ex["no_rate"] == 1 and src.health.dropped == 1 and ex["frame_id"] == "imu_link"
    assert src.health.reports == len(sent_t)
    src.close()


def test_stamps_far_from_the_clock_are_restamped_and_counted(dds):
    """A driver on sim time, or one that stamps zero: its samples still count, at the time
    they are read, and SOURCE says so."""
    from mousedom.service.ros2imu import Ros2ImuSource

    src = Ros2ImuSource(GyroConfig(ros2=GyroRos2("/imu/data", dds)))
    src.open()
    w = ImuWriter(dds)
    w.matched()
    for i in range(5):
        w.write(12.0 + 0.01 * i, (0.0, 0.0, 0.5))
    before = time.monotonic()
    t, rate = _read_all(src, 5)
    assert rate.tolist() == [0.5] * 5
    assert np.all(t >= before - 1e-6) and np.all(t <= time.monotonic())
    assert src.health.extra["stamps_restamped"] == 5


def test_a_driver_that_stops_or_goes_is_gone_and_comes_back(dds, monkeypatch):
    """No message for SILENT_S after some came: the topic is gone (the windows after it take
    the mice's heading), and joined again it is back with the next message.  A writer that
    is deleted hands its disposal over as an invalid sample: skipped, not a crash."""
    from mousedom.service import ros2imu
    from mousedom.sources.base import SourceGone

    # 1 s: the steps between the message and the first read below (a collection, the
    # writer's deletion) must stay well within it on a machine the other tests load
    monkeypatch.setattr(ros2imu, "SILENT_S", 1.0)
    src = ros2imu.Ros2ImuSource(GyroConfig(ros2=GyroRos2("/imu/data", dds)))
    src.open()
    w = ImuWriter(dds)
    w.matched()
    lead = time.time() - time.monotonic()
    w.write(time.monotonic() + lead, (0.0, 0.0, 0.25))
    _, rate = _read_all(src, 1)
    assert rate.tolist() == [0.25]
    w.w = None  # the driver quits: its writer deleted (an invalid sample comes)
    import gc

    gc.collect()
    time.sleep(0.05)
    assert src.read(time.monotonic()) == []  # (nothing, and no crash)
    time.sleep(1.05)
    with pytest.raises(SourceGone, match="no message for 1 s"):
        src.read(time.monotonic())
    assert not src.health.connected
    src.open()  # the daemon's retry
    w = ImuWriter(dds)
    w.matched()
    w.write(time.monotonic() + lead, (0.0, 0.0, -0.5))
    _, rate = _read_all(src, 1)
    assert rate.tolist() == [-0.5] and src.health.connected


def test_the_daemon_fuses_and_records_an_imu_topic(tmp_path, dds):
    """``mousedom run --record`` on replayed mice and a ROS 2 IMU: SOURCE says the topic and
    its samples, POSE carries the gyro's bias, and the recording holds the rates exactly
    as published (axis and sign applied), so that a replay fuses what the daemon did."""
    from daemon_fixtures import Conn, DaemonProcess
    from test_capture_gyro_replay import simulated, write_capture
    from test_gyro_replay_source import _config_text

    from mousedom.capture import open_capture

    rig, res = simulated()
    mice = tmp_path / "mice.mdcap"
    write_capture(mice, rig, res, gyro=False)
    config = tmp_path / "c.yaml"
    config.write_text(_config_text(mice, f"{{ros2: {{topic: /imu/data, domain_id: {dds}}}, "
                                         "sign: -1}"))  # fmt: skip
    sock = tmp_path / "run" / "d.sock"
    sock.parent.mkdir()
    rec = tmp_path / "rec.mdcap"
    daemon = DaemonProcess(config, sock, "--record", str(rec), env={"CYCLONEDDS_URI": LOOPBACK})
    sent: list[float] = []
    try:
        daemon.wait_socket()
        c = Conn(sock)
        w = ImuWriter(dds)
        w.matched()
        lead = time.time() - time.monotonic()
        stop = threading.Event()

        def drive() -> None:  # a 200 Hz IMU, until the checks are done
            i = 0
            while not stop.is_set() and i < 2000:
                z = 0.05 * math.sin(i / 20.0)
                w.write(time.monotonic() + lead, (0.0, 0.0, z))
                sent.append(-z)
                i += 1
                time.sleep(0.005)

        driver = threading.Thread(target=drive)
        driver.start()
        try:
            source = c.until("SOURCE", lambda m: m["name"] == "gyro" and m["reports"] > 250)
        finally:
            stop.set()
            driver.join()
        assert source["kind"] == "ros2" and source["connected"]
        assert source["topic"] == "/imu/data" and source["domain_id"] == dds
        assert source["frame_id"] == "imu_link" and source.get("stamps_restamped", 0) == 0
        pose = c.until("POSE", lambda m: "gyro" in m and m["gyro"]["bias"] is not None)
        assert math.isfinite(pose["gyro"]["bias"])
    finally:
        assert daemon.stop() == 0, daemon.log()
    cap = open_capture(str(rec))
    dev = cap.devices[-1]
    assert dev.kind == "iio" and dev.name == "/imu/data" and dev.extra["topic"] == "/imu/data"
    got = [r for feed in cap.feeds() for b in feed.batches for r in b.gyro]
    rates = np.concatenate([r.rate for r in got]).tolist()
    # best effort on loopback: all of them, or nearly; each one as sent, in order
    assert len(rates) >= 0.9 * len(sent)
    it = iter(sent)
    assert all(any(r == s for s in it) for r in rates)
    # and `mousedom replay` of the same config fuses the recording with its gyro
    from conftest import run_mousedom

    proc = run_mousedom("replay", "-c", str(config), "--capture", str(rec))
    assert proc.returncode == 0, proc.stderr
    assert f"gyro         {len(rates)} samples" in proc.stdout, proc.stdout


def test_without_the_extra_the_gyro_says_how_to_install_it_and_the_mice_go_on(tmp_path):
    """A machine without cyclonedds: the gyro's source is unavailable with the line that
    says what to install (the daemon retries it; its mice are read meanwhile)."""
    import subprocess
    import sys

    from test_ros2 import _without

    env = _without(tmp_path, "cyclonedds")
    code = (
        "from mousedom.config import GyroConfig, GyroRos2\n"
        "from mousedom.service.ros2imu import Ros2ImuSource\n"
        "from mousedom.sources.base import SourceUnavailable\n"
        "s = Ros2ImuSource(GyroConfig(ros2=GyroRos2('/imu')))\n"
        "try:\n    s.open()\nexcept SourceUnavailable as e:\n    print(e)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "gyro: /imu (" in proc.stdout and "pip install 'mousedom[ros2]'" in proc.stdout


def test_a_topic_nobody_publishes_is_gone_after_first_s_and_not_fused_before(dds):
    """A gyro topic joined but never published (no IMU driver, or one on another domain)
    said `connected` for ever: SILENT_S counts only after a message came.  Until its first
    message the source is not answered (read, not fused: Source.answered), and after
    FIRST_S with none it is gone, saying why; joined again, its first message answers."""
    from mousedom.service import ros2imu
    from mousedom.sources.base import SourceGone

    src = ros2imu.Ros2ImuSource(GyroConfig(ros2=GyroRos2("/imu/data", dds)))
    src.open()
    t0 = time.monotonic()
    assert src.read(t0) == [] and not src.answered
    assert src.read(t0 + ros2imu.FIRST_S - 0.1) == []
    with pytest.raises(SourceGone, match=r"no message in 3 s since it was joined .*domain"):
        src.read(t0 + ros2imu.FIRST_S + 0.1)
    assert not src.health.connected
    src.open()  # the daemon's retry; a driver now publishes
    assert not src.answered
    w = ImuWriter(dds)
    w.matched()
    lead = time.time() - time.monotonic()
    w.write(time.monotonic() + lead, (0.0, 0.0, 0.125))
    _, rate = _read_all(src, 1)
    assert rate.tolist() == [0.125] and src.answered and src.health.connected
    src.close()
