"""Mice stamped 0-4 ms late (DESIGN.md: "stamps arrive a few ms late") with a gyro: the
gyro's judge learns how far the rig's timing exceeds the config's rho (fusion/stampspread.py,
against the gyro; and each mouse's factor from the fault screen's noise model, where three
or more mice give one) instead of taking healthy windows for faults and learning its bias
and scale from the few that pass.

Before, on these drives: three mice's end heading with the gyro a median of 1.5 degrees
(0.15 without), four 0.24, five 0.58, and a pair up to 22.6 degrees (the gyro's scale
learnt 7.5 % off); then a pair 1.0 against 0.19 (the healthy windows judged before its
factor was used, 3 s in, taught the scale).  One mouse's factor is now learnt against its
sideways counts (GyroJudge.stamp_var), and with stamps 0-4 ms late its 24 drives of
docs/gyro.md end 0.23 degree off in median with the gyro, 0.38 without."""

from __future__ import annotations

import dataclasses
import math
import statistics

import numpy as np
import pytest

from mousedom.fusion import scenarios, sim, simgyro, stampspread
from mousedom.fusion.drives import drive

LATE_S = 0.004


def _heading_error(layout: str, model: str, seed: int, late: float, gyro: bool) -> float:
    rig = dataclasses.replace(scenarios.rig(layout), model=model)
    rig = dataclasses.replace(
        rig,
        mice=tuple(dataclasses.replace(m, stamp_delay=late) for m in rig.mice),
        gyro=simgyro.SimGyro(sample_hz=200.0, phase=0.0007 * seed),
    )
    result = sim.simulate(rig, sim.sequence(sim.pause(2.0), drive(30.0, seed=seed)), seed=seed)
    cfg = sim.rig_config(rig)
    if not gyro:
        cfg = dataclasses.replace(cfg, gyro=None)
    batch, _ = sim.run_tracker(result, cfg)
    end = result.truth(batch.t[-1:])[0]
    return math.degrees(abs((batch.theta[-1] - end[2] + math.pi) % (2 * math.pi) - math.pi))


def test_three_or_more_mice_stamped_late_keep_their_heading_with_a_gyro():
    """Three, four and five mice, three drives each: before, the end heading with the gyro
    had a median of 0.5-0.9 degrees on each of these layouts (the mice alone 0.11-0.14),
    the worst 5.6.  Seeds 23-25 (of the 20-25 this ran): their nine drives end 0.12 degree
    off in median (worst 0.36); with a span's timing taken as its mean (the mutant
    gyro-span-timing-its-mean) 0.61, where all six seeds' 18 drives gave 0.42 against the
    0.4 bound; half the time."""
    errors = [
        _heading_error(layout, "lsq", s, LATE_S, True)
        for layout in ("triangle", "square", "pentagon")
        for s in range(23, 26)
    ]
    assert statistics.median(errors) < 0.4 and max(errors) < 4.0, errors


def test_a_pair_stamped_late_does_not_learn_its_gyro_a_wrong_scale():
    errors = [_heading_error("pair", "diff-drive", s, LATE_S, True) for s in range(8)]
    assert statistics.median(errors) < 1.5 and max(errors) < 5.0, errors


def test_the_learnt_factor_is_the_timing_the_stamps_give():
    """The estimator alone, on innovations built as the module says: each edge's misplaced
    turn tau_k (variance lam * u / 2 for a window's u) taken from one window and given to
    the next, white noise of the same size on top; lam learnt within 10 %."""
    rng = np.random.default_rng(7)
    for lam in (1.0, 3.0, 9.0):
        spread = stampspread.StampSpread(0.01)
        u = rng.uniform(0.5, 2.0, 20001) * 1e-6
        tau = rng.normal(0.0, np.sqrt(lam * u / 2.0))
        e = tau[1:] - tau[:-1] + rng.normal(0.0, 1e-3 * math.sqrt(lam), len(u) - 1)
        for k in range(len(e)):
            spread.observe(float(e[k]), float(u[k + 1]), 0.0, (True,))
        assert spread.factor == pytest.approx(lam, rel=0.1)


def test_windows_the_stamps_cannot_move_teach_nothing():
    """Innovations of gyro noise alone against a timing variance below it (a robot driving
    straight): the factor stays the config's, whatever the noise's products sum to."""
    rng = np.random.default_rng(3)
    spread = stampspread.StampSpread(0.01)
    for e in rng.normal(0.0, 1e-3, 5000).tolist():
        spread.observe(e, 1e-12, 1e-6, (True,))
    assert spread.factor == 1.0


def test_a_skipped_pause_pairs_no_window_across_it():
    """Replay skips a long pause without closing its windows (Tracker.skip_quiet): the
    timing learner must not pair the window before the pause with the one after it, as the
    daemon, closing every empty window in between, does not."""
    from mousedom.fusion.tracker import Tracker

    rig = dataclasses.replace(scenarios.rig("triangle"), gyro=simgyro.SimGyro(sample_hz=200.0))
    result = sim.simulate(rig, sim.sequence(sim.pause(0.5), drive(3.0, seed=1)), seed=1)
    tracker = Tracker(sim.rig_config(rig), t0=float(result.motion.starts[0]))
    for name, rep in result.reports.items():
        tracker.push(name, rep.t, rep.dx, rep.dy)
    tracker.push_gyro(result.gyro.t, result.gyro.rate)
    last = max([float(r.t[-1]) for r in result.reports.values()] + [float(result.gyro.t[-1])])
    tracker.complete_until(last + 0.1)
    tracker.poll()
    spread = tracker._one.gyro.spread
    spread.observe(1e-3, 1.0, 0.0, (True, True, True))  # a window to pair with
    tracker.complete_until(last + 100.0)
    assert tracker.skip_quiet(last + 100.0) is not None
    assert spread._prev is None


def test_a_pair_stamped_late_uses_its_learnt_timing_within_a_second():
    """Eight drives other than test_a_pair_stamped_late_does_not_learn_its_gyro_a_wrong_scale's:
    the factor is used after 100 neighbouring windows (300 before: the healthy windows
    the judge took for faults in the first 3 s taught the gyro's scale), a median end
    heading under 0.5 degrees (0.67 before on these drives; the mice alone 0.25)."""
    errors = [_heading_error("pair", "diff-drive", s, LATE_S, True) for s in range(8, 16)]
    assert statistics.median(errors) < 0.5 and max(errors) < 3.0, errors
