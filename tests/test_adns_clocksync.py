"""Firmware microseconds -> host monotonic time: minimum offset with drift (pure)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.sources.clocksync import WRAP, ClockSync, FirmwareClock


def run(sync, f, host):
    return np.array([sync.update(a, b) for a, b in zip(f, host, strict=True)])


def test_constant_delay_gives_the_offset_exactly():
    f = np.arange(0, 20, 0.015)
    host = 1000.0 + f + 0.004  # offset 1000 s, every packet 4 ms late
    out = run(ClockSync(), f, host)
    # With no jitter the minimum offset includes the constant 4 ms: it cannot be told
    # apart from the offset, and the mapped times are the arrival times.
    np.testing.assert_allclose(out, host, atol=1e-9)


def test_jitter_is_removed_and_drift_tracked():
    """100 ppm drift, delays 1..20 ms (exponential): the estimate follows the fastest
    packets, so its error is about the minimum delay, not the mean."""
    rng = np.random.default_rng(1)
    f = np.arange(0, 120, 0.015)
    drift = 100e-6
    delay = 0.001 + rng.exponential(0.004, f.size).clip(0, 0.02)
    true_host = 500.0 + f * (1 + drift)
    host = true_host + delay
    sync = ClockSync(window=60.0)
    out = run(sync, f, host)
    late = f > 30  # after the filter has seen enough
    err = out[late] - true_host[late]
    assert np.all(err <= delay[late] + 1e-12)  # never after the arrival
    assert np.median(np.abs(err - 0.001)) < 0.0005  # within 0.5 ms of the 1 ms floor
    assert abs(sync.drift - drift) < 20e-6
    # the mean delay would have been the error of a naive mean-offset filter
    assert np.median(np.abs(err)) < np.mean(delay) / 2


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    st.lists(st.floats(0.0, 0.05), min_size=2, max_size=300),
    st.floats(-300e-6, 300e-6),
)
def test_outputs_monotonic_and_never_after_arrival(delays, drift):
    f = np.arange(len(delays)) * 0.015
    # packets arrive in order: arrival times never decrease
    host = np.maximum.accumulate(10.0 + f * (1 + drift) + np.array(delays))
    out = run(ClockSync(window=2.0, bucket=0.1, min_span=0.5), f, host)
    assert np.all(np.diff(out) >= 0)
    assert np.all(out <= host + 1e-12)


def test_drift_is_clamped():
    f = np.arange(0, 30, 0.01)
    host = f * 1.01  # 1% is no crystal: someone paused the process
    sync = ClockSync(max_drift=1e-3)
    run(sync, f, host)
    assert sync.drift == pytest.approx(1e-3)


def test_reset_forgets():
    sync = ClockSync()
    sync.update(100.0, 200.0)
    sync.reset()
    assert sync.update(0.0, 300.0) == 300.0


def test_firmware_clock_unwraps_32_bits():
    c = FirmwareClock()
    assert c.unwrap(WRAP - 10) == pytest.approx((WRAP - 10) * 1e-6)
    assert c.unwrap(5) == pytest.approx((WRAP + 5) * 1e-6)  # wrapped, not rebooted
    assert not c.is_backwards(6)
    assert c.is_backwards(4)  # a small step back is a reboot, not a wrap


@settings(max_examples=200)
@given(
    st.floats(0.0, 1e5),
    st.floats(1e-6, 1e-2),
    st.floats(0.0, 50.0),
    st.sampled_from([0.0, 1e-9, 1e-4, 1e-2]),  # 0: the next packet came in the same read
)
def test_a_firmware_reboot_never_steps_host_time_back(f_before, delay, f_after, gap):
    """Issue 11 item 8: after a reboot (reset) the fresh fit of one point could map a
    packet 1e-13 s before the last output.  The output is a floor across resets."""
    sync = ClockSync()
    host = 1000.0 + f_before
    outs = [sync.update(f_before + k * 0.01, host + k * 0.01 + delay) for k in range(50)]
    sync.reset()  # the firmware restarted: its clock begins again near 0
    arrival = host + 49 * 0.01 + delay + gap
    outs.append(sync.update(f_after, arrival))
    outs.append(sync.update(f_after + 0.01, arrival + 0.01))
    assert all(b >= a for a, b in zip(outs, outs[1:], strict=False))
    assert outs[-2] <= arrival  # never after the packet's arrival


@settings(max_examples=500)
@given(st.floats(0.0, 4295.0), st.floats(0.0, 4295.0), st.floats(1.0, 1e6))
def test_a_reboot_between_two_packets_of_one_read_keeps_their_order(f1, f2, host):
    """Two packets that came in one read share their arrival time; if the firmware
    rebooted between them, the second one's fresh fit rounds differently (f + (h - f) is
    not always h), and must still not be placed before the first."""
    sync = ClockSync()
    first = sync.update(f1, host)
    sync.reset()
    assert sync.update(f2, host) >= first
