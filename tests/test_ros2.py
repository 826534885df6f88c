"""ROS 2 output (issue 12): DDS to a subscriber made from ROS 2's own message definitions,
MCAP files read back by the mcap library and by rosbags, REP-105, and life without the
extra.

The DDS tests run a real daemon process and a real subscriber process
(tests/ros2_subscriber.py, whose types come from rosbags' typestores for Humble and
Jazzy) on a throw-away domain, over loopback unicast (no multicast needed).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import dds_domain, run_mousedom
from daemon_fixtures import REPO, Conn, DaemonProcess, Feeder, FifoMouse, write_rig_config
from ros2_checks import match_odometry
from rosbags.typesys import Stores, get_typestore

from mousedom.config import Ros2Config, parse_config
from mousedom.fusion import sim
from mousedom.service import ros2conv, ros2msgs
from mousedom.yamldoc import ConfigError

LOOPBACK = (
    '<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery>"
    '<ParticipantIndex>auto</ParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>'
    "</Discovery></Domain></CycloneDDS>"
)


def _yaw(q: dict) -> float:
    return 2.0 * math.atan2(q["z"], q["w"])


# --------------------------------------------------------------------------- definitions


@pytest.mark.parametrize("store", [Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY])
def test_our_field_lists_are_ros2s(store):
    """Every type we publish has exactly ROS 2's fields, in order, of ROS 2's types
    (rosbags' copies of the interface packages of Humble and of Jazzy)."""
    ts = get_typestore(store)

    def describe(node) -> str:
        kind, detail = node
        if kind == 1:
            return detail[0]
        if kind == 2:
            pkg, _, name = detail.split("/")
            return f"{pkg}/{name}"
        inner, size = detail
        return f"{describe(inner)}[{size if kind == 3 else ''}]"

    for name, fields in ros2msgs.FIELDS.items():
        consts, theirs = ts.fielddefs[ros2msgs.ros2_name(name)]
        assert [(describe(node), fname) for fname, node in theirs] == list(fields), name
        # and their constants (the MCAP schema's text carries them: a viewer names levels)
        ours = [(n, c, v) for c, n, v in ros2msgs.CONSTANTS.get(name, ())]
        assert ours == list(consts), name
    assert "byte OK=0\nbyte WARN=1\n" in ros2msgs.msgdef(ros2msgs.DIAGNOSTICS)


def test_our_cdr_is_what_rosbags_reads():
    """Serialised by cyclonedds from our types, deserialised by rosbags from ROS 2's."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    row = _row()
    msg = ros2conv.odometry(Ros2Config(), ros2conv.stamp(12.5, 0.0), (1.0, 2.0, 0.3),
                            row.cov, row, 50.0)  # fmt: skip
    data = ros2msgs.build(ros2msgs.ODOMETRY, msg).serialize()
    back = ts.deserialize_cdr(data, "nav_msgs/msg/Odometry")
    assert back.header.stamp.sec == 12 and back.header.stamp.nanosec == 500_000_000
    assert back.child_frame_id == "base_link" and back.pose.pose.position.y == 2.0
    assert back.twist.twist.angular.z == row.omega
    assert back.pose.covariance[35] == row.cov[2][2]


def _row():
    from mousedom.fusion.posebatch import PoseRow

    cov = [[1.0, 2.0, 3.0], [2.0, 5.0, 6.0], [3.0, 6.0, 9.0]]
    qcov = [[0.1, 0.2, 0.3], [0.2, 0.5, 0.6], [0.3, 0.6, 0.9]]
    return PoseRow(12.5, 1.0, 2.0, 0.3, 0.25, -0.01, 0.5, cov, 3, True, [[0, 0]] * 3,
                   [[1, 2]] * 3, (0, 0, 0), (0, 0, 0), True, qcov)  # fmt: skip


def test_covariances_land_in_rosses_six_by_six():
    """(x, y, yaw) at rows and columns 0, 1, 5 of the row-major 6x6; z, roll and pitch
    unobserved; the twist's is q's times rate squared."""
    row = _row()
    msg = ros2conv.odometry(Ros2Config(), ros2conv.stamp(0.0, 0.0), (0.0, 0.0, 0.0),
                            row.cov, row, 10.0)  # fmt: skip
    c = np.array(msg["pose"]["covariance"]).reshape(6, 6)
    assert c[np.ix_([0, 1, 5], [0, 1, 5])].tolist() == row.cov
    assert [c[2, 2], c[3, 3], c[4, 4]] == [ros2conv.UNOBSERVED] * 3
    assert c[0, 2] == c[2, 5] == 0.0
    t = np.array(msg["twist"]["covariance"]).reshape(6, 6)
    np.testing.assert_allclose(t[np.ix_([0, 1, 5], [0, 1, 5])], np.array(row.qcov) * 100.0)


@pytest.mark.parametrize("seed", range(20))
def test_the_six_by_six_is_symmetric_and_nan_is_no_correlation(seed):
    """The estimator's inverse and the map -> odom turn leave a 3x3 a rounding from
    symmetric (4.6e-23 against 0 was seen); ROS gets one symmetric matrix, the mean of the
    two cells, and an unknown (NaN) correlation as 0, not as UNOBSERVED (which made the
    6x6 indefinite), an unknown variance as UNOBSERVED."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, 3))
    c = a @ a.T
    c[0, 2] += 1e-17 * rng.normal()  # a rounding's asymmetry
    if seed % 3 == 0:
        c[1, 2] = c[2, 1] = np.nan
    if seed % 4 == 0:
        c[2, 2] = np.nan
    six = np.array(ros2conv.covariance6(c.tolist(), float(rng.uniform(-3, 3)))).reshape(6, 6)
    assert (six == six.T).all()
    assert np.isfinite(six).all()
    if seed % 3 == 0 and seed % 4 != 0:
        assert six[1, 5] == 0.0 and six[5, 1] == 0.0
        assert np.linalg.eigvalsh(six).min() > -1e-9
    if seed % 4 == 0:
        assert six[5, 5] == ros2conv.UNOBSERVED


def test_mouse_frames_take_the_base_frames_prefix():
    """Two robots sharing /tf (docs/ros2.md, "Several robots"): the mice's frames carry
    the base frame's prefix, as the mounts' transforms and the counts' headers say."""
    st = ros2conv.stamp(1.0, 0.0)
    for base, want in (("base_link", "front_l_mouse"), ("robot1/base_link", "robot1/front_l_mouse"),
                       ("a/b/base", "a/b/front_l_mouse")):  # fmt: skip
        assert ros2conv.mouse_frame("front-l", base) == want
        tr = ros2conv.mount_transform(base, "front-l", 0.1, 0.0, 0.0, False, st)
        assert tr["header"]["frame_id"] == base and tr["child_frame_id"] == want
        assert ros2conv.counts(st, "front-l", 1, 2, base)["header"]["frame_id"] == want


def test_a_mouse_whose_counts_topic_is_too_long_for_ros2_is_named():
    """outputs.ros2.counts: each mouse's topic <namespace>/mousedom/<token>/counts within
    ROS 2's 247 characters, the mouse named at its line; without counts no limit."""
    name = "m" * 240
    text = (f"mice:\n  {name}: {{cpi: 400, mount: {{x: 0, y: 0}}}}\n"
            "  b: {cpi: 400, mount: {x: 1, y: 0}}\noutputs: {ros2: {counts: %s}}\n")  # fmt: skip
    assert parse_config(text % "false", need_sources=False).ros2.counts is False
    with pytest.raises(ConfigError) as e:
        parse_config(text % "true", "<t>", need_sources=False)
    assert f"mice.{name}" in str(e.value) and "over ROS 2's 247" in str(e.value)


def test_a_ros2_gyro_is_on_the_outputs_domain_and_namespace_unless_told():
    """docs/gyro.md: a gyro read from ROS 2 takes the output's domain unless it names its
    own, and its reader's node the output's namespace."""
    base = ("mice:\n  a: {cpi: 400, mount: {x: 0, y: 0}}\n  b: {cpi: 400, mount: {x: 1, y: 0}}\n"
            "gyro: {ros2: %s}\n")  # fmt: skip
    out = "outputs: {ros2: {domain_id: 23, namespace: /robot1}}\n"
    g = parse_config(base % "/imu/data" + out, need_sources=False).gyro.ros2
    assert (g.domain(), g.namespace) == (23, "/robot1")
    g = parse_config(base % "{topic: /imu/data, domain_id: 4}" + out, need_sources=False).gyro.ros2
    assert (g.domain(), g.namespace) == (4, "/robot1")
    g = parse_config(base % "/imu/data", need_sources=False).gyro.ros2
    assert (g.domain(), g.namespace) == (None, "")


def test_a_reload_that_edits_only_the_ros2_output_keeps_a_ros2_gyro_and_the_learning():
    """The output keeps its domain and namespace until a restart: a SIGHUP that edits only
    them must neither reopen the gyro (it would read on another domain than the output
    publishes on) nor begin the fusion's learning again."""
    from mousedom.fusion.tracker import fusion_terms
    from mousedom.service.factory import source_key

    base = ("mice:\n  a: {cpi: 400, mount: {x: 0, y: 0}}\n  b: {cpi: 400, mount: {x: 1, y: 0}}\n"
            "gyro: {ros2: /imu/data}\n"
            "outputs: {ros2: {domain_id: %d, namespace: %s}}\n")  # fmt: skip
    one = parse_config(base % (23, "/robot1"), need_sources=False)
    two = parse_config(base % (24, "/robot2"), need_sources=False)
    assert one.gyro.ros2.domain() == 23 and two.gyro.ros2.domain() == 24
    assert source_key(one.gyro) == source_key(two.gyro)
    assert fusion_terms(one) == fusion_terms(two)
    own = parse_config((base % (23, "/robot1")).replace("{ros2: /imu/data}",
                       "{ros2: {topic: /imu/data, domain_id: 5}}"), need_sources=False)  # fmt: skip
    assert source_key(own.gyro) != source_key(one.gyro)  # the gyro's own domain: reopened


def test_rep105_odom_never_jumps_and_map_odom_takes_the_fix():
    rep = ros2conv.Rep105()
    p = (1.0, 0.5, 0.4)
    assert rep.odom_pose(p) == p
    rep.moved(p, (3.0, -1.0, 1.2))  # a fix moved the daemon's pose
    after = (3.0, -1.0, 1.2)
    np.testing.assert_allclose(rep.odom_pose(after), p, atol=1e-12)  # odom did not move
    step = (0.1, 0.02, 0.05)  # a body-frame step taken by both frames
    np.testing.assert_allclose(rep.odom_pose(ros2conv.compose(after, step)),
                               ros2conv.compose(p, step), atol=1e-12)  # fmt: skip
    np.testing.assert_allclose(ros2conv.compose(rep.map_odom, rep.odom_pose(after)), after,
                               atol=1e-12)  # fmt: skip


def test_outputs_ros2_config():
    base = "mice:\n  a: {cpi: 400, mount: {x: 0, y: 0}}\n  b: {cpi: 400, mount: {x: 1, y: 0}}\n"
    assert parse_config(base, need_sources=False).ros2 is None
    cfg = parse_config(base + "outputs: {ros2: true}\n", need_sources=False)
    assert cfg.ros2 == Ros2Config()
    cfg = parse_config(base + "outputs:\n  ros2: {namespace: /robot1, domain_id: 7, "
                       "publish_tf: false, stamps: monotonic}\n", need_sources=False)  # fmt: skip
    assert cfg.ros2.namespace == "/robot1" and cfg.ros2.domain_id == 7
    assert ros2conv.topic(cfg.ros2, cfg.ros2.odom_topic) == "/robot1/odom"
    off = parse_config(base + "outputs: {ros2: {enabled: false}}\n", need_sources=False)
    assert off.ros2 is None
    for bad, says in (
        ("{domain_id: 300}", "domain_id: must be between 0 and 232"),
        ("{namespace: robot1}", "namespace: must be /name or /a/b"),
        # ROS 2's rule (rcl): each name starts with a letter or _, letters, digits and _
        ("{namespace: /2robot}", "namespace: must be /name or /a/b"),
        ("{namespace: /robot~1}", "namespace: must be /name or /a/b"),
        ("{node_name: 2mice}", "node_name: must be a ROS 2 node name"),
        ("{node_name: mouse-dom}", "node_name: must be a ROS 2 node name"),
        ("{odom_topic: 'od om'}", "odom_topic: must be a ROS 2 topic name"),
        # what rcl would expand (~, {}) or refuse, and names beyond rmw's lengths
        ("{odom_topic: '~/odom'}", "odom_topic: must be a ROS 2 topic name"),
        ("{odom_topic: /odom/}", "odom_topic: must be a ROS 2 topic name"),
        ("{odom_topic: /odom/2d}", "odom_topic: must be a ROS 2 topic name"),
        ("{tf_topic: /tföö}", "tf_topic: must be a ROS 2 topic name"),
        ("{diagnostics_topic: '/{node}/d'}", "diagnostics_topic: must be a ROS 2 topic name"),
        ("{odom_topic: /" + "o" * 247 + "}", "over ROS 2's 247"),
        ("{namespace: /" + "n" * 245 + "}", "namespace: must be at most 245 characters"),
        # the topics it puts under any namespace: /tf_static, /initialpose
        ("{namespace: /" + "n" * 237 + "}", "/tf_static under it would be over"),
        ("{namespace: /" + "n" * 235 + "}", "/initialpose under it would be over"),
        # tf2 refuses a frame id with a leading /
        ("{odom_frame: /odom}", "odom_frame: must be a frame id"),
        ("{base_frame: /robot1/base_link}", "tf2 refuses a leading /"),
        ("{map_frame: 'map/'}", "map_frame: must be a frame id"),
        ("{stamps: wall}", "stamps: must be one of system, monotonic"),
        ("{odom_frme: x}", "unknown key (did you mean odom_frame?"),
    ):
        with pytest.raises(ConfigError) as e:
            parse_config(base + f"outputs: {{ros2: {bad}}}\n", "<t>", need_sources=False)
        assert "outputs.ros2." in str(e.value) and says in str(e.value), str(e.value)


# --------------------------------------------------------------------------- DDS


class Subscriber:
    """tests/ros2_subscriber.py as a process: its JSON lines, collected by a thread."""

    def __init__(self, distro: str, domain: int, env: dict, *topics: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, str(REPO / "tests" / "ros2_subscriber.py"), distro, str(domain),
             *topics],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
            text=True,
        )  # fmt: skip
        assert self.proc.stdout.readline().strip() == "ready", self.proc.stderr.read()
        self.messages: list[dict] = []
        self.thread = threading.Thread(target=self._collect, daemon=True)
        self.thread.start()

    def _collect(self) -> None:
        for line in self.proc.stdout:
            self.messages.append(json.loads(line))

    def of(self, topic: str) -> list[dict]:
        return [m["msg"] for m in list(self.messages) if m["topic"] == topic]

    def wait_for(self, topic: str, n: int, timeout: float = 10.0) -> list[dict]:
        deadline = time.monotonic() + timeout
        while len(self.of(topic)) < n and time.monotonic() < deadline:
            time.sleep(0.05)
        return self.of(topic)

    def stop(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(5)


@pytest.fixture
def dds_env(tmp_path):
    env = dict(os.environ)
    env["CYCLONEDDS_URI"] = LOOPBACK
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("ROS_DOMAIN_ID", None)
    return env, dds_domain()


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_odometry_and_tf_reach_a_ros2_subscriber(tmp_path, dds_env, distro):
    """A three-mouse FIFO rig; the daemon's /odom and /tf against its socket's POSE, window
    by window (monotonic stamps, so that a POSE and its Odometry share a time); then a
    ``fix`` that moves the POSE but not /odom, only map -> odom (REP-105)."""
    env, domain = dds_env
    rig = sim.three_mouse_rig()
    fifos = {m.name: tmp_path / f"{m.name}.fifo" for m in rig.mice}
    mice = {n: FifoMouse(p) for n, p in fifos.items()}
    extra = (f"outputs:\n  ros2: {{domain_id: {domain}, stamps: monotonic, "
             "publish_map_tf: true}\n")  # fmt: skip
    config = write_rig_config(tmp_path / "rig.yaml", rig, fifos, extra, rate_hz=50.0)
    sub = Subscriber(distro, domain, env, "/odom=nav_msgs/msg/Odometry",
                     "/tf=tf2_msgs/msg/TFMessage", "/tf_static=tf2_msgs/msg/TFMessage",
                     "/diagnostics=diagnostic_msgs/msg/DiagnosticArray")  # fmt: skip
    daemon = DaemonProcess(config, tmp_path / "run" / "mousedom.sock", env=env)
    feeder = None
    try:
        daemon.wait_socket()
        for m in mice.values():
            m.attach()
        traj = sim.sequence(sim.straight(0.6, 0.2), sim.arc(0.5, 1.0, 0.2))
        result = sim.simulate(rig, traj, seed=3)
        feeder = Feeder(mice, result.reports, time.monotonic() + 0.1)
        feeder.start()
        c = Conn(daemon.socket_path)
        poses = [m for m in (c.read() for _ in range(400)) if m["class"] == "POSE"]
        odoms = sub.wait_for("/odom", 100)
        matched = match_odometry(poses, odoms)
        assert len(matched) > 50
        moving = [o for p, o in matched if abs(p["vx"]) > 0.1]
        assert moving and all(o["twist"]["covariance"][0] > 0 for o in moving)
        tfs = sub.wait_for("/tf", 50)
        frames = {(t["header"]["frame_id"], t["child_frame_id"]) for m in tfs
                  for t in m["transforms"]}  # fmt: skip
        assert frames == {("odom", "base_link"), ("map", "odom")}

        # REP-105: a fix moves map -> odom, not odom
        last_odom = sub.of("/odom")[-1]["pose"]["pose"]["position"]["x"]
        c.send({"cmd": "fix", "x": 5.0})
        ok = c.until("OK")
        assert ok["pose"]["x"] == 5.0
        after = c.until("POSE")
        time.sleep(0.3)
        later = [o for o in sub.of("/odom") if o["header"]["stamp"]["sec"]
                 + o["header"]["stamp"]["nanosec"] * 1e-9 >= after["t"] - 1e-6]  # fmt: skip
        assert later and abs(later[0]["pose"]["pose"]["position"]["x"] - last_odom) < 0.05
        map_odom = [t for m in sub.of("/tf") for t in m["transforms"]
                    if t["header"]["frame_id"] == "map"][-1]["transform"]  # fmt: skip
        x_odom = later[-1]["pose"]["pose"]["position"]["x"]
        assert map_odom["translation"]["x"] == pytest.approx(5.0 - last_odom, abs=0.05)
        assert x_odom < 2.0  # odom still near where the robot drove, not at 5 m
        # Each mouse's mount on /tf_static: base_link -> <mouse>_mouse, yaw as configured.
        (static,) = sub.wait_for("/tf_static", 1)
        mounts = {t["child_frame_id"]: t for t in static["transforms"]}
        assert set(mounts) == {f"{m.name}_mouse" for m in rig.mice}
        for m in rig.mice:
            tr = mounts[f"{m.name}_mouse"]
            assert tr["header"]["frame_id"] == "base_link"
            got = tr["transform"]["translation"]
            assert (got["x"], got["y"]) == pytest.approx((m.x, m.y), abs=1e-9)
            assert _yaw(tr["transform"]["rotation"]) == pytest.approx(math.radians(m.yaw), abs=1e-9)
        diags = sub.wait_for("/diagnostics", 1)
        names = {s["name"] for s in diags[-1]["status"]}
        assert names == {"mousedom: front", "mousedom: left", "mousedom: right"}
        assert all(s["level"] == 0 for s in diags[-1]["status"])
        c.close()
    finally:
        if feeder is not None:
            feeder.stop()
        daemon.stop()
        sub.stop()


def test_run_demo_ros2_uses_ros_domain_id(tmp_path, dds_env):
    """`mousedom run --demo --ros2`, ROS_DOMAIN_ID from the environment: /odom arrives."""
    env, domain = dds_env
    env = {**env, "ROS_DOMAIN_ID": str(domain)}
    sub = Subscriber("jazzy", domain, env, "/odom=nav_msgs/msg/Odometry")
    daemon = DaemonProcess(Path("unused"), tmp_path / "run" / "m.sock", "--demo", "--ros2",
                           env=env, config_args=False)  # fmt: skip
    try:
        daemon.wait_socket()
        odoms = sub.wait_for("/odom", 20)
        assert len(odoms) >= 20
        stamp = odoms[-1]["header"]["stamp"]["sec"]
        assert abs(stamp - time.time()) < 60  # system clock stamps by default (ROS time)
    finally:
        daemon.stop()
        sub.stop()
    assert f"ROS 2 output on domain {domain}" in daemon.log()


# --------------------------------------------------------------------------- MCAP


def test_replay_mcap_reads_back_with_mcap_and_rosbags(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    from mousedom.capture.replay import read_csv
    from mousedom.demo import DEMO_CONFIG

    out = tmp_path / "demo.mcap"
    proc = run_mousedom("replay", "--config", str(DEMO_CONFIG), "-o", "-", "--mcap", str(out))
    assert proc.returncode == 0, proc.stderr
    rows = read_csv(proc.stdout)
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        kinds = {c.topic: (summary.schemas[c.schema_id].name,
                           summary.schemas[c.schema_id].encoding, c.message_encoding)
                 for c in summary.channels.values()}  # fmt: skip
        odom = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/odom"])]
    assert kinds["/odom"] == ("nav_msgs/msg/Odometry", "ros2msg", "cdr")
    assert kinds["/tf"][0] == "tf2_msgs/msg/TFMessage"
    assert kinds["/mousedom/front/counts"][0] == "geometry_msgs/msg/Vector3Stamped"
    assert len(odom) == len(rows["t"])
    x = np.array([m.pose.pose.position.x for m in odom])
    yaw = np.array([2 * math.atan2(m.pose.pose.orientation.z, m.pose.pose.orientation.w)
                    for m in odom])  # fmt: skip
    np.testing.assert_allclose(x, rows["x"], atol=1e-9)
    np.testing.assert_allclose(np.unwrap(yaw), rows["theta"], atol=1e-6)
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in odom])
    np.testing.assert_allclose(stamps, rows["t"], atol=1e-6)
    with AnyReader([out]) as bag:
        conns = {c.topic: c for c in bag.connections}
        got = [
            bag.deserialize(raw, c.msgtype)
            for c, _, raw in bag.messages(connections=[conns["/mousedom/left/counts"]])
        ]
        tf = [bag.deserialize(raw, c.msgtype)
              for c, _, raw in bag.messages(connections=[conns["/tf"]])]  # fmt: skip
    assert len(got) == len(rows["t"]) and got[0].header.frame_id == "left_mouse"
    assert tf[-1].transforms[0].transform.translation.x == pytest.approx(rows["x"][-1], abs=1e-9)
    # every count of the capture is in the recording (the demo's left mouse)
    total = sum(m.vector.y for m in got)
    assert total == pytest.approx(_net_counts("left")[1], abs=1e-6)


def _net_counts(name: str):
    """What the engine counted for a mouse of the demo, in process."""
    from mousedom.capture import assign
    from mousedom.capture.replay import Replay
    from mousedom.config import load_config
    from mousedom.demo import DEMO_CONFIG

    config = load_config(DEMO_CONFIG, need_sources=False)
    batches = []
    Replay(config, assign(config, [])).run(batches.append)
    i = config.names.index(name)
    return sum(b.counts[:, i].sum(axis=0) for b in batches)


def _demo_recording_mcap(tmp_path: Path) -> tuple[DaemonProcess, Path, Conn]:
    """`run --demo --record-mcap`, listening, and a client on its socket."""
    out = tmp_path / "run.mcap"
    daemon = DaemonProcess(Path("unused"), tmp_path / "run" / "m.sock", "--demo",
                           "--record-mcap", str(out), config_args=False)  # fmt: skip
    try:
        daemon.wait_socket()
        return daemon, out, Conn(daemon.socket_path)
    except BaseException:
        daemon.stop()
        raise


def test_run_record_mcap_writes_what_the_socket_saw(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    daemon, out, c = _demo_recording_mcap(tmp_path)
    try:
        poses = [m for m in (c.read() for _ in range(200)) if m["class"] == "POSE"]
        time.sleep(1.2)  # a SOURCE round: /diagnostics
    finally:
        assert daemon.stop() == 0
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        odom = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/odom"])]
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        diags = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/diagnostics"])]
    assert len(odom) >= len(poses) > 50 and diags
    xs = {round(m.pose.pose.position.x, 9) for m in odom}
    assert all(round(p["x"], 9) in xs for p in poses[-20:])


def test_a_killed_daemon_s_mcap_keeps_all_but_its_last_seconds(tmp_path):
    """`run --record-mcap` killed (SIGKILL, a power cut) lost its last 1 MiB chunk: about
    12 s of the demo, or the whole file (0 bytes after 6 s).  A live recording's chunks
    hold about a second and reach the file at the daemon's checkpoint: a streaming reader
    (Foxglove's, `mcap recover`) reads every window published 2.5 s before the kill."""
    import signal

    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    daemon, out, c = _demo_recording_mcap(tmp_path)
    try:
        seen = [m for m in (c.read() for _ in range(400)) if m["class"] == "POSE"]
        time.sleep(2.5)
        daemon.signal(signal.SIGKILL)
        daemon.proc.wait(5)
    finally:
        daemon.stop()
    odom, topics = set(), {}
    with open(out, "rb") as f:
        try:
            for rec in StreamReader(f, emit_chunks=False).records:
                if isinstance(rec, Channel):
                    topics[rec.id] = rec.topic
                if isinstance(rec, Message) and topics[rec.channel_id] == "/odom":
                    odom.add(rec.log_time)
        except Exception:  # the unfinished end of a killed file
            pass
    assert len(seen) > 100 and len(odom) >= len(seen), (len(odom), len(seen))


# --------------------------------------------------------------------------- without the extra


def _without(tmp_path: Path, *modules: str) -> dict:
    """An environment in which importing ``modules`` fails, as on a machine without them."""
    shim = tmp_path / "shim"
    for mod in modules:
        (shim / mod).mkdir(parents=True)
        (shim / mod / "__init__.py").write_text(f"raise ImportError('no module named {mod}')\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(shim), str(REPO), env.get("PYTHONPATH", "")])
    return env


def test_without_the_extra_the_daemon_runs_and_ros2_says_how_to_install(tmp_path):
    env = _without(tmp_path, "cyclonedds", "mcap", "mcap_ros2")
    proc = subprocess.run([sys.executable, "-m", "mousedom", "run", "--demo", "--ros2",
                           "--socket", str(tmp_path / "a.sock")], env=env, capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert proc.returncode != 0
    assert "pip install 'mousedom[ros2]'" in proc.stderr and "Traceback" not in proc.stderr
    proc = run_mousedom("replay", "--config", str(REPO / "mousedom" / "data" / "demo-rig.yaml"),
                        "--mcap", str(tmp_path / "x.mcap"), env=env)  # fmt: skip
    assert proc.returncode != 0 and "mousedom[ros2]" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "x.mcap").exists()
    # and without --ros2 the daemon runs as before, the DDS library never imported
    daemon = DaemonProcess(Path("unused"), tmp_path / "run" / "m.sock", "--demo", env=env,
                           config_args=False)  # fmt: skip
    try:
        daemon.wait_socket()
        c = Conn(daemon.socket_path)
        assert c.until("POSE")["updating"] in (True, False)
    finally:
        assert daemon.stop() == 0


def test_packed_cdr_is_byte_for_byte_cyclonedds():
    """ros2cdr packs the per-window messages with struct; the generic path (our types,
    cyclonedds' serializer) must give the same bytes, frame names of every length (the
    padding) included."""
    from mousedom.service import ros2cdr

    st = ros2conv.stamp(1234.000000123, 0.0)
    for frame, child in (("odom", "base_link"), ("o", "b"), ("robot1/odom", "robot1/base_lnk")):
        cfg = Ros2Config(odom_frame=frame, base_frame=child)
        msg = ros2conv.odometry(cfg, st, (0.1, -0.2, 2.9), ros2conv.turned(_row().cov, 0.4),
                               _row(), 100.0)  # fmt: skip
        want = ros2msgs.build(ros2msgs.ODOMETRY, msg).serialize()
        assert ros2cdr.OdometryCdr(frame, child).encode(st, msg) == want
        pairs = [(frame, child), ("map", frame)]
        tfs = [ros2conv.transform(p, c, st, (0.5, 0.25, -1.0)) for p, c in pairs]
        want = ros2msgs.build(ros2msgs.TF, {"transforms": tfs}).serialize()
        assert ros2cdr.TfCdr(pairs).encode(st, tfs) == want
        v = ros2conv.counts(st, child, 3, -7)
        enc = ros2cdr.Vector3StampedCdr(ros2conv.mouse_frame(child))
        assert enc.encode(st, v) == ros2msgs.build(ros2msgs.COUNTS, v).serialize()
    sources = [
        {"name": "front", "connected": True, "live": True, "state": "tracking",
         "rate_hz": 125.0, "residual": 1e-5, "kind": "evdev", "node": "/dev/input/event3"},
        {"name": "flow", "connected": True, "live": True, "state": "excluded",
         "reason": "low quality", "rate_hz": 66.0, "residual": None, "kind": "adns",
         "squal": 9},
        {"name": "gone", "connected": False, "error": "unplugged"},
    ]  # fmt: skip
    for subset in (sources, sources[:1], sources[1:], []):
        msg = ros2conv.diagnostics(st, subset)
        want = ros2msgs.build(ros2msgs.DIAGNOSTICS, msg).serialize()
        assert ros2cdr.diagnostics(st, msg) == want
    levels = [s["level"] for s in ros2conv.diagnostics(st, sources)["status"]]
    assert levels == [ros2conv.OK, ros2conv.ERROR, ros2conv.ERROR]


def test_diagnostics_carry_the_learnt_scale_and_warn_of_a_wrong_cpi():
    """Issue 31 item 3: each status's values hold the learnt scale and its spread (empty
    where none is learnt); a mouse 10 % or more off the others is WARN with the warning as
    its message, a mouse already worse keeps its level and adds the warning; what rosbags
    reads back (ROS 2's own definitions) is what was built."""
    from mousedom.service import ros2cdr

    warning = ("mouse left reads 12 % more than the others: check its cpi (learnt scale "
               "0.893 +- 0.004)")  # fmt: skip
    base = {"connected": True, "live": True, "state": "tracking", "rate_hz": 125.0,
            "residual": 1e-5, "kind": "evdev"}  # fmt: skip
    sources = [
        {**base, "name": "front", "scale": 1.0012, "scale_spread": 0.0004,
         "scale_applied": False, "scale_warning": None},
        {**base, "name": "left", "scale": 0.893, "scale_spread": 0.004,
         "scale_applied": True, "scale_warning": warning},
        {**base, "name": "right", "state": "excluded", "reason": "inconsistent",
         "scale": 1.15, "scale_spread": 0.01, "scale_applied": True,
         "scale_warning": warning.replace("left", "right")},
        {**base, "name": "two-mouse rig", "scale": None, "scale_spread": None},
        {**base, "name": "old daemon"},  # a SOURCE without the keys
    ]  # fmt: skip
    st = ros2conv.stamp(5.0, 0.0)
    msg = ros2conv.diagnostics(st, sources)
    status = {s["name"].removeprefix("mousedom: "): s for s in msg["status"]}
    values = {n: {kv["key"]: kv["value"] for kv in s["values"]} for n, s in status.items()}
    assert values["front"]["scale"] == "1.001200" and values["front"]["scale_spread"] == "0.000400"
    assert values["left"]["scale"] == "0.893000" and values["left"]["scale_applied"] == "true"
    assert values["two-mouse rig"]["scale"] == values["two-mouse rig"]["scale_spread"] == ""
    assert values["old daemon"]["scale"] == ""
    assert status["front"]["level"] == ros2conv.OK and status["front"]["message"] == "tracking"
    assert status["left"]["level"] == ros2conv.WARN and status["left"]["message"] == warning
    assert status["right"]["level"] == ros2conv.ERROR
    assert status["right"]["message"].startswith("excluded (inconsistent); mouse right reads")
    raw = ros2cdr.diagnostics(st, msg)
    assert raw == ros2msgs.build(ros2msgs.DIAGNOSTICS, msg).serialize()
    ts = get_typestore(Stores.ROS2_HUMBLE)
    back = ts.deserialize_cdr(raw, "diagnostic_msgs/msg/DiagnosticArray")
    assert [(s.level, s.message) for s in back.status][:2] == [
        (ros2conv.OK, "tracking"),
        (ros2conv.WARN, warning),
    ]
    assert {kv.key: kv.value for kv in back.status[1].values}["scale_spread"] == "0.004000"


def test_an_unsolved_window_and_diff_drive_sideways_are_not_claimed_certain():
    row = _row()._replace(ok=False, vx=0.0, vy=0.0, omega=0.0)
    msg = ros2conv.odometry(Ros2Config(), ros2conv.stamp(0.0, 0.0), (0.0, 0.0, 0.0),
                            row.cov, row, 10.0)  # fmt: skip
    t = np.array(msg["twist"]["covariance"]).reshape(6, 6)
    assert [t[0, 0], t[1, 1], t[5, 5]] == [ros2conv.UNOBSERVED] * 3
    diff = _row()._replace(qcov=[[0.1, 0.0, 0.3], [0.0, 0.0, 0.0], [0.3, 0.0, 0.9]])
    msg = ros2conv.odometry(Ros2Config(), ros2conv.stamp(0.0, 0.0), (0.0, 0.0, 0.0),
                            diff.cov, diff, 10.0)  # fmt: skip
    t = np.array(msg["twist"]["covariance"]).reshape(6, 6)
    assert t[1, 1] == t[0, 0] == pytest.approx(10.0) and t[0, 1] == 0.0


@pytest.mark.parametrize("store", [Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY])
def test_type_hashes_are_rep2011s(store):
    """The RIHS01 hashes we announce are the ones computed from ROS 2's definitions."""
    ts = get_typestore(store)
    for name, value in ros2msgs.TYPE_HASHES.items():
        assert ts.hash_rihs01(ros2msgs.ros2_name(name)) == value, name
    assert set(ros2msgs.TYPE_HASHES) == {ros2msgs.ODOMETRY, ros2msgs.TF, ros2msgs.DIAGNOSTICS,
                                         ros2msgs.COUNTS}  # fmt: skip


def test_writers_announce_their_type_hash(tmp_path, dds_env, monkeypatch):
    """What `ros2 topic info -v` reads: the writer's USER_DATA, seen through discovery."""
    from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
    from cyclonedds.domain import DomainParticipant

    from mousedom.service.ros2out import Ros2Output

    env, domain = dds_env
    monkeypatch.setenv("CYCLONEDDS_URI", env["CYCLONEDDS_URI"])
    out = Ros2Output(Ros2Config(domain_id=domain), ("a", "b"), 100.0)
    try:
        dp = DomainParticipant(domain)
        reader = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
        found = {}
        deadline = time.monotonic() + 10
        while len(found) < 3 and time.monotonic() < deadline:
            for s in reader.take(N=50):
                if s.topic_name.startswith("rt/"):
                    found[s.topic_name] = (s.type_name, s.qos)
            time.sleep(0.05)
        assert set(found) == {"rt/odom", "rt/tf", "rt/diagnostics"}
        name, qos = found["rt/odom"]
        assert name == "nav_msgs::msg::dds_::Odometry_"
        userdata = next(p for p in qos if type(p).__name__ == "Userdata").data
        assert userdata == f"typehash={ros2msgs.TYPE_HASHES[ros2msgs.ODOMETRY]};".encode()
    finally:
        out.close()


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5, math.pi])
@pytest.mark.parametrize("flip", [False, True])
def test_a_mounts_static_transform_turns_the_mouse_axes_as_configured(yaw, flip):
    """base -> <mouse>_mouse: the mouse's x (toward its buttons) is the body direction at
    its yaw; its y is to the left of that, or to the right for a mirrored sensor (a half
    turn about its x axis: upside down)."""
    tr = ros2conv.mount_transform(
        "base_link", "front", 0.1, -0.2, yaw, flip, ros2conv.stamp(1.0, 0)
    )
    q = tr["transform"]["rotation"]
    w, x, y, z = q["w"], q["x"], q["y"], q["z"]
    assert w * w + x * x + y * y + z * z == pytest.approx(1.0)
    rot = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    np.testing.assert_allclose(rot @ [1, 0, 0], fwd, atol=1e-12)
    np.testing.assert_allclose(rot @ [0, 1, 0], -left if flip else left, atol=1e-12)
    assert tr["child_frame_id"] == "front_mouse" and tr["header"]["frame_id"] == "base_link"


def _odom_covs(result, reset_at: float | None, to: tuple[float, float, float]):
    """The odom covariances Rep105 gives for a live run of ``result`` (one window at a
    time, as the daemon), the pose reset to ``to`` once the frontier passes ``reset_at``."""
    from mousedom.fusion.tracker import Tracker

    tracker = Tracker(sim.rig_config(result.rig), t0=float(result.motion.starts[0]))
    rep = ros2conv.Rep105()
    out: dict[float, np.ndarray] = {}

    def publish(batch) -> None:
        for row in batch.rows():
            odom = rep.odom_pose((row.x, row.y, row.theta))
            out[round(row.t, 6)] = np.array(rep.odom_cov(row.cov, odom))

    def poll(tr):
        nonlocal reset_at
        publish(tr.poll(one_by_one=True))
        if reset_at is not None and tr.frontier_time >= reset_at:
            before = tr.pose
            tr.reset(*to)
            rep.moved(before, tr.pose)
            reset_at = None
        return None

    for b in sim.run_tracker_live(result, tracker, poll)[-1:]:
        publish(b)
    return out


@pytest.mark.parametrize("seed", range(4))
def test_the_odom_covariance_goes_on_through_a_reset(seed):
    """REP-105: /odom is the same estimate before and after a reset or fix (only map ->
    odom moves), so its covariance must not collapse with the daemon's (it fell from
    1.9e-7 to 6.7e-10 m^2: a filter fusing /odom would trust it without limit).  The odom
    covariance of a run reset half way equals that of the same run never reset, to
    rounding, on random drives and random reset poses."""
    rng = np.random.default_rng(seed)
    rig = sim.three_mouse_rig()
    from mousedom.fusion.drives import drive

    result = sim.simulate(rig, sim.sequence(sim.pause(0.3), drive(4.0, seed=seed)), seed=seed)
    to = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)), float(rng.uniform(-3, 3)))
    plain = _odom_covs(result, None, to)
    reset = _odom_covs(result, 2.0, to)
    later = [t for t in plain if t > 2.2]
    assert later and set(later) <= set(reset)
    for t in later:
        np.testing.assert_allclose(reset[t], plain[t], rtol=1e-6, atol=1e-18)
    assert np.trace(reset[later[-1]][:2, :2]) > 1e-9  # (it grew: the test holds something)


def test_odometry_takes_an_angle_for_the_rows_covariance_turned_as_before():
    """odometry's fourth argument: the odom frame's covariance (Rep105.odom_cov), or, as
    it was before the odom covariance was carried, the angle that turns the row's."""
    row, st = _row(), ros2conv.stamp(3.0, 0.0)
    for angle in (0.0, 0.4, -2.9):
        by_angle = ros2conv.odometry(Ros2Config(), st, (0.1, 0.2, 0.3), angle, row, 50.0)
        by_cov = ros2conv.odometry(Ros2Config(), st, (0.1, 0.2, 0.3),
                                   ros2conv.turned(row.cov, angle), row, 50.0)  # fmt: skip
        assert by_angle == by_cov


def test_per_mouse_channels_pause_while_the_mice_are_not_the_start_ups(tmp_path):
    """A reload that adds, removes or reorders mice: a row's counts follow the new mice,
    an output's counts channels were made for the start-up ones.  Filled anyway, the
    counts went out under another mouse's name (a reorder) or a removed mouse read 0 with
    no state (Foxglove's schema refused it); they pause now until the mice are those again
    (the pose goes on), said once in the log.  MCAP's channels, read back by mcap."""
    from mcap.reader import make_reader

    from mousedom.service.mcapout import McapRecorder

    path = tmp_path / "o.mcap"
    out = McapRecorder(str(path), Ros2Config(), ("a", "b"), 100.0)
    row = _row()._replace(counts=[[1, 2], [3, 4]])
    out.publish(row._replace(t=1.0))
    out.mice_changed(("b", "a"))  # reordered: b's counts would go out as a's
    out.publish(row._replace(t=2.0))
    out.mice_changed(("a",))
    out.publish(row._replace(t=3.0, counts=[[1, 2]]))
    out.mice_changed(("a", "b"))  # the start-up mice again
    out.publish(row._replace(t=4.0))
    out.close()
    with open(path, "rb") as f:
        msgs = [(ch.topic, m.log_time) for _, ch, m in make_reader(f).iter_messages()]
    counts = sorted({t // 1_000_000_000 for topic, t in msgs if topic.endswith("/counts")})
    odom = sorted({t // 1_000_000_000 for topic, t in msgs if topic == "/odom"})
    assert counts == [1, 4] and odom == [1, 2, 3, 4]
