"""The live view without ROS (issue 25): the daemon serves Foxglove's WebSocket protocol
(foxglove-sdk); a WebSocket client here subscribes to every channel the server advertises,
decodes each message with the schema the server itself sends (protobuf for Foxglove's
schemas, JSON for ours), and checks the pose against the socket's POSE window by window."""

from __future__ import annotations

import base64
import contextlib
import json
import math
import os
import re
import struct
import subprocess
import sys
import threading
import time

import pytest
from conftest import REPO, mousedom_env
from daemon_fixtures import Conn, wait_listening

try:
    import foxglove  # noqa: F401
    import websockets.sync.client as websockets_sync
except ImportError as e:  # the README's test command installs both; CI must not skip
    if os.environ.get("CI"):
        raise
    pytest.skip(f"{e.name} is not installed: pip install '.[test,foxglove]'",
                allow_module_level=True)  # fmt: skip

DEMO = REPO / "mousedom" / "data" / "demo-rig.yaml"


def _decoder(schema_b64: str, name: str):
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def _start(tmp_path, extra: str = ""):
    text = DEMO.read_text().replace("demo-rig.mdcap", str(DEMO.with_suffix(".mdcap")))
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(text + f"outputs:\n  foxglove: {{port: 0{extra}}}\n")
    sock = tmp_path / "run" / "s.sock"
    log = tmp_path / "daemon.log"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "run", "--config", str(cfg), "--socket", str(sock)],
        env=mousedom_env(), stderr=open(log, "w"),  # noqa: SIM115
    )  # fmt: skip
    deadline = time.monotonic() + 20
    port = None
    while time.monotonic() < deadline and port is None:
        m = re.search(r"Foxglove live view on ws://([\d.]+):(\d+)", log.read_text())
        port = int(m.group(2)) if m else None
        time.sleep(0.05)
    assert port, log.read_text()
    wait_listening(sock, proc, 20, log.read_text)
    return proc, sock, port, m.group(1), log


def test_a_websocket_client_gets_pose_tf_path_and_mice(tmp_path):
    proc, sock, port, host, log = _start(tmp_path)
    assert host == "127.0.0.1"  # localhost unless the config says otherwise
    stack = contextlib.ExitStack()
    try:
        c = Conn(sock)
        ws = stack.enter_context(websockets_sync.connect(
            f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
            open_timeout=10, max_size=None,
        ))  # fmt: skip
        channels = {}
        deadline = time.monotonic() + 10
        while len(channels) < 5 and time.monotonic() < deadline:
            msg = ws.recv(timeout=5)
            if isinstance(msg, str):
                doc = json.loads(msg)
                if doc.get("op") == "advertise":
                    for ch in doc["channels"]:
                        channels[ch["id"]] = ch
        topics = {ch["topic"]: ch for ch in channels.values()}
        assert set(topics) == {"/mousedom/pose", "/tf", "/mousedom/path", "/mousedom/mice",
                               "/mousedom/sources"}, topics  # fmt: skip
        subs = {k + 1: ch for k, ch in enumerate(channels.values())}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": sid, "channelId": ch["id"]} for sid, ch in subs.items()]}))  # fmt: skip
        decoders = {}
        for sid, ch in subs.items():
            if ch["encoding"] == "protobuf":
                decoders[sid] = _decoder(ch["schema"], ch["schemaName"])
        socket_poses: list[dict] = []

        def read_socket() -> None:  # alongside, so both see the same windows
            try:
                while True:
                    m = c.read()
                    if m["class"] == "POSE":
                        socket_poses.append(m)
            except (EOFError, OSError, ValueError):
                pass

        threading.Thread(target=read_socket, daemon=True).start()
        got: dict[str, list] = {t: [] for t in topics}
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            msg = ws.recv(timeout=5)
            if isinstance(msg, bytes) and msg[0] == 1:
                sid, _ts = struct.unpack_from("<IQ", msg, 1)
                payload = msg[13:]
                ch = subs[sid]
                value = (decoders[sid].FromString(payload) if sid in decoders
                         else json.loads(payload))  # fmt: skip
                got[ch["topic"]].append(value)
        poses = list(socket_poses)
        c.close()
    finally:
        stack.close()
        proc.terminate()
        proc.wait(10)
    assert proc.returncode == 0, log.read_text()
    fox = got["/mousedom/pose"]
    assert len(fox) > 100, len(fox)  # 50 Hz for 3 s
    by_t = {round(p.timestamp.seconds + p.timestamp.nanos * 1e-9, 6): p for p in fox}
    matched = [(p, by_t[round(p["t"], 6)]) for p in poses if round(p["t"], 6) in by_t]
    assert len(matched) > 50, (len(matched), len(poses), len(fox))
    for p, f in matched:
        assert f.frame_id == "odom"
        assert (f.pose.position.x, f.pose.position.y) == pytest.approx((p["x"], p["y"]), abs=1e-12)
        q = f.pose.orientation
        yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))
        assert yaw == pytest.approx(p["theta"], abs=1e-9)
    frames = {(t.parent_frame_id, t.child_frame_id) for m in got["/tf"] for t in m.transforms}
    assert frames == {("odom", "base_link"), ("base_link", "front_mouse"),
                      ("base_link", "left_mouse"), ("base_link", "right_mouse")}  # fmt: skip
    path = got["/mousedom/path"][-1]
    assert len(path.poses) >= 10 and path.frame_id == "odom"
    mice = got["/mousedom/mice"][-1]["mice"]
    assert [m["name"] for m in mice] == ["front", "left", "right"]
    assert all(m["state"] == "tracking" for m in mice)
    assert sum(abs(m["dy"]) for w in got["/mousedom/mice"] for m in w["mice"]) > 100
    assert got["/mousedom/sources"] and {
        s["name"] for s in got["/mousedom/sources"][-1]["sources"]
    } == {"front", "left", "right"}


def test_a_port_in_use_is_one_line(tmp_path):
    import socket

    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    text = DEMO.read_text().replace("demo-rig.mdcap", str(DEMO.with_suffix(".mdcap")))
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(text + f"outputs:\n  foxglove: {{port: {port}}}\n")
    p = subprocess.run(
        [sys.executable, "-m", "mousedom", "run", "--config", str(cfg), "--socket",
         str(tmp_path / "s.sock")], env=mousedom_env(), capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    busy.close()
    lines = [ln for ln in p.stderr.splitlines() if not ln.startswith("INFO")]
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert f"cannot listen on 127.0.0.1:{port}" in lines[0] and "Traceback" not in p.stderr


def _row(t: float, x: float, names: int = 2):
    from mousedom.fusion.posebatch import PoseRow

    cov = [[0.0] * 3 for _ in range(3)]
    return PoseRow(t, x, 0.0, 0.0, 0.0, 0.0, 0.0, cov, names, True, [[0, 0]] * names,
                   [[1, 2]] * names, (0,) * names, (0,) * names, True, cov)  # fmt: skip


def test_the_path_holds_motion_not_a_standstill_and_the_sdk_log_stays_out():
    """A pose every 0.1 s of motion: none while the robot stands (6 minutes still had
    filled the path with 3,000 copies of one pose and pushed the drive out), each step of
    0.1 s taken at 0.1 s (50 Hz windows gave 0.1 or 0.12); and the SDK's own log lines
    stay out of the daemon's log (a stalled viewer's disconnect logged up to 639 ERRORs)."""
    import logging

    from mousedom.config import FoxgloveConfig
    from mousedom.service.foxgloveout import PATH_STEP_S, FoxgloveOutput

    out = FoxgloveOutput(FoxgloveConfig(port=0), ("a", "b"))
    try:
        assert logging.getLogger("foxglove.websocket.server").getEffectiveLevel() > logging.ERROR
        for k in range(100):  # 2 s of motion at 50 Hz: 20 path poses
            out.publish(_row(1.0 + 0.02 * k, 0.01 * k))
        moving = len(out.path)
        for k in range(3000):  # a minute standing still
            out.publish(_row(3.0 + 0.02 * k, 0.99))
        # (the first still pose is where the motion ended: one more, then none)
        assert moving == round(2.0 / PATH_STEP_S) and len(out.path) == moving + 1
        out.publish(_row(63.0, 1.5))  # and moving again
        assert len(out.path) == moving + 2
    finally:
        out.close()


def test_a_reload_that_changes_the_view_says_it_waits_for_a_restart(tmp_path):
    """The view is made at start, as the metrics endpoint is: a SIGHUP that changes
    outputs.foxglove was ignored without a word; it is said now, and the view goes on."""
    from test_metrics import _start, reload_with

    d = _start(tmp_path, "outputs:\n  foxglove: {port: 0}\n")
    try:
        log = reload_with(d, tmp_path / "rig.yaml", "{port: 0}", "{port: 1}")
        assert "outputs.foxglove changed: takes effect at the next restart" in log
    finally:
        assert d.stop() == 0


def test_mouse_frames_are_named_and_turned_as_ros2_has_them():
    """Foxglove's base_link -> mouse transforms used the raw name ("front-left_mouse",
    ROS 2's /tf_static "front_left_mouse") and the yaw alone (a mirrored sensor drawn
    upright): both now as ros2conv's static transforms, for any name, yaw and flip."""
    import numpy as np

    from mousedom.config import MouseConfig
    from mousedom.config.rig import Mount
    from mousedom.service import ros2conv
    from mousedom.service.foxgloveout import mount_frames

    rng = np.random.default_rng(4)
    names = ["front-left", "2nd", "Rear", "a.b", "x"]
    mice = [
        MouseConfig(
            name=n,
            cpi_x=800.0,
            cpi_y=800.0,
            flip=bool(rng.random() < 0.5),
            mount=Mount(
                x=float(rng.uniform(-0.2, 0.2)),
                y=float(rng.uniform(-0.2, 0.2)),
                yaw=float(rng.uniform(-math.pi, math.pi)),
            ),
        )  # fmt: skip
        for n in names
    ]
    assert any(m.flip for m in mice) and not all(m.flip for m in mice)
    from foxglove.messages import FrameTransform

    schema = FrameTransform.get_schema()
    decode = _decoder(base64.b64encode(schema.data).decode(), schema.name).FromString
    frames = [decode(f.encode()) for f in mount_frames(mice, None)]
    for m, f in zip(mice, frames, strict=True):
        ros = ros2conv.mount_transform("base_link", m.name, m.mount.x, m.mount.y, m.mount.yaw,
                                       m.flip, {"sec": 0, "nanosec": 0})  # fmt: skip
        assert f.parent_frame_id == "base_link" and f.child_frame_id == ros["child_frame_id"]
        r = ros["transform"]["rotation"]
        q = f.rotation
        assert (q.x, q.y, q.z, q.w) == (r["x"], r["y"], r["z"], r["w"])
        assert (f.translation.x, f.translation.y) == (m.mount.x, m.mount.y)
    assert frames[0].child_frame_id == "front_left_mouse"
