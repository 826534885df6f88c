"""The pose covariance is true, not just present: a Monte Carlo consistency test.

Several hundred noisy runs of one simulated rig and path (exact truth from the
simulator), through the tracker's array path (one batch) and its one-window path (the
daemon's: one window per poll).  For a consistent estimator, the normalised estimation
error squared of the end pose, NEES = e^T P^-1 e with e = estimate - truth, is chi-square
with 3 degrees of freedom: its mean over N runs is 3 with a standard error of sqrt(6/N).
A covariance that is optimistic (too small) pushes the mean up, a pessimistic one down.

The rig and path are chosen to make the covariance's structure matter, not just its
size: the mice sit far ahead of the body origin (their sideways motion and the turn are
strongly correlated, so the twist's covariance is far from isotropic), the output rate is
low and the turn fast (0.8 rad per window), so rotating a window's noise by the heading
before the window or after it changes the result; the deliberate bug that did just that
passed the whole suite before this test (issue 17).  The simulator's noise (counts per
report, one report per window) is the config's ``sigma``, so the model is exactly right.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mousedom.config import parse_config
from mousedom.fusion import robust, sim
from mousedom.fusion.tracker import PoseBatch, Tracker

RUNS = 300
RATE = 5.0  # output rate and report rate: one report per window, on the window's end
SIGMA = 2.0  # counts per report and axis


def _rig() -> tuple[sim.Rig, object]:
    mice = tuple(
        sim.SimMouse(name, x, y, report_hz=RATE, noise=SIGMA, quantize=False)
        for name, x, y in (("a", 0.5, 0.05), ("b", 0.5, -0.05), ("c", 0.45, 0.0))
    )
    rig = sim.Rig(mice, rate_hz=RATE)
    text = sim.rig_yaml(rig).replace("    flip: false", f"    flip: false\n    sigma: {SIGMA}")
    return rig, parse_config(text, "<monte carlo>", need_sources=False)


def _nees(path: str, lifted: bool = False) -> np.ndarray:
    rig, config = _rig()
    if lifted:  # mouse c lifted for three windows (edges at multiples of 0.2 s)
        c = dataclasses.replace(rig.mice[2], lost=((0.6, 1.2),))
        rig = dataclasses.replace(rig, mice=(*rig.mice[:2], c))
    trajectory = sim.arc(0.1, 6.0, 0.4)  # 4 rad/s: 0.8 rad per window
    values = []
    for seed in range(RUNS):
        result = sim.simulate(rig, trajectory, seed=seed)
        tracker = Tracker(config, t0=0.0)
        if path == "array":
            for name, r in result.reports.items():
                tracker.push(name, r.t, r.dx, r.dy)
            last = tracker.finish()
        else:  # each report pushed as a live read would (lists) and polled
            last = PoseBatch.concat(sim.run_tracker_live(result, tracker), 3)
        if lifted:  # the robust fusion left c out while it was lifted
            held = (last.t > 0.7) & (last.t < 1.2)
            # (late for its first window, then excluded: health.LATE)
            assert np.isin(last.state[held, 2], (robust.EXCLUDED, robust.LATE)).all(), seed
            assert (last.state[held, 2] == robust.EXCLUDED).any(), seed
        t_end = float(last.t[-1]) if len(last) else tracker.frontier_time
        truth = result.truth(np.array([t_end]))[0]
        e = np.asarray(tracker.pose) - truth
        e[2] = (e[2] + math.pi) % (2 * math.pi) - math.pi
        values.append(float(e @ np.linalg.solve(np.asarray(tracker.pose_cov), e)))
    return np.asarray(values)


@pytest.mark.parametrize("path,lifted", [("array", False), ("one-window", False),
                                         ("array", True)])  # fmt: skip
def test_end_pose_nees_averages_three(path, lifted):
    """With and without a mouse excluded for part of the run (issue 16): a covariance
    built from fewer mice must be as true as one from all of them."""
    nees = _nees(path, lifted)
    band = 3 * math.sqrt(6 / RUNS)  # three standard errors of the mean of chi2(3)
    assert abs(nees.mean() - 3.0) < band, (nees.mean(), band)
    # and its spread is a chi-square's, not a covariance right only on average
    assert np.var(nees) == pytest.approx(6.0, rel=0.4)


def test_a_mouse_with_unequal_axis_cpis_is_not_overconfident():
    """Two mice of 400 by 1600 CPI (one turned 90 degrees), the config's sigma their true
    noise: the covariance comes from the config (two mice).  sigma in metres was taken at
    the mean CPI, 51 um on both axes where REL_X errs by 127: the end pose's NEES was 11.2.
    One isotropic sigma per mouse cannot be right along both axes; the root mean square of
    the two (units.sigma_metres) keeps their summed variance: 3.4 here (the direction of
    each error is not modelled: the bound allows for it)."""
    rate, sigma, runs = 10.0, 2.0, 200
    mice = (sim.SimMouse("a", 0.0, 0.12, cpi_x=400.0, cpi_y=1600.0, report_hz=rate,
                         noise=sigma, quantize=False),
            sim.SimMouse("b", 0.05, -0.12, yaw=90.0, cpi_x=400.0, cpi_y=1600.0,
                         report_hz=rate, noise=sigma, quantize=False))  # fmt: skip
    rig = sim.Rig(mice, rate_hz=rate)
    text = sim.rig_yaml(rig).replace("    flip: false", f"    flip: false\n    sigma: {sigma}")
    config = parse_config(text, "<anisotropic>", need_sources=False)
    trajectory = sim.sequence(sim.arc(1.0, 1.5, 0.3), sim.turn(-3.0, 3.0),
                              sim.arc(1.0, 0.5, 0.2))  # fmt: skip
    values = []
    for seed in range(runs):
        result = sim.simulate(rig, trajectory, seed=seed)
        tracker = Tracker(config, t0=0.0)
        for name, r in result.reports.items():
            tracker.push(name, r.t, r.dx, r.dy)
        last = tracker.finish()
        e = np.asarray(tracker.pose) - result.truth(np.array([float(last.t[-1])]))[0]
        e[2] = (e[2] + math.pi) % (2 * math.pi) - math.pi
        values.append(float(e @ np.linalg.solve(np.asarray(tracker.pose_cov), e)))
    mean = float(np.mean(values))
    assert 1.5 < mean < 4.0, mean
