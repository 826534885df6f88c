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
    mouse = sim.SimMouse("a", 0.1, 0.0, report_hz=1000.0, stamp_tail=0.005)
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


# --------------------------------------------------------------------------- drives, layouts


def test_drive_is_as_before_and_its_spans_name_what_it_does():
    from mousedom.fusion import scenarios

    segs = scenarios.drive(60.0, 0)
    assert len(segs) == 254 and sum(s.duration for s in segs) == 60.34921323700254
    assert sum(s.omega * s.duration for s in segs) == -6.143846933415397
    for seed in range(4):
        spans = scenarios.drive_spans(30.0, seed)
        motion = sim.Motion.of(scenarios.drive(30.0, seed))
        assert spans[0].start == 0.0 and spans[-1].end == pytest.approx(motion.duration)
        for sp in spans:
            assert sp.start in motion.starts and sp.end in motion.starts
            k = int(np.searchsorted(motion.starts, sp.start))
            seg = motion.segments[k]
            assert seg.duration == pytest.approx(sp.end - sp.start)
            kind = {(False, False): "stop", (True, False): "straight", (False, True): "turn"}
            assert kind.get((seg.vx != 0, seg.omega != 0), "arc") == sp.kind
    s = scenarios.drive_having("turn", 20.0, 1)
    assert any(sp.kind == "turn" for sp in scenarios.drive_spans(20.0, s))
    with pytest.raises(ValueError):
        scenarios.drive_having("wiggle", 20.0, 1)


def test_the_new_layouts_configure():
    from mousedom.fusion import scenarios

    pent = scenarios.rig("pentagon")
    assert len(pent.mice) == 5
    assert [math.hypot(m.x, m.y) for m in pent.mice] == pytest.approx([0.12] * 5, abs=1e-4)
    assert {m.report_hz for m in pent.mice} == {125.0, 250.0, 500.0, 1000.0}
    assert len(scenarios.rig("kite").mice) == 4
    for layout in ("pentagon", "kite"):
        assert scenarios.config(scenarios.rig(layout)).names == tuple(
            name for name, *_ in scenarios.LAYOUTS[layout]
        )


# --------------------------------------------------------------------------- pair faults


def test_pair_cases_cover_every_two_mice_and_kinds():
    from mousedom.fusion import scenarios

    assert len(scenarios.pair_cases("square")) == 6 * 9
    assert len(scenarios.pair_cases("pentagon")) == 10 * 9
    assert len(set(scenarios.pair_cases("pentagon"))) == 90


@pytest.mark.parametrize("during", ["straight", "arc", "turn"])
def test_pair_faults_overlap_and_start_in_the_stretch_asked(during):
    from mousedom.fusion import scenarios

    base = scenarios.rig("pentagon")
    for kinds in (("lift", "jumps"), ("under-read", "lift"), ("jumps", "under-read")):
        seed = scenarios.drive_having(during, 30.0, 3)
        f1, f2 = scenarios.pair_faults(base, kinds, ("front", "rr"), during, 30.0, seed)
        assert (f1.kind, f2.kind) == kinds and (f1.mouse, f2.mouse) == ("front", "rr")
        first = f1.jumps[0][0] if f1.kind == "jumps" else f1.start
        assert any(
            sp.kind == during and sp.start <= first < sp.end
            for sp in scenarios.drive_spans(30.0, seed)
        )
        assert f2.start < f1.end and f1.start < f2.end  # together for a while
        for f in (f1, f2):
            if f.kind == "jumps":
                assert len(f.jumps) == 4 and f.end - f.start <= 3.02
    with pytest.raises(ValueError):
        scenarios.pair_faults(base, ("lift", "lift"), ("rr", "rr"), during, 30.0, 0)


def test_a_pair_trial_puts_both_faults_on_and_removes_both_for_the_informed():
    from mousedom.fusion import scenarios

    tr = scenarios.pair_trial("square", ("lift", "under-read"), ("fl", "rr"), "arc", 0, 10.0)
    assert len(tr.faults) == 2 and "lift@fl+under-read@rr in arc" in tr.label
    for run in (tr.default, tr.off, tr.informed, tr.clean):
        assert run.windows > 900 and math.isfinite(run.position) and run.nees_dof in (0, 1, 2, 3)
    assert tr.off.position != tr.informed.position  # the informed reference lost the spans


# --------------------------------------------------------------------------- conditions


def test_conditions_by_name_with_defaults_and_overrides():
    from mousedom.fusion import conditions

    gaps = conditions.condition("usb-gaps", seed=4)
    assert 1.0 <= gaps.gap_rate <= 5.0 and gaps.gap_length == 0.03
    assert gaps == conditions.condition("usb-gaps", seed=4)
    assert conditions.condition("usb-gaps", seed=4, gap_rate=2.0).gap_rate == 2.0
    both = conditions.condition("late-stamps+noisy+cpi-error", cpi_error=0.25)
    assert (both.stamp_tail, both.noise_factor, both.cpi_error) == (0.003, 5.0, 0.25)
    assert conditions.condition("stamp-delay").stamp_delay == 0.003
    assert conditions.condition("healthy") == conditions.Condition()
    with pytest.raises(ValueError):
        conditions.condition("usb-gaps+gremlins")


def test_a_condition_acts_on_the_mice_it_says():
    from mousedom.fusion import conditions, scenarios

    base = scenarios.rig("square")  # fl 125 Hz, rl 1000 Hz
    cond = conditions.condition("usb-gaps+late-stamps+noisy+cpi-error", seed=1, cpi_error=0.2)
    true = {m.name: m for m in conditions.apply_condition(base, cond, 30.0).mice}
    was = {m.name: m for m in base.mice}
    assert true["fl"].usb_gaps and not any(true[n].usb_gaps for n in ("fr", "rl", "rr"))
    assert all(b - a == pytest.approx(0.03, rel=0.31) for a, b in true["fl"].usb_gaps)
    assert true["rl"].stamp_tail == 0.003 and true["fl"].stamp_tail == 0.0
    assert true["fl"].noise == pytest.approx(5 * was["fl"].noise)
    assert true["fl"].cpi_x == pytest.approx(1.2 * was["fl"].cpi_x) and true["fr"] == was["fr"]
    cfg = conditions.condition_config(base, cond)
    told = conditions.condition_config(base, cond, robust=False, told=True)
    assert cfg.mouse("fl").cpi_x == was["fl"].cpi_x and cfg.robust.enabled
    assert told.mouse("fl").cpi_x == pytest.approx(true["fl"].cpi_x) and not told.robust.enabled
    assert cfg.mouse("fl").sigma == told.mouse("fl").sigma  # the config keeps its sigma
    other = conditions.condition("noisy", noise_mouse="rr", noise_factor=3.0)
    moved = {m.name: m for m in conditions.apply_condition(base, other, 30.0).mice}
    assert moved["rr"].noise == pytest.approx(3 * was["rr"].noise) and moved["fl"] == was["fl"]
    with pytest.raises(ValueError):
        conditions.apply_condition(base, conditions.condition("noisy", noise_mouse="zz"), 30.0)


def test_condition_trials_run_four_ways():
    from mousedom.fusion import conditions

    healthy = conditions.condition_trial("triangle", "healthy", 2, 8.0)
    assert healthy.default == healthy.clean  # the same drive, the same engine
    cpi = conditions.condition_trial("triangle", "cpi-error", 2, 8.0)
    assert cpi.clean == healthy.clean and cpi.default != cpi.clean
    assert cpi.informed.windows == cpi.off.windows
    gaps = conditions.condition_trial(
        "triangle", conditions.condition("usb-gaps", seed=2, gap_rate=5.0), 2, 8.0
    )
    # Without the gaps, and plain: the informed reference is the healthy drive, robust off.
    assert gaps.informed == conditions.condition_trial("triangle", "healthy", 2, 8.0).off


# --------------------------------------------------------------------------- measuring


def test_nees_inverts_the_covariance_where_it_can():
    from mousedom.fusion import scenarios

    assert scenarios.nees(np.array([1.0, 0, 0]), np.diag([4.0, 1, 1])) == (0.25, 3)
    p = np.array([[2.0, 1.0, 0], [1.0, 2.0, 0], [0, 0, 1e-4]])
    e = np.array([0.3, -0.2, 0.01])
    assert scenarios.nees(e, p)[0] == pytest.approx(float(e @ np.linalg.solve(p, e)))
    value, dof = scenarios.nees(np.array([1.0, 1.0, 5.0]), np.diag([1.0, 1.0, 0.0]))
    assert (value, dof) == (2.0, 2)  # nothing known of theta: its error left out
    value, dof = scenarios.nees(np.ones(3), np.zeros((3, 3)))
    assert math.isnan(value) and dof == 0


def test_exclusions_count_windows_a_mouse_newly_went_out():
    from types import SimpleNamespace

    from mousedom.fusion import robust, scenarios

    ex, ok = robust.EXCLUDED, robust.TRACKING
    state = np.array([[ok, ok], [ex, ok], [ex, ex], [ok, ex], [ex, ex]])
    batch = SimpleNamespace(state=state, consistent=np.array([True, False, True, True, True]))
    assert scenarios.exclusions(batch) == (3, 1)
