"""Seed: David Hong, "Optical Mouse Based Odometry" (seeds/hong-single-mouse-odometry.md).

Hong's frame has y forward and x lateral; his mouse sits at distance s ahead of the axle and
reports (dx_m lateral, dy_m forward).  In mousedom's REP-103 body frame the mouse is at
(s, 0), its forward reading is body x and its lateral reading body y, so Hong's
(dy, dx) <-> mousedom's (dx, dy), and his dy_m is our u_x.  With dtheta = a:

    Hong dy / dy_m = sin(a)/a        = our exact dx / u_x
    Hong dx / dy_m = (1 - cos a)/a   = our exact dy / u_x
"""

from __future__ import annotations

import numpy as np
import pytest

from mousedom.fusion import models
from mousedom.fusion.integrate import body_step, compose


def ratios(method: str, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hong's (dx/dy_m, dy/dy_m) for each integrator: a unit forward reading turned by a."""
    q = np.column_stack([np.ones_like(a), np.zeros_like(a), a])
    step = body_step(q, method)
    return step[:, 1], step[:, 0]  # his lateral dx, his forward dy


def test_exact_is_hongs_theorem_1_formula():
    """Theorem 1: dx = dy_m (1 - cos a)/a, dy = dy_m sin(a)/a."""
    a = np.linspace(0.05, 1.5, 30)
    lat, fwd = ratios("exact", a)
    np.testing.assert_allclose(lat, (1 - np.cos(a)) / a, rtol=1e-13)
    np.testing.assert_allclose(fwd, np.sin(a) / a, rtol=1e-13)


def test_hong_table_taylor_lateral_error_at_pi_over_8():
    """Section 3: "our approximation of dx/dy_m is very accurate up to dtheta = pi/8".

    At pi/8 the Taylor form a/2 exceeds (1 - cos a)/a by about 1.3 %.
    """
    a = np.array([np.pi / 8])
    exact, _ = ratios("exact", a)
    taylor, _ = ratios("taylor", a)
    rel = taylor[0] / exact[0] - 1
    assert rel == pytest.approx(0.01296, abs=5e-5)
    assert 0.0125 < rel < 0.0135


def test_hong_table_taylor_forward_error_at_pi_over_4():
    """Section 3: "our approximation of dy/dy_m is accurate up to dtheta = pi/4".

    At pi/4, 1 - a^2/6 falls short of sin(a)/a by about 0.35 %.
    """
    a = np.array([np.pi / 4])
    _, exact = ratios("exact", a)
    _, taylor = ratios("taylor", a)
    rel = taylor[0] / exact[0] - 1
    assert rel == pytest.approx(-0.003466, abs=5e-5)
    assert -0.0040 < rel < -0.0030


def test_hongs_approximation_beats_the_previous_one():
    """Section 3: the Taylor form is closer to the exact solution than the previous
    approximation (dx ~ dy_m sin a, dy ~ dy_m cos a, i.e. ``euler``) for both ratios."""
    a = np.linspace(1e-3, np.pi / 2, 200)
    ex_lat, ex_fwd = ratios("exact", a)
    ta_lat, ta_fwd = ratios("taylor", a)
    eu_lat, eu_fwd = ratios("euler", a)
    np.testing.assert_allclose(eu_lat, np.sin(a), rtol=1e-14)
    np.testing.assert_allclose(eu_fwd, np.cos(a), rtol=1e-14)
    assert np.all(np.abs(ta_lat - ex_lat) < np.abs(eu_lat - ex_lat))
    assert np.all(np.abs(ta_fwd - ex_fwd) < np.abs(eu_fwd - ex_fwd))


def test_theorem_1_with_one_mouse_and_diff_drive():
    """Theorem 1: dtheta = dx_m / s; the forward reading is the arc length u_x."""
    s = 0.12
    fwd, lat = 0.004, -0.0009  # our body x and body y readings (his dy_m and dx_m)
    sol = models.solve("diff-drive", np.array([[[fwd, lat]]]), np.array([[s, 0.0]]), 1e-5)
    assert sol.ok[0]
    np.testing.assert_allclose(sol.q[0], [fwd, 0.0, lat / s], rtol=1e-14, atol=1e-18)
    np.testing.assert_allclose(sol.residual, 0, atol=1e-18)  # 2 readings, 2 unknowns
    a = lat / s
    step = body_step(sol.q, "exact")[0]
    # the literal 1 - cos(a) loses ~8 digits at a = 0.0075: compare at that precision
    hong = [fwd * np.sin(a) / a, fwd * (1 - np.cos(a)) / a]
    np.testing.assert_allclose(step[:2], hong, rtol=1e-9)


@pytest.mark.parametrize("turn", [+1.0, -1.0])
@pytest.mark.parametrize("windows", [7, 250])
def test_one_mouse_diff_drive_on_a_circle(turn, windows):
    """Hong's set-up driven round 1.5 laps of a circle: the exact pose to 1e-9.

    A point rigidly attached to a body turning at constant rate w and speed v has a constant
    body-frame velocity (v, w s) (the mouse at (s, 0)), so its reading over a window of
    length dt is exactly (v dt, w s dt).  The true pose at time t is on the circle of radius
    R = v/w centred at (0, R): (R sin wt, R (1 - cos wt), wt).
    """
    v, w, s = 0.3, turn * 0.8, 0.1
    total = 1.5 * 2 * np.pi / abs(w)
    dt = total / windows
    d = np.tile([[[v * dt, w * s * dt]]], (windows, 1, 1))
    sol = models.solve("diff-drive", d, np.array([[s, 0.0]]), 1e-5)
    assert sol.ok.all()
    poses = compose(np.zeros(3), body_step(sol.q, "exact"))
    t = dt * np.arange(1, windows + 1)
    r = v / w
    truth = np.column_stack([r * np.sin(w * t), r * (1 - np.cos(w * t)), w * t])
    np.testing.assert_allclose(poses, truth, atol=1e-9)
    # Hong's Taylor form drifts off the circle, the more so the longer the window
    approx = compose(np.zeros(3), body_step(sol.q, "taylor"))
    assert np.abs(approx[-1, :2] - truth[-1, :2]).max() > 1e-9
