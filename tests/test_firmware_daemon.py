"""The whole chain: the firmware in simavr -> pty -> ``mousedom run`` -> Unix socket.

One ADNS-3080 downsampler as the only sensor of a differential-drive robot (Hong's
single-mouse case), 0.1 m ahead of the axle.  The simulated sensor moves straight forward
at 2 in/s for 0.5 s; the daemon must publish a pose 1 in (0.0254 m) ahead, no heading
change, and a SOURCE status carrying the sensor's SQUAL.  Toolchain gating as in
test_firmware_build.py."""

from __future__ import annotations

import os
import time

import pytest
from daemon_fixtures import Conn, DaemonProcess
from test_firmware_build import make, require_toolchain  # tests/ is on sys.path
from test_firmware_sim import start_sim, stop_sim


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    require_toolchain()
    out = tmp_path_factory.mktemp("fwdaemon")
    r = make(out, "all", "sim-tools")
    assert r.returncode == 0, r.stdout + r.stderr
    return out


def test_daemon_tracks_the_simulated_sensor(build, tmp_path):
    sim = start_sim(build, "--duration", "1.6", "--seg", "0.5:0:2", "--seg", "1.0:0:0")
    daemon = conn = None
    try:
        pty = None
        buf = b""
        while pty is None:
            chunk = os.read(sim.stdout.fileno(), 4096)
            assert chunk, "the simulator exited"
            buf += chunk
            for line in buf.decode(errors="replace").splitlines():
                if line.startswith("PTY "):
                    pty = line.split()[1]
        config = tmp_path / "rig.yaml"
        config.write_text(
            "rate_hz: 20\n"
            "model: diff-drive\n"
            "mice:\n"
            "  floor:\n"
            "    cpi: 1600\n"
            "    mount: {x: 0.1, y: 0.0, yaw: 0}\n"
            "    report_hz: 66.7\n"
            f"    serial: {{port: {pty}, k: 12, sensor_cpi: 1600}}\n"
        )
        daemon = DaemonProcess(config, tmp_path / "run" / "mousedom.sock")
        daemon.wait_socket()
        conn = Conn(daemon.socket_path)
        time.sleep(0.3)  # let the daemon open the port and send its settings
        sim.stdin.write(b"go\n")
        sim.stdin.flush()
        source = conn.until("SOURCE", lambda m: m.get("sensor") == "ok", limit=2000)
        assert source["name"] == "floor" and source["squal"] == 80
        last = None
        end = time.monotonic() + 6
        while time.monotonic() < end:
            m = conn.read()
            if m["class"] == "POSE":
                last = m
                if abs(m["x"] - 0.0254) < 1e-4 and m["t"] > 0:
                    break
        assert last is not None, daemon.log()
        assert last["x"] == pytest.approx(0.0254, abs=1e-4), daemon.log()
        assert abs(last["y"]) < 1e-6 and abs(last["theta"]) < 1e-6
    finally:
        if conn is not None:
            conn.close()
        if daemon is not None:
            daemon.stop()
        stop_sim(sim, timeout=10)
