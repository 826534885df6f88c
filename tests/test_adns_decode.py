"""Serial bytes -> reports: axis convention, clock mapping, replay of raw chunks, and
Kim & Lee's velocity (pure; no I/O)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.sources import adns_protocol as P
from mousedom.sources.adns_decode import AdnsDecoder, kim_lee_velocity, packets_to_reports


def motion(seq, t_us, dx, dy, flags=P.FLAG_RES1600, frames=12):
    return P.encode_packet(P.Motion(seq, t_us, dx, dy, frames, 80, flags))


def test_kim_lee_eq50():
    """Kim & Lee eq. (50): v = (sum CNT_j / CPI) / (K / FPS).  K = 12 frames at 6400 fps
    holding 24 counts at 1600 CPI is 0.015 in in 1.875 ms = 8 in/s."""
    assert kim_lee_velocity(24, 1600, 12, 6400) == pytest.approx(8.0)
    # the downsampler: 12 polls of 1250 us (800 /s), 120 counts at 400 CPI -> 20 in/s
    assert kim_lee_velocity(120, 400, 12, 800) == pytest.approx(20.0)


def test_axes_follow_evdev():
    """Delta_X + (sensor moved right) -> REL_X +; Delta_Y + (moved forward) -> REL_Y -."""
    dec = AdnsDecoder()
    reports, _ = dec.feed(motion(0, 1000, 5, 7), host_t=1.0)
    assert reports.dx.tolist() == [5] and reports.dy.tolist() == [-7]


def test_velocity_uses_frames_and_poll_rate():
    dec = AdnsDecoder()
    dec.feed(P.encode_packet(P.Version(0, 0, 1, 1, 0, 1250, 7372800)), 0.0)
    dec.feed(motion(1, 15000, 160, -80, flags=P.FLAG_RES1600), 0.1)
    vx, vy = dec.health.velocity_ips
    assert vx == pytest.approx(160 / 1600 / (12 / 800))
    assert vy == pytest.approx(-80 / 1600 / (12 / 800))


def test_status_health_and_flags():
    dec = AdnsDecoder()
    dec.feed(
        P.encode_packet(P.Status(0, 0, P.STATE_NO_SENSOR, 0, 0xFF, 0, 12, 1600, 1250, 0, 0, 3)), 0.0
    )
    assert dec.health.sensor == "no-sensor" and dec.health.sensor_retries == 3
    dec.feed(motion(1, 1000, 0, 0, flags=P.FLAG_OVERFLOW | P.FLAG_FAULT), 0.1)
    assert dec.health.overflow_packets == 1 and dec.health.fault_packets == 1
    assert dec.stats()["lost_seq"] == 0


def test_reboot_resets_the_clock():
    dec = AdnsDecoder()
    r1, _ = dec.feed(motion(0, 5_000_000, 1, 0) + motion(1, 5_015_000, 1, 0), 100.0)
    r2, _ = dec.feed(motion(0, 300_000, 1, 0, flags=P.FLAG_BOOT), 101.0)
    assert dec.health.clock_resets == 1 and dec.parser.stats.reboots == 1
    assert r2.t[0] == pytest.approx(101.0)  # mapped afresh, not 4.7 s in the past
    assert r2.t[0] >= r1.t[-1]


@settings(max_examples=50, deadline=None, derandomize=True)
@given(st.lists(st.integers(1, 40), min_size=1, max_size=30))
def test_replay_is_independent_of_chunking(cuts):
    """packets_to_reports gives the same counts whatever the read sizes were, and the
    total equals what was sent (counts are never lost)."""
    wire = b"".join(motion(i, i * 15000, i - 10, 2 * i) for i in range(40))
    chunks, pos, t = [], 0, 50.0
    for c in cuts * 10:
        if pos >= len(wire):
            break
        chunks.append((t, wire[pos : pos + c]))
        pos += c
        t += 0.001
    if pos < len(wire):
        chunks.append((t, wire[pos:]))
    reports, dec = packets_to_reports(chunks, name="adns0")
    assert reports.mouse == "adns0"
    assert len(reports) == 40
    assert reports.dx.sum() == sum(i - 10 for i in range(40))
    assert reports.dy.sum() == -sum(2 * i for i in range(40))
    assert np.all(np.diff(reports.t) >= 0)
    assert dec.lost == 0


def test_replay_of_nothing():
    reports, dec = packets_to_reports([])
    assert len(reports) == 0 and dec.lost == 0


def test_replay_decoder_hook_for_capture_batches():
    """The replay engine's hook: one decoder per recorded port, fed batch by batch."""
    from mousedom.config import Mount, MouseConfig, SerialSource
    from mousedom.sources.adns import replay_decoder

    m = MouseConfig("floor", 1600, 1600, Mount(), serial=SerialSource("/dev/null"))
    dec = replay_decoder(m)
    wire = b"".join(motion(i, i * 15000, 1, 2) for i in range(10))
    half = len(wire) // 2
    r1 = dec.feed_many(np.array([1.0, 1.1]), [wire[:7], wire[7:half]])
    r2 = dec.feed_many(np.array([1.2]), [wire[half:]])
    assert r1.mouse == "floor" and len(r1) + len(r2) == 10
    assert r1.dx.sum() + r2.dx.sum() == 10 and r1.dy.sum() + r2.dy.sum() == -20


@pytest.mark.parametrize("seed", range(10))
def test_packets_lost_on_the_line_mark_the_next_report_for_the_span_they_held(seed):
    """Packets that never arrived held counts nobody knows: not none, as a mouse that
    does not report did not move.  The first motion report after a loss says counts were
    lost since the last packet that arrived (its quality's lost_from), and the screen's
    evidence gates the mouse in every window from then to it; reports without a loss
    before them say nothing."""
    from mousedom.fusion.evidence import SensorEvidence

    rng = np.random.default_rng(seed)
    n = 200
    dropped = set(rng.choice(np.arange(1, n), size=int(rng.integers(1, 12)), replace=False))
    for k in list(dropped):  # runs of losses, some
        if rng.random() < 0.3:
            dropped.update(range(k, min(n - 1, k + int(rng.integers(1, 20)))))
    wire = [(i, motion(i, 1_000_000 + i * 15000, 1, 1)) for i in range(n)]
    dec = AdnsDecoder()
    t, overflow, lost_from = [], [], []
    for i, w in wire:  # each read as it arrives, 2 ms after it was sent
        if i not in dropped:
            r, _ = dec.feed(w, host_t=20.0 + i * 0.015 + 0.002)
            t += r.quality[0]
            overflow += r.quality[2]
            lost_from += r.lost_from
    assert len(t) == n - len(dropped) and dec.lost == len(dropped)
    kept = [i for i in range(n) if i not in dropped]
    for k, i in enumerate(kept):
        after_loss = k > 0 and i - kept[k - 1] > 1
        assert overflow[k] == after_loss and (lost_from[k] is not None) == after_loss
        if after_loss:
            assert lost_from[k] == t[k - 1]
    ev = SensorEvidence([0.015], [None])
    ev.push(0, t, [None] * len(t), overflow, lost_from)
    edges = np.arange(t[0], t[-1], 0.01)
    _, low = ev.windows(edges)
    for k in range(len(kept)):
        if lost_from[k] is not None:  # every window inside the lost span is gated
            inside = (edges[:-1] >= lost_from[k]) & (edges[1:] <= t[k])
            assert low[inside, 0].all()
