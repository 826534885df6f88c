"""Prometheus metrics (issue 29, item 7): the real daemon on the bundled demo capture,
scraped over real TCP, its exposition text parsed with prometheus-client's own parser and
checked against what is true (the config's mice, the capture's report rates, a client on
the Unix socket); the config section; no port at all when metrics are off; the errors a
user meets (the extra not installed, the port taken) without a traceback."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from conftest import REPO, mousedom_env
from daemon_fixtures import Conn, DaemonProcess

from mousedom.config import ConfigError, MetricsConfig, parse_config

try:
    from prometheus_client.parser import text_string_to_metric_families
except ImportError as e:  # the test extra installs it; CI must not skip
    if os.environ.get("CI"):
        raise
    pytest.skip(f"{e.name} is not installed: pip install '.[test]'", allow_module_level=True)

from mousedom.service.metrics import CPU_BUCKETS, WindowCpu

DEMO = REPO / "mousedom" / "data" / "demo-rig.yaml"
DEMO_MICE = {"front", "left", "right"}
DEMO_REPORT_HZ = 125.0  # each simulated mouse of the capture reports at 125 Hz
DEMO_RATE_HZ = 50.0  # the demo's windows a second

CONFIG = """\
model: lsq
mice:
  left: {cpi: 800, mount: {x: 0.0, y: 0.1, yaw: 0}, replay: a.events}
  right: {cpi: 800, mount: {x: 0.0, y: -0.1, yaw: 0}, replay: a.events}
"""


# --------------------------------------------------------------------------- the config


def _parse(outputs: str):
    return parse_config(CONFIG + outputs, "rig.yaml")


def test_metrics_are_off_unless_asked():
    assert _parse("").metrics is None
    assert _parse("outputs: {foxglove: {port: 0}}\n").metrics is None
    assert _parse("outputs: {metrics: false}\n").metrics is None
    assert _parse("outputs: {metrics: {enabled: false, port: 1}}\n").metrics is None


def test_metrics_on_bind_localhost_by_default():
    assert _parse("outputs: {metrics: true}\n").metrics == MetricsConfig("127.0.0.1", 9464)
    assert _parse("outputs: {metrics: {}}\n").metrics == MetricsConfig("127.0.0.1", 9464)
    cfg = _parse("outputs:\n  metrics: {host: '::1', port: 0}\n").metrics
    assert cfg == MetricsConfig("::1", 0)
    assert _parse("outputs: {metrics: {host: 0.0.0.0}}\n").metrics.host == "0.0.0.0"


@pytest.mark.parametrize(
    "section, key, words",
    [
        ("{port: 70000}", "outputs.metrics.port", "0 to 65535"),
        ("{port: -1}", "outputs.metrics.port", "at least 0"),
        ("{port: http}", "outputs.metrics.port", "integer"),
        ("{host: prometheus.example.com}", "outputs.metrics.host", "IP address"),
        ("{host: '127.0.0.1:9464'}", "outputs.metrics.host", "IP address"),
        ("{host: 5}", "outputs.metrics.host", "string"),
        ("{prot: 9464}", "outputs.metrics.prot", "did you mean port?"),
        ("{enabled: yes please}", "outputs.metrics.enabled", "true or false"),
        ("9464", "outputs.metrics", "mapping"),
    ],
)
def test_metrics_mistakes_name_line_and_key(section, key, words):
    with pytest.raises(ConfigError) as err:
        _parse(f"outputs:\n  metrics: {section}\n")
    msg = str(err.value)
    assert msg.startswith(f"rig.yaml:6: {key}: "), msg
    assert words in msg, msg


# --------------------------------------------------------------------------- the CPU clock


def test_window_cpu_shares_a_wake_among_its_windows_and_carries_empty_wakes():
    cpu = WindowCpu()
    cpu.start(0)
    cpu.stop(0)  # a wake that closed nothing: its time waits for the next window
    assert sum(cpu.counts) == 0 and cpu.sum == 0.0
    cpu.start(0)
    t0 = time.thread_time()
    while time.thread_time() - t0 < 0.003:  # burn 3 ms of this thread's CPU
        pass
    cpu.stop(2)  # two windows: 1.5 ms each or more
    assert sum(cpu.counts) == 2 and cpu.sum >= 0.003
    per_window = cpu.sum / 2
    (k,) = [i for i, n in enumerate(cpu.counts) if n]
    assert (CPU_BUCKETS[k - 1] if k else 0.0) < per_window <= CPU_BUCKETS[k]


# --------------------------------------------------------------------------- the daemon


def _demo_config(tmp_path: Path, outputs: str) -> Path:
    text = DEMO.read_text().replace("demo-rig.mdcap", str(DEMO.with_suffix(".mdcap")))
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(text + outputs)
    return cfg


def _start(tmp_path: Path, outputs: str) -> DaemonProcess:
    d = DaemonProcess(_demo_config(tmp_path, outputs), tmp_path / "run" / "s.sock")
    d.wait_socket(20)
    return d


def _endpoint(d: DaemonProcess) -> tuple[str, int]:
    deadline = time.monotonic() + 10
    while not (m := re.search(r"Prometheus metrics on http://([\d.]+):(\d+)/metrics", d.log())):
        assert time.monotonic() < deadline and d.proc.poll() is None, d.log()
        time.sleep(0.05)
    return m.group(1), int(m.group(2))


def _scrape(port: int) -> dict[str, dict]:
    """{family name: {(sample name, sorted labels): value}} of one scrape."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as r:
        assert r.status == 200
        assert r.headers["Content-Type"].startswith("text/plain; version=0.0.4")
        text = r.read().decode()
    out: dict[str, dict] = {}
    for family in text_string_to_metric_families(text):
        samples = out.setdefault(family.name, {"type": family.type})
        for s in family.samples:
            samples[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def _value(scrape: dict, family: str, sample: str | None = None, **labels: str) -> float:
    return scrape[family][(sample or family, tuple(sorted(labels.items())))]


def _listening_tcp_ports(pid: int) -> set[int]:
    """The TCP ports process ``pid`` listens on: its socket descriptors' inodes looked up
    in /proc/net/tcp and tcp6 (state 0A, LISTEN)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        if not os.path.exists(table):
            continue
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:
                ports.add(int(f[1].rsplit(":", 1)[1], 16))
    return ports


def test_scrape_says_what_the_daemon_does(tmp_path):
    d = _start(tmp_path, "outputs:\n  metrics: {port: 0}\n")
    try:
        host, port = _endpoint(d)
        assert host == "127.0.0.1"  # localhost unless the config says otherwise
        assert _listening_tcp_ports(d.proc.pid) == {port}
        # The per-mouse figures come with the SOURCE messages, once a second; a mouse's
        # rate once it has reported for a second
        deadline = time.monotonic() + 10
        while True:
            first = _scrape(port)
            rates = first.get("mousedom_mouse_report_rate_hertz", {})
            if len(rates) > 1 and all(v > 0 for k, v in rates.items() if k != "type"):
                break
            assert time.monotonic() < deadline, first
            time.sleep(0.2)
        t_first = time.monotonic()

        windows = _value(first, "mousedom_windows", "mousedom_windows_total")
        assert first["mousedom_windows"]["type"] == "counter" and windows > 0
        assert _value(first, "mousedom_clients") == 0

        # One mouse label per mouse of the config, and nothing else
        assert {dict(k[1])["mouse"] for k in rates if k != "type"} == DEMO_MICE
        for mouse in DEMO_MICE:
            assert _value(first, "mousedom_mouse_report_rate_hertz", mouse=mouse) == (
                pytest.approx(DEMO_REPORT_HZ, rel=0.1)
            )
            assert _value(first, "mousedom_mouse_state", state="tracking", mouse=mouse) == 1
            for other in ("suspect", "excluded", "missing", "gone"):
                assert _value(first, "mousedom_mouse_state", state=other, mouse=mouse) == 0
            assert _value(first, "mousedom_mouse_dropped_reports",
                          "mousedom_mouse_dropped_reports_total", mouse=mouse) == 0  # fmt: skip
            # healthy mice agree to within a fraction of a millimetre a window
            residual = _value(first, "mousedom_mouse_residual_meters", mouse=mouse)
            assert 0 <= residual < 1e-3

        # A client on the Unix socket is counted while it is there
        c = Conn(d.socket_path)
        try:
            assert c.read()["class"] == "VERSION"
            c.until("POSE")
            second = _scrape(port)
            assert _value(second, "mousedom_clients") == 1
        finally:
            c.close()
        t_second = time.monotonic()

        # Windows grow at the output rate, reports at each mouse's
        grown = _value(second, "mousedom_windows", "mousedom_windows_total") - windows
        assert grown > 0
        assert grown <= DEMO_RATE_HZ * (t_second - t_first) * 1.2 + 5
        for mouse in DEMO_MICE:
            n0 = _value(first, "mousedom_mouse_reports", "mousedom_mouse_reports_total",
                        mouse=mouse)  # fmt: skip
            n1 = _value(second, "mousedom_mouse_reports", "mousedom_mouse_reports_total",
                        mouse=mouse)  # fmt: skip
            assert n1 >= n0 > 0

        # The covariance: m^2 and rad^2 apart; it grows as the rig drives
        pos = _value(second, "mousedom_pose_position_variance_square_meters")
        heading = _value(second, "mousedom_pose_heading_variance_square_radians")
        assert pos > 0 and heading > 0

        # The CPU per window: one observation per window the loop closed
        h = second["mousedom_window_cpu_seconds"]
        assert h["type"] == "histogram"
        count = _value(second, "mousedom_window_cpu_seconds", "mousedom_window_cpu_seconds_count")
        total = _value(second, "mousedom_window_cpu_seconds", "mousedom_window_cpu_seconds_sum")
        windows_now = _value(second, "mousedom_windows", "mousedom_windows_total")
        assert 0 < count <= windows_now
        assert 0 < total / count < 0.05  # seconds of CPU a window: far under the 20 ms window
        inf = _value(second, "mousedom_window_cpu_seconds", "mousedom_window_cpu_seconds_bucket",
                     le="+Inf")  # fmt: skip
        assert inf == count

        # The process's own figures come along (the library's process collector)
        assert _value(second, "process_cpu_seconds", "process_cpu_seconds_total") > 0

        # When the client has gone, the gauge says so
        deadline = time.monotonic() + 5
        while _value(_scrape(port), "mousedom_clients") != 0:
            assert time.monotonic() < deadline, "the client is still counted"
            time.sleep(0.1)
    finally:
        rc = d.stop()
    assert rc == 0, d.log()
    assert "Traceback" not in d.log()


def test_metrics_off_opens_no_port(tmp_path):
    d = _start(tmp_path, "")
    try:
        time.sleep(0.5)
        assert _listening_tcp_ports(d.proc.pid) == set()
        assert "Prometheus" not in d.log()
    finally:
        assert d.stop() == 0


def _run_until_exit(cfg: Path, tmp_path: Path, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mousedom", "run", "--config", str(cfg),
         "--socket", str(tmp_path / "run" / "s.sock")],
        capture_output=True, text=True, timeout=30, env=env,
    )  # fmt: skip


def test_port_taken_is_one_clear_line(tmp_path):
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    try:
        port = taken.getsockname()[1]
        cfg = _demo_config(tmp_path, f"outputs:\n  metrics: {{port: {port}}}\n")
        r = _run_until_exit(cfg, tmp_path, mousedom_env())
    finally:
        taken.close()
    assert r.returncode == 2, r.stderr
    assert f"cannot listen on 127.0.0.1:{port}" in r.stderr and "outputs.metrics" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "run" / "s.sock").exists()  # the socket is removed on the way out


def test_missing_library_names_the_extra(tmp_path):
    # A prometheus_client that cannot be imported, first on the path
    hide = tmp_path / "hide" / "prometheus_client"
    hide.mkdir(parents=True)
    (hide / "__init__.py").write_text("raise ImportError('hidden by the test')\n")
    env = mousedom_env()
    env["PYTHONPATH"] = str(hide.parent) + os.pathsep + env["PYTHONPATH"]
    cfg = _demo_config(tmp_path, "outputs:\n  metrics: {port: 0}\n")
    r = _run_until_exit(cfg, tmp_path, env)
    assert r.returncode == 2, r.stderr
    assert "pip install 'mousedom[metrics]'" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert "open (replay)" not in r.stderr  # said before any sensor was opened


def reload_with(d: DaemonProcess, cfg: Path, old: str, new: str) -> str:
    """Edit the running daemon's config (``old`` -> ``new``), SIGHUP it and wait for the
    reload: its log."""
    cfg.write_text(cfg.read_text().replace(old, new))
    d.signal(signal.SIGHUP)
    deadline = time.monotonic() + 10
    while "reloaded" not in d.log():
        assert time.monotonic() < deadline, d.log()
        time.sleep(0.05)
    return d.log()


def test_reload_keeps_the_endpoint_and_says_a_change_waits_for_a_restart(tmp_path):
    d = _start(tmp_path, "outputs:\n  metrics: {port: 0}\n")
    try:
        _, port = _endpoint(d)
        before = _value(_scrape(port), "mousedom_windows", "mousedom_windows_total")
        log = reload_with(d, tmp_path / "rig.yaml", "{port: 0}", "{port: 1}")
        assert "outputs.metrics changed: takes effect at the next restart" in log
        time.sleep(0.3)
        after = _value(_scrape(port), "mousedom_windows", "mousedom_windows_total")
        assert after > before  # the same endpoint, the same counter, going on
    finally:
        assert d.stop() == 0
    assert "Traceback" not in d.log()


def test_doctor_checks_the_endpoint_the_config_names(tmp_path, capsys):
    """`mousedom doctor` on a daemon serving metrics at a fixed port: OK with the windows
    it has published; the same config with nothing listening there: FAIL, saying why."""
    import json

    from mousedom.cli import main

    with socket.socket() as s:  # a port free now (the daemon binds it next)
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    d = _start(tmp_path, f"outputs:\n  metrics: {{port: {port}}}\n")
    try:
        _endpoint(d)
        cfg = str(_demo_config(tmp_path, f"outputs:\n  metrics: {{port: {port}}}\n"))
        main(["doctor", "--json", "--config", cfg, "--socket", str(d.socket_path),
              "--timeout", "1"])  # fmt: skip
        doc = json.loads(capsys.readouterr().out)
        got = [c for c in doc["checks"] if c["check"] == "metrics"]
        assert [c["status"] for c in got] == ["OK"], got
        assert got[0]["data"]["url"] == f"http://127.0.0.1:{port}/metrics"
        assert got[0]["data"]["windows"] > 0
    finally:
        d.stop()
    other = tmp_path / "other"
    other.mkdir()
    d = _start(other, "")  # a daemon without metrics: nothing serves the port
    try:
        main(["doctor", "--json", "--config", cfg, "--socket", str(d.socket_path),
              "--timeout", "1"])  # fmt: skip
        doc = json.loads(capsys.readouterr().out)
        got = [c for c in doc["checks"] if c["check"] == "metrics"]
        assert [c["status"] for c in got] == ["FAIL"], got
        assert "restart it" in got[0]["hint"]
    finally:
        d.stop()


def test_idle_scrapers_cannot_use_up_the_daemons_descriptors(tmp_path):
    """Each connection to the endpoint held a thread and a descriptor for ever: 150 idle
    half-sent requests used up the daemon's descriptors and its socket refused clients.
    At most MAX_SCRAPERS connections are served at once (the rest closed unanswered), each
    given REQUEST_TIMEOUT_S to send its request; the socket's clients never notice."""
    from mousedom.service.metrics import MAX_SCRAPERS, REQUEST_TIMEOUT_S

    d = _start(tmp_path, "outputs:\n  metrics: {port: 0}\n")
    idle: list[socket.socket] = []
    try:
        _, port = _endpoint(d)
        _scrape(port)
        before = len(os.listdir(f"/proc/{d.proc.pid}/fd"))
        for _ in range(60):
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            s.sendall(b"GET /metrics HTTP/1.1\r\nHost: x\r\n")  # and never the end
            idle.append(s)
        time.sleep(0.5)
        held = len(os.listdir(f"/proc/{d.proc.pid}/fd")) - before
        assert held <= MAX_SCRAPERS + 2, held
        c = Conn(d.socket_path)  # the socket's clients are served as before
        assert c.read()["class"] == "VERSION" and c.until("POSE")
        c.close()
        # Once the held ones' time is up, a scrape is answered again
        time.sleep(REQUEST_TIMEOUT_S + 0.5)
        assert _value(_scrape(port), "mousedom_clients") == 0
    finally:
        for s in idle:
            s.close()
        rc = d.stop()
    assert rc == 0, d.log()
    assert "Traceback" not in d.log()
