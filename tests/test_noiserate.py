"""The covariance's learnt noise (fusion.noiserate, issue 31 item 4): what it learns, and
that the daemon's path and replay's learn and use it alike."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mousedom.fusion import scenarios, sim
from mousedom.fusion.posebatch import PoseBatch
from mousedom.fusion.tracker import Tracker
from mousedom.fusion.units import INCH


@pytest.mark.parametrize("layout", ["triangle", "square", "pentagon"])
def test_it_learns_the_noise_that_adds_up(layout):
    """The simulator's report noise (0.3 counts per report at 125 Hz to 1 kHz, while moving)
    adds up to 0.09 * reports per window: what each mouse's learnt variance per moving
    window must come near, whatever the config's sigma says (0.5 counts per window) and
    however much the stamps' lateness moves counts between windows (far more)."""
    base = scenarios.rig(layout)
    truth = np.array([0.09 * m.report_hz / 100.0 for m in base.mice])
    per_mouse, total = [], []
    for seed in (7, 8, 9, 10):
        result = sim.simulate(base, scenarios.drive(60.0, seed), seed=seed)
        _, tracker = scenarios.run(result, scenarios.config(base))
        learnt = tracker.noise_rate.variance / (INCH / 1000.0) ** 2  # counts^2
        per_mouse.append(learnt / truth)
        total.append(learnt.sum() / truth.sum())
    # the sum well: it is what the pose's covariance mostly is; each mouse's share within
    # a factor of 3 (on three mice, 3 residual degrees of freedom share out 3 variances;
    # the 125 Hz mouse's noise is small against its rounding and lateness)
    assert 0.75 < np.median(total) < 1.35, total
    ratio = np.median(per_mouse, axis=0)
    assert np.all((ratio > 1 / 3) & (ratio < 3.0)), ratio


@pytest.mark.parametrize("n_mice", [3, 2])
def test_the_daemons_path_and_replays_cover_alike_through_pauses(n_mice):
    """Pauses leave rounding dust (1e-17 counts) on the daemon's float path where replay's
    arrays have 0: neither the learnt noise nor a window's "counted" may hang on it. Two
    mice learn one factor of their sigma^2 (noiserate), on either path alike."""
    rig = sim.three_mouse_rig()
    mice = [dataclasses.replace(m, noise=0.3, stamp_tail=0.002) for m in rig.mice][:n_mice]
    rig = dataclasses.replace(rig, mice=tuple(mice))
    legs = [sim.arc(0.5, 1.0, 0.4), sim.pause(0.37), sim.straight(0.5, 0.3), sim.pause(0.53)]
    result = sim.simulate(rig, sim.sequence(*legs * 5), seed=3)
    cfg = sim.rig_config(rig)
    batch, tb = sim.run_tracker(result, cfg)
    tl = Tracker(cfg, t0=0.0)
    live = PoseBatch.concat(sim.run_tracker_live(result, tl), n_mice)
    assert tb.noise_rate.noise is not None  # learnt within the drive
    assert np.allclose(tb.noise_rate.variance, tl.noise_rate.variance, rtol=1e-9)
    n = min(len(batch), len(live))
    scale = np.abs(batch.cov[:n]).max(axis=(1, 2))[:, None, None]
    assert np.all(np.abs(batch.cov[:n] - live.cov[:n]) <= 1e-9 * scale)
    qscale = np.abs(batch.qcov[:n]).max(axis=(1, 2))[:, None, None] + 1e-300
    assert np.all(np.abs(batch.qcov[:n] - live.qcov[:n]) <= 1e-9 * qscale)
