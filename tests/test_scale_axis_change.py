"""A mouse whose CPI is off on one axis (or on both, unequally) is no change of scale.

The learner looks for a change of a mouse's scale (another floor, a dirty lens) by
comparing the recent evidence's scales with the older's (``ScaleLearner._changed``).  One
scale per mouse reads a mouse off on one axis as a mean of its two axes weighted by the
directions driven, so that scale moved wherever the drive's mix of straights, turns and
slides did, and was taken for a change: the evidence before it was dropped.  On the
review's triangle (one mouse 3 % off on x, a 30 s drive with slides) 8 of 15 drives found
such a change, `calibrate scales` then learnt from 7 s of the 32 and missed the 3 %, or
refused; random rigs of 3-6 mice, one mouse off by 1-5 % per axis, found changes in 9 of 60
drives.  Each count axis is now corrected by its own scale before the scales are compared
(``_change_evidence``)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from layouts import random_layout

from mousedom.fusion import scenarios, sim
from mousedom.fusion.drives import drive


def _legs(rng: np.random.Generator, seconds: float, slide: bool) -> list[sim.Segment]:
    """Straights, arcs, turns, pauses and (``slide``) sideways slides, at random."""
    legs: list[sim.Segment] = []
    while sum(s.duration for s in legs) < seconds:
        kind = int(rng.integers(0, 5 if slide else 4))
        legs += [
            lambda: sim.straight(rng.uniform(-0.5, 0.5), 0.3),
            lambda: sim.arc(rng.uniform(0.2, 1) * rng.choice([-1, 1]), rng.uniform(0.3, 1.5), 0.3),
            lambda: sim.turn(rng.uniform(-2, 2), 0.8),
            lambda: sim.pause(0.3),
            lambda: sim.sideways(rng.uniform(-0.4, 0.4), 0.3),
        ][kind]()
    return legs


def triangle(seed: int, axis: str) -> tuple[sim.Rig, sim.Rig, list[sim.Segment]]:
    """The review's case: sim.three_mouse_rig at 250 Hz, 0.3 counts of noise, mouse 'left'
    3 % more on ``axis`` ("x" or "y") than configured; a 30 s drive with slides.  (rig as
    configured, rig as it is, drive)"""
    rng = np.random.default_rng(seed)
    rig = sim.three_mouse_rig(cpi=800.0, report_hz=250.0)
    rig = dataclasses.replace(rig, mice=tuple(dataclasses.replace(m, noise=0.3) for m in rig.mice))
    mice = list(rig.mice)
    mice[1] = dataclasses.replace(mice[1], **{f"cpi_{axis}": 824.0})
    return rig, dataclasses.replace(rig, mice=tuple(mice)), _legs(rng, 30.0, True)


def random_axes(seed: int) -> tuple[sim.Rig, sim.Rig, list[sim.Segment], int]:
    """3-6 mice, ring, scattered or bunched, any yaws, 125-1000 Hz, late stamps, USB gaps
    on some; one mouse off by 1-5 % on its x axis, its y axis or both unequally; drives of
    25-40 s, of random legs with or without slides or of ``drives.drive``.  (rig as
    configured, rig as it is, drive, the mouse off)"""
    rng = np.random.default_rng((9191, seed))
    n = int(rng.integers(3, 7))
    xy = random_layout(rng, n, str(rng.choice(["ring", "scatter", "bunched"])))
    yaws = 90.0 * rng.integers(-1, 3, n) if rng.random() < 0.5 else rng.uniform(-180, 180, n)
    mice = []
    for k in range(n):
        cpi = float(rng.choice([400, 800, 1000, 1600]))
        hz = float(rng.choice([125.0, 250.0, 500.0, 1000.0]))
        gaps: tuple = ()
        if rng.random() < 0.4:
            gaps = sim.usb_gap_spans(int(rng.integers(1 << 30)), 45.0,
                                     float(rng.uniform(0.5, 3)), 0.03, 0.3)  # fmt: skip
        mice.append(sim.SimMouse(
            f"m{k}", float(xy[k, 0]), float(xy[k, 1]), yaw=float(yaws[k]), cpi_x=cpi,
            cpi_y=cpi, report_hz=hz, phase=float(rng.uniform(0, 1 / hz)), noise=0.3,
            stamp_delay=float(rng.uniform(0, 0.003)), usb_gaps=gaps,
            flip=bool(rng.random() < 0.2)))  # fmt: skip
    off = int(rng.integers(n))
    which = str(rng.choice(["x", "y", "xy"]))
    e = rng.uniform(0.01, 0.05, 2) * rng.choice([-1, 1], 2)
    m = mice[off]
    true = list(mice)
    true[off] = dataclasses.replace(
        m,
        cpi_x=m.cpi_x * (1 + e[0]) if "x" in which else m.cpi_x,
        cpi_y=m.cpi_y * (1 + e[1]) if "y" in which else m.cpi_y,
    )
    slide = bool(rng.random() < 0.6)
    seconds = float(rng.uniform(25, 40))
    if rng.random() < 0.5:
        legs = _legs(rng, seconds, slide)
    else:
        legs = drive(seconds, int(rng.integers(1 << 20)))
    return sim.Rig(tuple(mice), model="lsq"), sim.Rig(tuple(true), model="lsq"), legs, off


def _through(base: sim.Rig, true: sim.Rig, legs: list[sim.Segment], seed: int):
    """The drive through the tracker, the config told ``base``'s CPIs and then the true
    ones: (learner, end error, end error told)."""
    result = sim.simulate(true, legs, seed=seed)
    cpi = {m.name: (m.cpi_x, m.cpi_y) for m in base.mice}
    out = []
    for cfg in (scenarios.config(true, cpi=cpi), scenarios.config(true)):
        batch, tracker = scenarios.run(result, cfg)
        e = scenarios.end_pose_error(result, batch)
        out += [tracker.scales, math.hypot(e[0], e[1])]
    return out[0], out[1], out[3]


@pytest.mark.parametrize("axis", ["x", "y"])
def test_a_triangle_mouse_off_on_one_axis_is_no_change(axis):
    """Eight of the review's drives per axis (before: changes found in 3 of them on x, 4
    on y): none, and the mouse's scale learnt on its axis within 0.3 %."""
    for seed in range(8):
        base, true, legs = triangle(seed, axis)
        learner, on, told = _through(base, true, legs, seed)
        assert learner.changes == 0, (seed, learner.changed)
        a = "xy".index(axis)
        assert learner.scale[1, a] == pytest.approx(800.0 / 824.0, abs=0.003), (seed, learner.scale)
        assert on < told + 0.02, (seed, on, told)


def test_random_rigs_off_per_axis_find_no_change():
    """Sixteen of the generator's drives (before: changes found in six, 1-3 each): none.
    (Their end errors are not this test's: where the drive does not tell a mouse's axes
    apart its one scale is applied, bent by the axis off, with or without a change.)"""
    for seed in range(30, 46):
        base, true, legs, _ = random_axes(seed)
        result = sim.simulate(true, legs, seed=seed)
        cpi = {m.name: (m.cpi_x, m.cpi_y) for m in base.mice}
        _, tracker = scenarios.run(result, scenarios.config(true, cpi=cpi))
        assert tracker.scales.changes == 0, (seed, tracker.scales.changed)


@pytest.mark.parametrize("seed", [4, 8])
def test_calibrate_scales_writes_the_axis_of_a_mouse_off_on_one_axis(tmp_path, seed):
    """The review's seeds through `calibrate scales`: seed 4 had cut 31.7 s of evidence
    to 7.2 s and written nothing (the 3 % missed), seed 8 had taken the healthy mouse
    'right' for changed and refused.  Now no change is said, and left's x CPI is the true
    824 within 0.1 %, its y and the others' as configured."""
    from test_calib_cli import write_evemu

    from mousedom.calibrate import scales as calib_scales
    from mousedom.config import load_config

    base, true, legs = triangle(seed, "x")
    result = sim.simulate(true, legs, seed=seed)
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(sim.rig_yaml(base))
    caps = [f"{m.name}={write_evemu(tmp_path / f'{m.name}.events', result.reports[m.name])}"
            for m in base.mice]  # fmt: skip
    learnt = calib_scales.learn(load_config(str(cfg), need_sources=False), caps)
    calib_scales.check(learnt)
    assert not [w for w in learnt.warnings if "changed during" in w], learnt.warnings
    assert learnt.evidence_s > 25.0
    written = {m.name: m.written for m in learnt.mice}
    assert written["left"][0] == pytest.approx(824.0, rel=0.001), written
    assert written["left"][1] == 800.0 and written["front"] == written["right"] == (800.0, 800.0)
