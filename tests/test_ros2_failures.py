"""When the ROS 2 output cannot start (issue 25): one ``mousedom: error:`` line naming the
cause and docs/ros2.md's section, never a traceback; with ``outputs.ros2.optional`` the
daemon logs it and serves its socket without ROS 2."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest
from conftest import REPO, mousedom_env
from daemon_fixtures import Conn, wait_listening

DEMO = REPO / "mousedom" / "data" / "demo-rig.yaml"
SECTION = 'see docs/ros2.md, "When the ROS 2 output cannot start"'


def _run(args: list[str], env: dict, netns: bool = False, timeout: float = 30):
    cmd = [sys.executable, "-m", "mousedom", *args]
    if netns:
        cmd = ["unshare", "-n", *cmd]  # a network namespace whose loopback is down
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)


def _error_lines(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if not ln.startswith("INFO ")]


def test_a_bad_cyclonedds_uri_is_one_line_naming_it(tmp_path):
    env = mousedom_env(CYCLONEDDS_URI="<CycloneDDS><Bad")
    p = _run(["run", "--demo", "--ros2", "--socket", str(tmp_path / "s.sock")], env)
    lines = _error_lines(p.stderr)
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert lines[0].startswith("mousedom: error: ROS 2 output: no DDS participant on domain 0")
    assert "Bad: unknown element" in lines[0] and "CYCLONEDDS_URI" in lines[0]
    assert lines[0].endswith(SECTION)


def _netns_or_skip() -> None:
    if shutil.which("unshare") is None:
        pytest.skip("no unshare command: cannot make a network namespace")
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"cannot make a network namespace: {probe.stderr.strip()}")


def test_no_usable_interface_is_one_line_naming_it(tmp_path):
    _netns_or_skip()
    p = _run(["run", "--demo", "--ros2", "--socket", str(tmp_path / "s.sock")],
             mousedom_env(), netns=True)  # fmt: skip
    lines = _error_lines(p.stderr)
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert 'failed to find interfaces for "udp"' in lines[0] and "drop-in" in lines[0]
    assert lines[0].endswith(SECTION) and "Traceback" not in p.stderr


def test_a_domain_out_of_range_is_one_line(tmp_path):
    p = _run(["run", "--demo", "--ros2", "--socket", str(tmp_path / "s.sock")],
             mousedom_env(ROS_DOMAIN_ID="300"))  # fmt: skip
    lines = _error_lines(p.stderr)
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert "ROS_DOMAIN_ID='300'" in lines[0] and "0 to 232" in lines[0]


def test_an_optional_ros2_output_that_cannot_start_leaves_the_socket_working(tmp_path):
    text = DEMO.read_text().replace("demo-rig.mdcap", str(DEMO.with_suffix(".mdcap")))
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(text + "outputs:\n  ros2: {optional: true}\n")
    sock = tmp_path / "run" / "s.sock"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mousedom", "run", "--config", str(cfg), "--socket", str(sock)],
        env=mousedom_env(CYCLONEDDS_URI="<CycloneDDS><Bad"), stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        wait_listening(sock, proc, 20)
        c = Conn(sock)
        assert c.read()["class"] == "VERSION"
        assert len(c.poses(0.5)) >= 10
        c.close()
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "no DDS participant" in err and "going on without it (outputs.ros2.optional)" in err
    assert "Traceback" not in err
