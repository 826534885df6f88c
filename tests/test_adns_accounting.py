"""ADNS line accounting: every packet the downsampler sent and the host did not get is
counted once in ``lost_seq`` (and ``dropped``), whatever lost it (a damaged frame, a reset
mid-frame, a reboot, the sequence wrap, a reconnect); a repeated frame is taken once; the
counters add up over reopens; and a capture's reopen marker makes replay what live was.

The property test plays a firmware (boots, sequence and clock wraps) through a hostile
line (lost, damaged, cut, repeated frames, noise, reopens, any read sizes) and holds the
counters to what was delivered."""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.capture import DeviceInfo, NativeWriter, open_capture
from mousedom.sources import adns_protocol as P
from mousedom.sources.adns_decode import AdnsDecoder, packets_to_reports

WRAP = 1 << 32


def motion(seq, t_us, dx=1, flags=P.FLAG_RES1600):
    return P.encode_packet(P.Motion(seq, t_us, dx, 0, 12, 80, flags))


def status(seq, t_us):
    return P.encode_packet(
        P.Status(seq, t_us, P.STATE_OK, P.REASON_BOOT, 0x17, 0x19, 12, 1600, 1250, 0, 0, 0)
    )


def damaged(frame: bytes, at: int = 5) -> bytes:
    out = bytearray(frame)
    out[at] ^= 0x01
    return bytes(out)


# ----------------------------------------------------------------- the reviewer's cases


def test_one_damaged_packet_is_one_lost_packet():
    """A frame refused by its CRC also leaves a sequence gap: one loss, not two."""
    frames = [motion(i, 15000 * (i + 1)) for i in range(10)]
    frames[4] = damaged(frames[4])
    dec = AdnsDecoder()
    reports, _ = dec.feed(b"".join(frames), 1.0)
    s = dec.parser.stats
    assert len(reports) == 9 and s.crc_errors == 1  # the reason
    assert s.lost_seq == 1 and dec.lost == 1  # the loss, once


def test_a_reboot_whose_first_packet_is_lost_is_not_65000_losses():
    dec = AdnsDecoder()
    dec.feed(b"".join(motion(i, 15000 * (i + 1)) for i in range(5000)), 1.0)
    wire = (
        damaged(status(0, 300_000), 3) + motion(1, 315_000, flags=P.FLAG_BOOT) + motion(2, 330_000)
    )
    reports, _ = dec.feed(wire, 200.0)
    s = dec.parser.stats
    assert s.reboots == 1 and dec.health.clock_resets == 1
    assert s.lost_seq == 1 and dec.lost == 1  # packet 0 of the new boot
    assert len(reports) == 2 and reports.t[0] == pytest.approx(200.0)


def test_a_reset_mid_frame_costs_the_first_packet_of_the_boot_only():
    """The host holds half a frame when the device resets: that half and the boot's
    STATUS seq 0 make one refused frame (the firmware's leading 0x00 avoids even that,
    test_firmware_sim.py), and the restart is recognised, not 65436 losses."""
    dec = AdnsDecoder()
    dec.feed(b"".join(motion(i, 15000 * (i + 1)) for i in range(100)), 1.0)
    dec.feed(motion(100, 15000 * 101)[:9] + status(0, 300_000) + motion(1, 315_000), 5.0)
    s = dec.parser.stats
    assert s.reboots == 1 and s.lost_seq == 1 and s.crc_errors + s.bad_frames == 1
    # and with the boot's delimiter, nothing of the new boot is lost
    dec = AdnsDecoder()
    dec.feed(b"".join(motion(i, 15000 * (i + 1)) for i in range(100)), 1.0)
    dec.feed(motion(100, 15000 * 101)[:9] + b"\0" + status(0, 300_000) + motion(1, 315_000), 5.0)
    assert dec.parser.stats.reboots == 1 and dec.parser.stats.lost_seq == 0


def test_a_reboot_after_half_the_clock_range_is_a_reboot():
    """After 40 minutes t_us is past 2**31: a reboot's small clock looks like a forward
    wrap of 31 minutes, which the host saw take one second.  It is a restart, and the
    parser and the clock mapping agree on it."""
    dec = AdnsDecoder()
    t0 = 40 * 60 * 1_000_000
    for i in range(100):
        dec.feed(motion(1000 + i, t0 + 15000 * i), 1000.0 + 0.015 * i)
    dec.feed(status(0, 300_000) + motion(1, 315_000, flags=P.FLAG_BOOT), 1003.0)
    assert dec.parser.stats.reboots == 1 and dec.health.clock_resets == 1
    assert dec.parser.stats.lost_seq == 0
    # a real wrap of the clock is no reboot
    dec = AdnsDecoder()
    for i in range(10):
        dec.feed(motion(i, (WRAP - 60_000 + 15000 * i) % WRAP), 1.0 + 0.015 * i)
    assert dec.parser.stats.reboots == 0 and dec.health.clock_resets == 0


def test_stats_keep_the_decoders_and_the_parsers_counters_apart():
    """``stats()`` merges the sensor health and the parser counters: no name may be in
    both, or one hides the other (both had ``reboots``)."""
    dec = AdnsDecoder()
    assert not set(dec.health.as_dict()) & set(dec.parser.stats.as_dict())
    dec.feed(motion(0, 5_000_000) + motion(1, 5_015_000), 1.0)
    dec.feed(motion(0, 300_000, flags=P.FLAG_BOOT), 2.0)
    stats = dec.stats()
    assert stats["reboots"] == 1 and stats["clock_resets"] == 1


def test_a_loss_at_the_sequence_wrap_is_a_loss():
    dec = AdnsDecoder()
    seqs = [65533, 65534, 0, 1]  # 65535 lost
    dec.feed(b"".join(motion(s, 1000 + 15000 * i) for i, s in enumerate(seqs)), 1.0)
    assert dec.parser.stats.lost_seq == 1 and dec.parser.stats.reboots == 0


def test_a_repeated_frame_is_taken_once():
    dec = AdnsDecoder()
    wire = motion(5, 100_000, 10) + motion(6, 115_000, 10) * 2 + motion(7, 130_000, 10)
    reports, packets = dec.feed(wire, 1.0)
    assert reports.dx.sum() == 30 and [p.seq for p in packets] == [5, 6, 7]
    s = dec.parser.stats
    assert s.duplicates == 1 and s.lost_seq == 0 and s.reboots == 0


def test_reopen_drops_the_partial_frame_and_keeps_counters_and_sequence():
    """A reopen of the port: the half frame read before is gone (it cannot begin the
    next one), the counters carry on, and the packets sent while the port was closed are
    lost by sequence."""
    dec = AdnsDecoder()
    frames = [motion(i, 15000 * (i + 1), 10) for i in range(30)]
    frames[3] = damaged(frames[3])
    dec.feed(b"".join(frames[:20]) + frames[20][:10], 1.0)  # unplugged mid-frame
    dec.reopen()
    reports, _ = dec.feed(b"".join(frames[25:]), 2.0)  # 21..24 sent while unplugged
    s = dec.parser.stats
    assert len(reports) == 5  # frame 25 read whole, not swallowed by the stale half
    assert s.crc_errors == 1 and s.reopens == 1
    assert s.lost_seq == 1 + 5 and dec.lost == 6  # 3 (damaged), 20 (cut), 21..24
    assert dec.health.motion_packets == 19 + 5


def test_a_capture_reopen_marker_replays_as_live(tmp_path):
    """``AdnsSource`` hands ``on_raw`` an empty chunk when it reopens the port: stored in
    a native capture (an empty piece of a SERIAL chunk, readable by any reader), replay
    reopens there as live did; without it, the stale half frame swallows the next frame."""
    frames = [motion(i, 15000 * (i + 1), 10) for i in range(40)]
    chunks = [(1.0 + 0.015 * i, frames[i]) for i in range(20)]
    chunks.append((1.31, frames[20][:10]))
    chunks.append((1.6, b""))  # reopened
    chunks += [(1.6 + 0.015 * i, frames[i]) for i in range(21, 40)]
    live = AdnsDecoder(name="floor")
    live_dx = []
    for t, d in chunks:
        if d:
            live_dx += live.feed(d, t)[0].dx.tolist()
        else:
            live.reopen()
    p = tmp_path / "r.mdcap"
    dev = DeviceInfo(name="downsampler", kind="serial", mouse="floor")
    with NativeWriter(p, [dev]) as w:
        w.serial_many(0, [t for t, _ in chunks], [d for _, d in chunks])
    cap = open_capture(p)
    stored = [
        (float(t), bytes(d))
        for f in cap.feeds()
        for b in f.batches
        for s in b.serial
        for t, d in zip(s.t, s.data, strict=True)
    ]
    assert stored == chunks
    replayed, dec = packets_to_reports(stored, name="floor")
    assert replayed.dx.tolist() == live_dx and len(live_dx) == 39
    assert dec.parser.stats.as_dict() == live.parser.stats.as_dict()
    assert dec.lost == 1  # packet 20, cut by the unplug
    # the same bytes without the marker: the half frame takes frame 21 with it
    unmarked, _ = packets_to_reports([c for c in chunks if c[1]], name="floor")
    assert len(unmarked) == 38


# ----------------------------------------------------------------- property test


def firmware(rng: random.Random) -> list[tuple[int, P.Packet, float]]:
    """What a downsampler sends: (boot, packet, host arrival time).  The first boot is
    joined anywhere (sequence and clock may wrap in it); later boots begin at seq 0 with
    STATUS, their first MOTION flagged BOOT, 0.3 s after their reset."""
    out = []
    boots = rng.choice([1, 1, 2, 3])
    host = 100.0
    uid = 0
    for b in range(boots):
        n = rng.randrange(80, 200)
        if b == 0:
            seq = rng.choice([rng.randrange(65536), 65536 - rng.randrange(1, 60)])
            if boots == 1 and rng.random() < 0.5:
                t = WRAP - 15000 * rng.randrange(1, 60)  # the clock wraps in this boot
            else:
                # (a reboot 10 s or less after a wrap of the clock is not told from a
                # gap of 10 s: no reboot follows a clock that close to its wrap)
                t = rng.randrange(10_000_000, WRAP - 30_000_000)
        else:
            seq, t = 0, 300_000 + 1000 * b
            host += 0.3 + rng.random()
        start = t
        for i in range(n):
            h = host + ((t - start) % WRAP) * 1e-6 + 0.001 + 0.002 * rng.random()
            if b > 0 and i == 0:
                p: P.Packet = P.Status(seq, t, 1, 0, 0x17, 0x19, 12, 1600, 1250, 0, 0, 0)
            else:
                flags = P.FLAG_RES1600 | (P.FLAG_BOOT if b > 0 and i == 1 else 0)
                uid += 1
                p = P.Motion(seq, t, uid, -uid % 50, 12, 80, flags)
            out.append((b, p, h))
            seq = (seq + 1) % 65536
            t = (t + 15000) % WRAP
        host = out[-1][2]
    return out


def hostile_line(rng: random.Random, sent) -> list[tuple[float, bytes]]:
    """The sent frames through a bad line, as reads (host time, bytes) of any size, with
    reopen markers (empty reads) now and then."""
    segments: list[tuple[bytes, float]] = []
    for _, p, h in sent:
        frame = P.encode_packet(p)
        r = rng.random()
        if r < 0.05:
            continue  # lost (an overrun, an unplug)
        if r < 0.10:
            frame = bytearray(frame)
            frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)  # any byte, 0x00 too
            frame = bytes(frame)
        elif r < 0.13:
            frame = frame[: rng.randrange(1, len(frame))]  # cut short: runs into the next
        elif r < 0.16:
            frame = frame * 2  # repeated
        if rng.random() < 0.03:
            noise = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
            frame = noise + (b"\0" if rng.random() < 0.5 else b"") + frame
        segments.append((frame, h))
    chunks: list[tuple[float, bytes]] = []
    for frame, h in segments:
        pos = 0
        while pos < len(frame):
            n = rng.randrange(1, 40)
            chunks.append((h, frame[pos : pos + n]))
            pos += n
            if rng.random() < 0.005:
                chunks.append((h, b""))  # the port reopened here
    return chunks


def expected(sent, delivered_keys: list[tuple[int, int]]) -> tuple[int, int]:
    """Losses and reboots knowable from what arrived: in the first boot seen, the packets
    between the first and the last that arrived; in each later boot seen, those from its
    seq 0 to the last that arrived.  What a boot sent after its last packet that arrived
    is unknowable."""
    index = {(p.seq, p.t_us): (b, i) for i, (b, p, _) in enumerate(sent)}
    boot_start = {}
    for i, (b, _, _) in enumerate(sent):
        boot_start.setdefault(b, i)
    per_boot: dict[int, list[int]] = {}
    for k in delivered_keys:
        b, i = index[k]
        per_boot.setdefault(b, []).append(i - boot_start[b])
    lost = 0
    for n, b in enumerate(sorted(per_boot)):
        got = per_boot[b]
        first = got[0] if n == 0 else 0
        lost += got[-1] - first + 1 - len(got)
    return lost, len(per_boot) - 1


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_every_lost_packet_is_counted_once(seed):
    rng = random.Random(seed)
    sent = firmware(rng)
    chunks = hostile_line(rng, sent)
    reports, dec = packets_to_reports(chunks, name="floor")
    # what arrived: sent packets, each once, in order, unaltered
    by_key = {(p.seq, p.t_us): p for _, p, _ in sent}
    got = []
    live = AdnsDecoder(name="floor")  # the same bytes read live: same packets and counts
    for t, d in chunks:
        if d:
            got += live.feed(d, t)[1]
        else:
            live.reopen()
    keys = [(p.seq, p.t_us) for p in got]
    assert len(set(keys)) == len(keys), "a packet taken twice"
    order = {k: i for i, k in enumerate(by_key)}
    assert [order[k] for k in keys] == sorted(order[k] for k in keys)
    for p in got:  # unaltered (but for the host time the parser stamps)
        assert {**p.__dict__, "host_t": None} == by_key[(p.seq, p.t_us)].__dict__
    lost, reboots = expected(sent, keys)
    s = dec.parser.stats
    assert (s.lost_seq, s.reboots) == (lost, reboots)
    assert dec.lost == lost and dec.health.clock_resets == reboots
    assert s.packets == len(got)
    assert live.parser.stats.as_dict() == s.as_dict()
    # every count that arrived is reported once
    motion_dx = sum(p.dx for p in got if isinstance(p, P.Motion))
    assert reports.dx.sum() == motion_dx
    assert np.all(np.diff(reports.t) >= 0)


@pytest.mark.parametrize("kept_s, dropped", [(45.0, 1000), (5.0, 40), (0.5, 300)])
def test_a_loss_read_after_a_stall_is_a_loss_not_a_restart(kept_s, dropped):
    """A daemon stalled (SIGSTOP, a VM paused) while the device sent on: the port kept the
    oldest ``kept_s`` of packets and the kernel dropped the next ``dropped``; read after the
    stall, the packets on either side of the hole arrive milliseconds apart though they
    were sent seconds apart.  That was taken for a restart (the clock "further ahead than
    the host went"): 44,000 packets counted lost for 1,000, the clock mapping begun again.
    When the last packet was sent is its firmware time on the clock's earliest arrival."""
    dec = AdnsDecoder()
    k_us, live = 15000, 2000
    for s in range(live):  # read live, as sent
        dec.feed(motion(s, 300_000 + k_us * s), 100.0 + s * 0.015)
    kept = int(kept_s / 0.015)
    t = 100.0 + live * 0.015 + kept_s + dropped * 0.015 + 5.0  # read 5 s after the last sent
    backlog = b"".join(motion(s, 300_000 + k_us * s) for s in range(live, live + kept))
    for i in range(0, len(backlog), 4095):
        dec.feed(backlog[i : i + 4095], t)
        t += 0.001
    first = live + kept + dropped
    for s in range(first, first + 20):
        dec.feed(motion(s, 300_000 + k_us * s), t)
        t += 0.015
    stats = dec.parser.stats
    assert (stats.lost_seq, stats.reboots, dec.health.clock_resets) == (dropped, 0, 0)
    # a restart read the same way is still one (its clock begins again)
    dec.feed(status(0, 300_000) + motion(1, 315_000, flags=P.FLAG_BOOT), t + 1.0)
    assert dec.parser.stats.reboots == 1


def _boot(dec: AdnsDecoder, first_seq: int, n: int, t: float, boot: bool) -> tuple[float, list]:
    """``n`` motion packets of 50 counts, K = 12 (15 ms apart), from ``first_seq``."""
    marks = []
    for k in range(n):
        seq = first_seq + k
        flags = P.FLAG_RES1600 | (P.FLAG_BOOT if boot and k == 0 else 0)
        data = (b"\0" if boot and k == 0 else b"") + P.encode_packet(
            P.Motion(seq, 15000 * (seq + 1), 50, 0, 12, 90, flags)
        )
        r, _ = dec.feed(data, t)
        marks += list(zip(r.quality[2], r.lost_from, strict=True)) if len(r) else []
        t += 0.015
    return t, marks


@pytest.mark.parametrize("lost_on_the_line", [0, 1, 3])
@pytest.mark.parametrize("gap_s", [0.05, 0.2, 2.0])
def test_a_firmware_restart_marks_the_counts_it_lost(lost_on_the_line, gap_s):
    """A board reset (a brown-out) loses what the firmware had summed and not sent, and the
    old boot's last packets if they never arrived.  The first motion report after it was
    not marked (overflow False, lost_from None) where the same packets lost without a
    restart were: the fusion read the gap as the mouse standing still (11 of 11 resets of
    the real firmware while moving, 4 to 396 counts).  Now it says the counts since the
    old boot's last packet that arrived are unknown."""
    dec = AdnsDecoder(name="a")
    t, marks = _boot(dec, 0, 10, 100.0, boot=True)
    assert not any(overflow for overflow, _ in marks)
    last = dec._last_t
    t += 0.015 * lost_on_the_line + gap_s
    _, marks = _boot(dec, 0, 3, t, boot=True)
    assert dec.parser.stats.reboots == 1
    assert marks[0] == (True, last), marks
    assert not any(overflow for overflow, _ in marks[1:])
