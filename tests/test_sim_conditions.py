"""Simulated conditions that are not faults (issue 31): USB polling gaps, long-tailed
arrival stamps, and the scenario builders of the benches (conditions, pair faults, the
runs side by side).  These hold the simulator and the builders, not the engine's quality:
the engine's targets are bench/robust.py's."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mousedom.fusion import sim

DRIVE = 12.0


def _drive(seed: int = 0) -> list[sim.Segment]:
    from mousedom.fusion import scenarios

    return scenarios.drive(DRIVE, seed)


def _square(**first) -> sim.Rig:
    from mousedom.fusion import scenarios

    rig = scenarios.rig("square")
    return dataclasses.replace(
        rig, mice=(dataclasses.replace(rig.mice[0], **first),) + rig.mice[1:]
    )


def _missed(t: np.ndarray, gaps) -> np.ndarray:
    out = np.zeros(len(t), dtype=bool)
    for a, b in gaps:
        out |= (t >= a) & (t < b)
    return out


# --------------------------------------------------------------------------- USB gaps


def test_gap_spans_are_a_poisson_process_of_the_asked_rate_and_length():
    gaps = sim.usb_gap_spans(3, 2000.0, 2.0, 0.03, jitter=0.5)
    starts = np.array([a for a, _ in gaps])
    lengths = np.array([b - a for a, b in gaps])
    assert np.all(np.diff(starts) > 0) and np.all(starts[1:] > starts[:-1] + lengths[:-1])
    assert len(gaps) / 2000.0 == pytest.approx(2.0 / (1 + 2.0 * 0.03), rel=0.1)
    assert lengths.min() >= 0.015 - 1e-12 and lengths.max() <= 0.045 + 1e-12
    assert lengths.mean() == pytest.approx(0.03, rel=0.05)
    assert sim.usb_gap_spans(3, 10.0, 2.0, 0.03) == sim.usb_gap_spans(3, 10.0, 2.0, 0.03)
    assert sim.usb_gap_spans(3, 10.0, 0.0, 0.03) == ()
    assert all(b - a == pytest.approx(0.03) for a, b in sim.usb_gap_spans(4, 10.0, 2.0, 0.03))


@pytest.mark.parametrize("seed", range(5))
def test_gaps_lose_no_counts_and_deliver_them_after_the_gap(seed):
    gaps = sim.usb_gap_spans(seed, DRIVE, 5.0, 0.05, jitter=0.4)
    traj = _drive(seed)
    clean = sim.simulate(_square(stamp_delay=0.0), traj, seed=seed)
    gapped = sim.simulate(_square(stamp_delay=0.0, usb_gaps=gaps), traj, seed=seed)
    a, b = clean.reports["fl"], gapped.reports["fl"]
    # Counts are never lost: the totals equal the gap-free ones exactly, in whole counts.
    assert b.dx.sum() == a.dx.sum() and b.dy.sum() == a.dy.sum()
    assert np.all(b.dx == np.round(b.dx)) and np.all(b.dy == np.round(b.dy))
    # No report inside a gap; fewer reports than without.
    assert not _missed(b.t, gaps).any() and len(b.t) < len(a.t)

    def upto(r: sim.SimReports, t: float) -> tuple[float, float]:
        sel = r.t <= t + 1e-9
        return float(r.dx[sel].sum()), float(r.dy[sel].sum())

    # At every report, all counts measured so far have arrived: nothing late past a poll.
    for t in b.t[:: max(1, len(b.t) // 200)]:
        assert upto(b, t) == upto(a, t)
    # Each gap's counts arrive in the first slot polled at or after its end.
    slot = 1.0 / 125  # the square's first mouse: 125 Hz, phase 0
    held_somewhere = False
    for lo, hi in gaps:
        k = math.ceil(hi / slot - 1e-9)
        while _missed(np.array([k * slot]), gaps)[0]:
            k += 1
        catch = k * slot
        before = upto(a, float(b.t[b.t < lo][-1])) if np.any(b.t < lo) else (0.0, 0.0)
        held = np.subtract(upto(a, catch), before)
        if np.any(held != 0):
            held_somewhere = True
            i = int(np.argmin(np.abs(b.t - catch)))
            assert b.t[i] == pytest.approx(catch, abs=1e-9)
            assert (b.dx[i], b.dy[i]) == tuple(held)
    assert held_somewhere
    # The other mice read exactly as without the gaps (same noise, same stamps).
    for name in ("fr", "rl", "rr"):
        for k_ in ("t", "dx", "dy"):
            assert np.array_equal(
                getattr(clean.reports[name], k_), getattr(gapped.reports[name], k_)
            )


def test_gaps_leave_the_other_mice_and_the_totals_alone_with_late_stamps():
    gaps = sim.usb_gap_spans(9, DRIVE, 4.0, 0.03)
    clean = sim.simulate(_square(), _drive(2), seed=2)
    gapped = sim.simulate(_square(usb_gaps=gaps), _drive(2), seed=2)
    a, b = clean.reports["fl"], gapped.reports["fl"]
    assert (b.dx.sum(), b.dy.sum()) == (a.dx.sum(), a.dy.sum())
    assert np.all(np.diff(b.t) >= 0)
    for name in ("fr", "rl", "rr"):
        assert np.array_equal(clean.reports[name].dy, gapped.reports[name].dy)
        assert np.array_equal(clean.reports[name].t, gapped.reports[name].t)


def test_a_gap_holds_a_whole_leg_and_delivers_it_in_one_catch_up_report():
    mouse = sim.SimMouse("a", 0.1, 0.0, usb_gaps=((0.1, 0.5),))
    r = sim.simulate(sim.Rig((mouse,)), sim.straight(0.2, 0.2), seed=0).reports["a"]
    plain = sim.simulate(
        sim.Rig((dataclasses.replace(mouse, usb_gaps=()),)), sim.straight(0.2, 0.2)
    )
    a = plain.reports["a"]
    assert not np.any((r.t >= 0.1) & (r.t < 0.5))
    k = int(np.searchsorted(r.t, 0.5))
    assert r.t[k] == pytest.approx(0.504)  # the first 125 Hz slot at or after the gap's end
    held = a.dy[(a.t >= 0.1) & (a.t <= 0.504 + 1e-9)].sum()
    assert r.dy[k] == held and abs(held) > 50
    assert r.dy.sum() == a.dy.sum()


def test_a_gap_past_the_end_delivers_the_counts_at_the_next_slot_polled():
    mouse = sim.SimMouse("a", 0.1, 0.0, quantize=False, usb_gaps=((0.5, 3.0),))
    r = sim.simulate(sim.Rig((mouse,)), sim.straight(0.2, 0.2)).reports["a"]
    assert r.t[-1] == pytest.approx(3.0)
    assert r.dy.sum() == pytest.approx(-0.2 / 0.0254 * 450)


# --------------------------------------------------------------------------- stamps


@pytest.mark.parametrize("seed", range(3))
def test_long_tailed_stamps_stay_ordered_and_late(seed):
    traj = _drive(seed)
    clean = sim.simulate(_square(), traj, seed=seed)
    late = sim.simulate(_square(stamp_tail=0.003), traj, seed=seed)
    a, b = clean.reports["fl"], late.reports["fl"]
    assert np.all(np.diff(b.t) >= 0)
    assert np.array_equal(a.dx, b.dx) and np.array_equal(a.dy, b.dy)
    assert np.all(b.t >= a.t)
    assert np.mean(b.t - a.t) == pytest.approx(0.003, rel=0.35)
    assert np.max(b.t - a.t) > 0.01  # the tail: some reports far late
    for name in ("fr", "rl", "rr"):
        assert np.array_equal(clean.reports[name].t, late.reports[name].t)


def test_a_tail_without_uniform_delay_is_still_monotone():
    mouse = sim.SimMouse("a", 0.1, 0.0, rate_hz=1000.0, stamp_tail=0.005)
    r = sim.simulate(sim.Rig((mouse,)), sim.straight(0.3, 0.2), seed=1).reports["a"]
    assert np.all(np.diff(r.t) >= 0) and np.any(np.diff(r.t) == 0)


def test_defaults_give_the_same_reports_as_before():
    """Figures of the simulator before the timing conditions existed (same seed, same
    drive): with the new imperfections off, every draw and every report is unchanged."""
    res = sim.simulate(_square(), _drive(7), seed=7)
    for name, (n, sx, sy, head, last) in REFERENCE.items():
        r = res.reports[name]
        assert (len(r.t), r.dx.sum(), r.dy.sum()) == (n, sx, sy)
        assert r.t[:3].tolist() == head and r.t[-1] == last


REFERENCE = {
    "fl": (1339, -5738.0, -62762.0,
           [0.5043068560286508, 0.5120102650647035, 0.5205327987942265], 11.216739608616042),
    "rl": (10681, 5741.0, -62776.0,
           [0.5015383481521813, 0.5024542234499466, 0.5034205105182337], 11.213536655092067),
}  # fmt: skip
