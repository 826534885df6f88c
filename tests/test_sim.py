"""The simulator: reports follow the evdev convention and carry sub-count motion over."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mousedom.fusion import sim
from mousedom.fusion.units import INCH


def rig(**kw) -> sim.Rig:
    return sim.Rig((sim.SimMouse("a", 0.1, 0.0, **kw),))


def test_straight_forward_gives_negative_rel_y_with_carry():
    res = sim.simulate(rig(), sim.straight(0.2, 0.2))
    r = res.reports["a"]
    exact = 0.2 / INCH * 450
    assert r.dx.sum() == 0
    # Whole counts, remainder carried: the total is the exact count rounded down.
    assert r.dy.sum() == math.floor(-exact)
    assert np.all(r.dy == np.round(r.dy))
    # 125 Hz reports, only while moving.
    assert np.allclose(np.diff(r.t), 1 / 125)
    assert res.truth(res.duration)[0] == pytest.approx([0.2, 0.0, 0.0])


def test_turn_in_place_moves_a_front_mouse_left():
    res = sim.simulate(rig(quantize=False), sim.turn(math.pi / 2, 0.5))
    r = res.reports["a"]
    # Mouse 0.1 m ahead of the centre; rotating CCW moves it left: REL_X negative.
    assert r.dx.sum() == pytest.approx(-(0.1 * math.pi / 2) / INCH * 450)
    assert r.dy.sum() == pytest.approx(0.0, abs=1e-9)
    assert res.truth(res.duration)[0] == pytest.approx([0, 0, math.pi / 2])


def test_umbmark_square_closes():
    for cw in (True, False):
        res = sim.simulate(rig(), sim.umbmark_square(cw=cw))
        end = res.truth(res.duration)[0]
        assert end[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
        assert end[2] == pytest.approx(-2 * math.pi if cw else 2 * math.pi)
        # The first leg goes along +x; a clockwise square then heads to -y.
        corner = res.truth(res.motion.starts[3])[0]
        assert corner[:2] == pytest.approx([4.0, 0.0], abs=1e-9)


def test_lost_tracking_hides_motion():
    res = sim.simulate(rig(lost=((1.0, 2.0),), quantize=False), sim.straight(0.6, 0.2))
    r = res.reports["a"]
    assert r.dy.sum() == pytest.approx(-(0.4) / INCH * 450)
    assert not np.any((r.t > 1.0 + 1 / 125) & (r.t < 2.0))


def test_noise_is_seeded():
    a = sim.simulate(rig(noise=0.5), sim.straight(0.2), seed=3).reports["a"]
    b = sim.simulate(rig(noise=0.5), sim.straight(0.2), seed=3).reports["a"]
    c = sim.simulate(rig(noise=0.5), sim.straight(0.2), seed=4).reports["a"]
    assert np.array_equal(a.dy, b.dy) and not np.array_equal(a.dy, c.dy)


def test_rig_config_round_trips_the_rig():
    r = sim.three_mouse_rig()
    cfg = sim.rig_config(r)
    assert cfg.names == ("front", "left", "right")
    assert cfg.mouse("left").mount.y == pytest.approx(r.mice[1].y)


def test_rig_config_accepts_numpy_numbers():
    mice = (sim.SimMouse("a", np.float64(0.15), np.float64(0.0), cpi_x=np.float64(400)),)
    rig = sim.Rig(mice + (sim.SimMouse("b", 0.0, 0.1),), rate_hz=np.float64(50))
    cfg = sim.rig_config(rig)
    assert cfg.mouse("a").mount.x == 0.15 and cfg.rate_hz == 50
