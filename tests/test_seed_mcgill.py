"""Seed: P. Diez and S. Lawlor, "Odometry", ECSE 211 notes, McGill University
(seeds/mcgill-wheel-odometry.md).

Their derivation: dC = (drho r_R + dlambda r_L)/2, dtheta = (drho r_R - dlambda r_L)/w; the
chord has length dC sinc(dtheta/2) along theta + dtheta/2; they then drop sinc ~ 1 and iterate
x_{n+1} = x_n + dC cos(theta_n + dtheta/2), y likewise, theta_{n+1} = theta_n + dtheta.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.fusion import models
from mousedom.fusion.integrate import body_step, compose, sinc


@settings(max_examples=200, deadline=None)
@given(
    ux=st.floats(-1, 1),
    uy=st.floats(-1, 1),
    a=st.floats(-6.0, 6.0),
)
def test_exact_is_midpoint_times_sinc_half_angle(ux, uy, a):
    """Derivation 2: |dr| = dC sinc(dtheta/2) along theta + dtheta/2, i.e.
    exact = sinc(dtheta/2) * midpoint, component by component (also with sideways u_y)."""
    q = np.array([[ux, uy, a]])
    ex = body_step(q, "exact")[0]
    mid = body_step(q, "midpoint")[0]
    factor = math.sin(a / 2) / (a / 2) if a / 2 != 0 else 1.0
    # Where the two components nearly cancel (|result| << |u|), both formulas are exact to
    # a few ulps of |u|, not of the result: the absolute tolerance scales with |u|.
    tol = 1e-15 * (abs(ux) + abs(uy)) + 1e-300
    np.testing.assert_allclose(ex[:2], factor * mid[:2], rtol=1e-13, atol=tol)
    assert ex[2] == mid[2] == a


def test_sinc_factor_values():
    """sinc(dtheta/2) ~ 1 for small turns (their approximation), 2/pi for a half turn."""
    np.testing.assert_allclose(sinc(np.array([0.0, 1e-8, np.pi / 2])), [1.0, 1.0, 2 / np.pi])
    # their "sufficiently short interval": at 0.1 rad per sample the chord is 0.04 % short
    np.testing.assert_allclose(1 - sinc(0.05), 1 - np.sin(0.05) / 0.05, rtol=1e-12)
    assert 3e-4 < 1 - sinc(0.05) < 5e-4


def test_wheels_reproduces_dc_and_dtheta():
    """Derivation 2: dC = (drho r_R + dlambda r_L)/2, dtheta = (drho r_R - dlambda r_L)/w."""
    rng = np.random.default_rng(211)
    dl, dr = rng.normal(size=(2, 100))
    r_l, r_r, w = 0.0205, 0.0211, 0.153
    sol = models.wheels(dl, dr, r_l, r_r, w)
    np.testing.assert_allclose(sol.q[:, 0], (dr * r_r + dl * r_l) / 2, rtol=1e-15)
    np.testing.assert_allclose(sol.q[:, 2], (dr * r_r - dl * r_l) / w, rtol=1e-15, atol=1e-17)
    assert np.all(sol.q[:, 1] == 0)


def test_wheels_is_the_linear_model_with_wheels_as_sensors():
    """The wheel contact points behave like two sensors at (0, +w/2), (0, -w/2) that read
    only along x (no side slip, assumption 2): diff-drive/lsq on them gives the same q."""
    rng = np.random.default_rng(1)
    dl, dr = rng.normal(size=(2, 20))
    r_l, r_r, w = 0.02, 0.021, 0.15
    wh = models.wheels(dl, dr, r_l, r_r, w)
    pos = np.array([[0.0, w / 2], [0.0, -w / 2]])
    d = np.zeros((20, 2, 2))
    d[:, 0, 0] = dl * r_l  # the left wheel's arc length dL
    d[:, 1, 0] = dr * r_r  # the right wheel's dR
    for model in ("lsq", "diff-drive"):
        sol = models.solve(model, d, pos, 1e-5)
        np.testing.assert_allclose(sol.q, wh.q, rtol=1e-12, atol=1e-15)


def test_their_recursion_equals_compose_of_midpoint_steps():
    """Derivation 3: x_{n+1} = x_n + dC cos(theta_n + dtheta_n/2), y_{n+1} = y_n + dC
    sin(theta_n + dtheta_n/2), theta_{n+1} = theta_n + dtheta_n, written out as a loop."""
    rng = np.random.default_rng(3)
    n = 400
    dl = rng.uniform(0, 0.5, n)
    dr = rng.uniform(0, 0.5, n)
    r_l, r_r, w = 0.0205, 0.0211, 0.153
    x, y, th = 0.5, -0.25, 1.0
    xs = []
    for k in range(n):
        dc = (dr[k] * r_r + dl[k] * r_l) / 2
        dth = (dr[k] * r_r - dl[k] * r_l) / w
        x += dc * math.cos(th + dth / 2)
        y += dc * math.sin(th + dth / 2)
        th += dth
        xs.append((x, y, th))
    sol = models.wheels(dl, dr, r_l, r_r, w)
    poses = compose(np.array([0.5, -0.25, 1.0]), body_step(sol.q, "midpoint"))
    np.testing.assert_allclose(poses, np.array(xs), rtol=0, atol=1e-12)


def test_wheel_odometry_on_a_circle_exact_vs_their_approximation():
    """Constant wheel speeds drive a circle; exact integration lands on it, theirs lags by the
    sinc factor (error O(dtheta^2) per sample, Error 2: a longer sample period costs accuracy).
    """
    r, w = 0.02, 0.15
    dl_rate, dr_rate = 5.0, 7.0  # rad/s
    v = (dr_rate + dl_rate) * r / 2
    om = (dr_rate - dl_rate) * r / w
    total = 2.0
    truth = np.array([v / om * np.sin(om * total), v / om * (1 - np.cos(om * total)), om * total])
    errs = []
    for n in (10, 20, 40):
        dt = total / n
        sol = models.wheels(np.full(n, dl_rate * dt), np.full(n, dr_rate * dt), r, r, w)
        ex = compose(np.zeros(3), body_step(sol.q, "exact"))[-1]
        np.testing.assert_allclose(ex, truth, atol=1e-12)
        mid = compose(np.zeros(3), body_step(sol.q, "midpoint"))[-1]
        errs.append(np.hypot(*(mid[:2] - truth[:2])))
    # halving the sample period quarters the error of their recursion
    np.testing.assert_allclose(np.log2(np.array(errs[:-1]) / np.array(errs[1:])), 2.0, atol=0.05)
