"""The real firmware .elf in simavr, against the simulated ADNS-3080 of firmware/sim, its
UART bridged to a pty that the Python serial source reads as the daemon would.

Each scenario runs paced to the wall clock (so that the host's clock mapping sees real
transport delays) for one to three simulated seconds.  The harness reports every count
the sensor saw and where it went; the tests hold the firmware and the host to it:
counts in equal counts out, no sequence gaps, firmware timestamps K poll periods apart
and monotonic host times, a missing or unplugged sensor reported, overflow flagged, and
no datasheet timing violated on the SPI bus.

Skips without the toolchain (see test_firmware_build.py), fails instead in CI or with
MOUSEDOM_REQUIRE_FIRMWARE=1."""

from __future__ import annotations

import json
import os
import selectors
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from test_firmware_build import make, require_toolchain  # tests/ is on sys.path

from mousedom.config import Mount, MouseConfig, SerialSource
from mousedom.sources import adns_protocol as P
from mousedom.sources.adns import AdnsSource
from mousedom.sources.adns_decode import packets_to_reports

POLL_US = 1250


@pytest.fixture(scope="module")
def build(tmp_path_factory) -> Path:
    require_toolchain()
    out = tmp_path_factory.mktemp("fwsim")
    r = make(out, "all", "sim-tools")
    assert r.returncode == 0, r.stdout + r.stderr
    return out


@dataclass
class SimRun:
    summary: dict
    source: AdnsSource
    raw: list = field(default_factory=list)
    t: np.ndarray = None
    dx: np.ndarray = None
    dy: np.ndarray = None
    packets: list = field(default_factory=list)

    @property
    def motion(self) -> list[P.Motion]:
        return [p for p in self.packets if isinstance(p, P.Motion)]

    @property
    def statuses(self) -> list[P.Status]:
        return [p for p in self.packets if isinstance(p, P.Status)]


def start_sim(build: Path, *args: str) -> subprocess.Popen:
    """The firmware in simavr beside the ADNS-3080 model; it prints "PTY <path>" and waits
    for "go" on its stdin."""
    return subprocess.Popen(
        [str(build / "adns_sim"), str(build / "downsampler.elf"), "--wait-start", *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        bufsize=0,
    )


def stop_sim(proc: subprocess.Popen, timeout: float) -> None:
    """Close its stdin (the simulator's cue to end) and reap it, killed if it lingers."""
    try:
        proc.stdin.close()
    except OSError:
        pass
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def run_sim(build: Path, *args: str, k: int = 12, cpi: int = 1600, timeout: float = 60) -> SimRun:
    proc = start_sim(build, *args)
    lines: list[str] = []
    pending = b""

    def pull_lines() -> None:
        nonlocal pending
        chunk = os.read(proc.stdout.fileno(), 65536)
        if not chunk:
            raise EOFError
        pending += chunk
        *done, pending = pending.split(b"\n")
        lines.extend(x.decode(errors="replace") for x in done)

    deadline = time.monotonic() + timeout
    try:
        while not any(x.startswith("PTY ") for x in lines):
            pull_lines()
        pty = next(x for x in lines if x.startswith("PTY ")).split()[1]
        mouse = MouseConfig(
            "adns", cpi, cpi, Mount(), serial=SerialSource(pty, k=k, sensor_cpi=cpi)
        )
        raw: list = []
        src = AdnsSource(mouse, on_raw=lambda t, b: raw.append((t, b)))
        src.open()
        proc.stdin.write(b"go\n")
        proc.stdin.flush()
        sel = selectors.DefaultSelector()
        sel.register(src.fileno(), selectors.EVENT_READ, "src")
        sel.register(proc.stdout.fileno(), selectors.EVENT_READ, "sim")
        reports = []
        summary = None
        while time.monotonic() < deadline:
            events = sel.select(0.3)
            if not events and summary is not None:
                break  # the simulation ended and the line has been quiet for 0.3 s
            for key, _ in events:
                if key.data == "src":
                    reports += src.read(time.monotonic())
                else:
                    try:
                        pull_lines()
                    except EOFError:
                        sel.unregister(proc.stdout.fileno())
                    for x in lines:
                        if x.startswith("SUMMARY "):
                            summary = json.loads(x[len("SUMMARY ") :])
        assert summary is not None, "the simulation did not finish:\n" + "\n".join(lines)
    finally:
        stop_sim(proc, timeout=5)
    run = SimRun(summary=summary, source=src, raw=raw)
    run.t = np.concatenate([r.t for r in reports]) if reports else np.zeros(0)
    run.dx = np.concatenate([r.dx for r in reports]) if reports else np.zeros(0)
    run.dy = np.concatenate([r.dy for r in reports]) if reports else np.zeros(0)
    parser = P.Parser()
    for t, b in raw:
        run.packets += parser.feed(b, t)
    src.close()
    return run


def assert_clean_bus(run: SimRun) -> None:
    s = run.summary
    assert s["violations"] == 0, s["first_violation"]


def assert_counts_conserved(run: SimRun) -> None:
    """Everything the sensor delivered reached the host (REL_Y = -Delta_Y), nothing
    stayed in the sensor, and the line lost nothing."""
    s = run.summary
    assert s["buffered"] == [0, 0]
    assert run.dx.sum() == s["read"][0]
    assert -run.dy.sum() == s["read"][1]
    stats = run.source.decoder.parser.stats
    assert stats.lost_seq == 0 and stats.crc_errors == 0 and stats.bad_frames == 0
    assert run.source.health.dropped == 0


def test_counts_in_equal_counts_out(build):
    run = run_sim(
        build,
        "--duration", "2.2",
        "--seg", "0.4:3:-2",
        "--seg", "0.9:-7.5:4",
        "--seg", "1.3:0.5:0.25",
        "--seg", "1.7:-20:-30",
        "--seg", "1.9:0:0",
    )  # fmt: skip
    s = run.summary
    assert_clean_bus(run)
    assert s["cpi"] == 1600 and s["config"] & 0x10  # Configuration_bits RES = 1600
    assert s["gen"][0] != 0 and s["gen"] == s["read"]  # nothing lost in the sensor
    assert s["lost"] == [0, 0] and s["untracked"] == [0, 0]
    assert_counts_conserved(run)

    motion = run.motion
    assert len(motion) > 100
    assert all(p.frames == 12 for p in motion)
    assert motion[0].flags & P.FLAG_BOOT and not any(p.flags & P.FLAG_BOOT for p in motion[1:])
    assert all(p.flags & P.FLAG_RES1600 for p in motion)
    assert not any(p.flags & (P.FLAG_OVERFLOW | P.FLAG_FAULT) for p in motion)
    assert min(p.squal_min for p in motion) == 80
    # firmware timestamps: one packet every K polls of 1250 us, to a few us of loop jitter
    periods = np.diff([p.t_us for p in motion])
    assert np.all(np.abs(periods - 12 * POLL_US) <= 30), periods
    # host times: monotonic, and the mapping keeps the period
    assert np.all(np.diff(run.t) >= 0)
    assert np.median(np.diff(run.t)) == pytest.approx(0.015, rel=0.02)
    # sequence numbers: consecutive over every packet the device sent
    seqs = [p.seq for p in run.packets]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    # status says the sensor is fine; version answered
    assert run.source.health.extra["sensor"] == "ok"
    assert run.source.health.extra["firmware"] == "1.0 (protocol 1)"
    assert run.source.health.error is None
    # the raw chunks replay to the very same reports
    replay, _ = packets_to_reports(run.raw, name="adns")
    np.testing.assert_array_equal(replay.dx, run.dx)
    np.testing.assert_array_equal(replay.t, run.t)


def test_boot_begins_with_a_delimiter(build):
    """The firmware's first byte after a reset is a lone 0x00: a host that still holds
    part of a frame from before the reset (the device reset while sending it) ends that
    frame there, and the boot's first packet (seq 0: VERSION, the answer to the host's
    GET_VERSION) is read whole.  Without the 0x00 the stale bytes and packet 0 make one
    frame, refused (a lost packet)."""
    run = run_sim(build, "--duration", "0.6")
    data = b"".join(b for _, b in run.raw)
    assert data[:1] == b"\0"
    stale = P.encode_packet(P.Motion(700, 9_000_000, 1, 1, 12, 80, P.FLAG_RES1600))
    parser = P.Parser()
    parser.feed(stale, 1.0)  # the last packet of the boot before
    got = parser.feed(stale[:9] + data, 2.0)  # the reset cut the next one short
    assert got[0].seq == 0
    assert parser.stats.reboots == 1 and parser.stats.lost_seq == 0
    assert parser.stats.bad_frames + parser.stats.crc_errors == 1  # the stale half only


def test_set_k_and_400_cpi(build):
    """K=5 and 400 CPI from the config: the firmware acknowledges, clears
    Configuration_bits bit 4 (read-modify-write keeps the other bits) and sends a packet
    every 5 polls."""
    run = run_sim(build, "--duration", "1.3", "--seg", "0.5:2:1", "--seg", "1.0:0:0", k=5, cpi=400)
    s = run.summary
    assert_clean_bus(run)
    assert s["cpi"] == 400 and s["config"] == 0x09
    assert s["gen"] == [400, 200]  # 0.5 s at (2, 1) in/s and 400 CPI
    assert_counts_conserved(run)
    acks = [p for p in run.statuses if p.reason == P.REASON_ACK]
    assert acks and acks[-1].k == 5 and acks[-1].cpi == 400
    motion = run.motion
    assert all(p.frames == 5 for p in motion)
    assert not any(p.flags & P.FLAG_RES1600 for p in motion)
    periods = np.diff([p.t_us for p in motion])
    assert np.all(np.abs(periods - 5 * POLL_US) <= 30)


def test_missing_sensor_reported_and_retried(build):
    """No sensor at power-up (MISO floats high): STATUS packets say so, once a second,
    with what Product_ID read; when the sensor appears, the next retry brings it up."""
    run = run_sim(
        build, "--duration", "3.0", "--absent-until", "2.1", "--seg", "2.5:1:1", "--seg", "2.8:0:0"
    )
    assert_clean_bus(run)
    st = run.statuses
    missing = [p for p in st if p.state == P.STATE_NO_SENSOR]
    assert len(missing) >= 2 and all(p.product_id == 0xFF for p in missing)
    gaps = np.diff([p.t_us for p in missing])
    assert np.all(np.abs(gaps - 1_000_000) < 50_000)  # retried every second
    ok = [p for p in st if p.state == P.STATE_OK]
    assert ok and ok[-1].retries == len(missing)
    assert run.summary["resets"] == 1  # pulses while absent do nothing
    assert run.source.health.extra["sensor"] == "ok" and run.source.health.error is None
    assert_counts_conserved(run)
    assert run.summary["gen"][0] > 0 and run.summary["gen"] == run.summary["read"]


def test_unplugged_sensor_is_a_fault(build):
    """The sensor vanishes while running, MISO low (so motion reads look like zeros): the
    per-packet Product_ID check flags the packet and a STATUS reports the fault."""
    run = run_sim(
        build,
        "--duration", "1.6",
        "--unplug-at", "0.9",
        "--absent-miso", "0",
        "--seg", "0.4:2:0",
        "--seg", "0.8:0:0",
    )  # fmt: skip
    assert_clean_bus(run)
    faults = [p for p in run.motion if p.flags & P.FLAG_FAULT]
    assert len(faults) == 1
    st = [p for p in run.statuses if p.reason == P.REASON_FAULT]
    assert st and st[0].state == P.STATE_NO_SENSOR and st[0].product_id == 0x00
    assert run.source.health.extra["fault_packets"] == 1
    assert "no ADNS-3080" in run.source.health.error
    # what was read before the unplug all arrived
    assert run.dx.sum() == run.summary["read"][0] == 1600 * 0.4 * 2


def test_overflow_flagged(build):
    """200 in/s is five times the sensor's limit: 320 counts a poll.  With an internal
    buffer of 127 counts the sensor loses counts and sets OVF; the firmware flags those
    packets and the host counts them.  What the sensor did deliver still all arrives."""
    run = run_sim(
        build,
        "--duration", "1.0",
        "--internal-max", "127",
        "--seg", "0.4:200:0",
        "--seg", "0.7:0:0",
    )  # fmt: skip
    s = run.summary
    assert_clean_bus(run)
    assert s["lost"][0] > 0 and s["ovf_reads"] > 0
    assert s["gen"][0] == s["read"][0] + s["lost"][0]
    assert_counts_conserved(run)
    assert run.source.health.extra["overflow_packets"] > 0
    assert any(p.flags & P.FLAG_OVERFLOW for p in run.motion)


def test_full_scale_deltas_are_drained(build):
    """At 100 in/s (160 counts a poll, over the 8-bit +-127) a sensor with a deep buffer
    loses nothing as long as the firmware re-reads while the deltas are at full scale."""
    run = run_sim(
        build,
        "--duration", "1.0",
        "--internal-max", "4095",
        "--seg", "0.4:100:-100",
        "--seg", "0.7:0:0",
    )  # fmt: skip
    s = run.summary
    assert_clean_bus(run)
    assert s["lost"] == [0, 0] and s["gen"] == s["read"]
    assert s["gen"][0] == pytest.approx(1600 * 100 * 0.3, rel=0.01)
    assert_counts_conserved(run)
    assert any(p.flags & P.FLAG_SATURATED for p in run.motion)
    assert not any(p.flags & P.FLAG_OVERFLOW for p in run.motion)


def test_k1_polls_overrun_in_simulation_and_time_is_kept(build):
    """K=1: a packet a poll.  In simavr an SPI byte takes 100 us, so the burst plus the
    per-packet Product_ID check outlasts the 1250 us period and ticks merge.  The firmware
    counts merged ticks as frames (DELAYED), so frames still measure time, and no count
    is lost."""
    run = run_sim(build, "--duration", "1.2", "--seg", "0.4:5:-5", "--seg", "0.8:0:0", k=1)
    s = run.summary
    assert_clean_bus(run)
    assert s["gen"] == s["read"] and s["gen"][0] == 1600 * 5 * 0.4
    assert_counts_conserved(run)
    motion = run.motion
    assert any(p.frames > 1 and p.flags & P.FLAG_DELAYED for p in motion)
    assert all(p.frames == 1 for p in motion if not p.flags & P.FLAG_DELAYED)
    # every poll period is in exactly one packet
    span_polls = (motion[-1].t_us - motion[0].t_us) / POLL_US
    assert sum(p.frames for p in motion[1:]) == pytest.approx(span_polls, abs=1)


@pytest.fixture(scope="module")
def slow_build(tmp_path_factory) -> Path:
    require_toolchain()
    out = tmp_path_factory.mktemp("fwsim38400")
    r = make(out, "BAUD=38400UL", "all", "sim-tools")
    assert r.returncode == 0, r.stdout + r.stderr
    return out


def test_uart_slower_than_the_packets_loses_nothing(slow_build):
    """A firmware built for 38400 baud (3.8 kB/s) asked for K=1 (about 11 kB/s of
    packets): the UART ring fills, the firmware keeps summing and sends when there is
    room.  Fewer, fuller packets; no lost count, no lost poll period, no sequence gap."""
    run = run_sim(slow_build, "--duration", "1.2", "--seg", "0.4:5:-5", "--seg", "0.8:0:0", k=1)
    assert_clean_bus(run)
    assert run.summary["gen"] == run.summary["read"]
    assert_counts_conserved(run)
    motion = run.motion
    rate = len(motion) / ((motion[-1].t_us - motion[0].t_us) * 1e-6)
    # 38400 baud carries 167 packets of 23 bytes a second (simavr, counting 8 bits a
    # byte, about 210); far below the 800 polls a second that K=1 asks for
    assert rate < 250
    assert max(p.frames for p in motion) >= 4
    span_polls = (motion[-1].t_us - motion[0].t_us) / POLL_US
    assert sum(p.frames for p in motion[1:]) == pytest.approx(span_polls, abs=1)


def test_recorded_firmware_bytes_calibrate_cpi(build, tmp_path):
    """The firmware's own bytes, recorded as `mousedom record` stores a serial port, give
    the sensor's CPI through `mousedom calibrate cpi`: 4 pushes of 1 inch (4 in/s for
    0.25 s at 1600 CPI: 1600 counts each) forth and back along the sensor's Y."""
    from conftest import run_mousedom

    from mousedom.capture.base import DeviceInfo
    from mousedom.capture.native import NativeWriter

    segs = []
    for k, t0 in enumerate((0.4, 0.9, 1.4, 1.9)):
        segs += ["--seg", f"{t0}:0:{4 if k % 2 == 0 else -4}", "--seg", f"{t0 + 0.25}:0:0"]
    run = run_sim(build, "--duration", "2.4", *segs)
    assert_clean_bus(run)
    assert_counts_conserved(run)
    assert run.summary["gen"][1] == 0  # forth and back: the pushes cancel
    cap = tmp_path / "adns.mdcap"
    dev = DeviceInfo(name="downsampler", kind="serial", mouse="floor", rel_xy=True)
    with NativeWriter(cap, [dev]) as w:
        w.serial_many(0, [t for t, _ in run.raw], [b for _, b in run.raw])
        w.sync(run.raw[-1][0])
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "model: diff-drive\n"
        "mice:\n  floor: {cpi: 1500, mount: {x: 0.1}, serial: {port: /dev/null}}\n"
    )
    p = run_mousedom(
        "calibrate", "cpi", "--config", str(cfg), "--capture", str(cap),
        "--distance", "0.0254", "--gap", "0.15", "--json",
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)["floor"]
    assert doc["runs"] == 4 and doc["axis"] == "y"
    assert doc["stderr"] < 0.5, doc  # the pushes are the same to a count or so
    assert doc["cpi"] == pytest.approx(1600, abs=1.0), doc
