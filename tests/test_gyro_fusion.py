"""The gyro's row in the window's solve (mousedom/fusion/gyro.py), against the stacked
least squares it stands for, and its bias against the truth over many seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mousedom.fusion.gyro import GyroFusion, GyroNoise
from mousedom.fusion.gyrobias import SCALE_SIGMA, SPAN_S

T = 0.01
NOISE = GyroNoise(density=math.radians(0.005), bias_walk=math.radians(0.001),
                  bias_sigma=math.radians(1.0))  # fmt: skip


def _mice_solve(rng: np.random.Generator, n_mice: int) -> tuple:
    """A random rig's design matrix (Kim & Lee's rows) with weights, a window's readings
    and the mice-only estimate: (A, W, d, q, C)."""
    p = rng.uniform(-0.2, 0.2, (n_mice, 2))
    rows = []
    for px, py in p:
        rows += [[1.0, 0.0, -py], [0.0, 1.0, px]]
    a = np.array(rows)
    w = np.diag(np.repeat(1.0 / rng.uniform(1e-5, 1e-4, n_mice) ** 2, 2))
    q_true = rng.normal(0.0, [2e-3, 5e-4, 1e-2])
    d = a @ q_true + rng.normal(0.0, 1.0, 2 * n_mice) / np.sqrt(np.diag(w))
    c = np.linalg.inv(a.T @ w @ a)
    return a, w, d, c @ a.T @ w @ d, c


@pytest.mark.parametrize("seed", range(20))
def test_both_is_the_least_squares_with_the_gyros_row_stacked(seed):
    """Kim & Lee's weighted least squares (their eq. for N mice) with one more row,
    [0, 0, 1] q = g - b T, weighted by 1 / (N^2 T + T^2 P): the fused q and covariance."""
    rng = np.random.default_rng(seed)
    a, w, d, q_m, c_m = _mice_solve(rng, int(rng.integers(2, 6)))
    fusion = GyroFusion(NOISE, T, "both")
    fusion.state.bias = rng.normal(0.0, 0.01)
    # the scale known (its uncertainty would make the gyro's row's variance depend on
    # the turn: tests below), the bias not
    fusion.state.p = [[rng.uniform(1e-8, 1e-4), 0.0], [0.0, 0.0]]
    prior_bias, prior_var = fusion.state.bias, fusion.state.var + NOISE.bias_walk**2 * T
    g = float(q_m[2] + rng.normal(0.0, 1e-3))
    q, c, said = fusion.window(q_m.tolist(), c_m.tolist(), g, True)
    r = NOISE.density**2 * T + T * T * prior_var
    a2 = np.vstack([a, [0.0, 0.0, 1.0]])
    w2 = np.zeros((len(a2), len(a2)))
    w2[:-1, :-1] = w
    w2[-1, -1] = 1.0 / r
    d2 = np.append(d, g - prior_bias * T)
    c2 = np.linalg.inv(a2.T @ w2 @ a2)
    assert np.allclose(q, c2 @ a2.T @ w2 @ d2, rtol=1e-9, atol=1e-15)
    assert np.allclose(c, c2, rtol=1e-7, atol=1e-20)
    e = g - q_m[2] - prior_bias * T
    assert said.stat == pytest.approx(e * e / (c_m[2, 2] + r), rel=1e-12)
    assert said.used


def test_mice_keeps_the_mice_and_gyro_takes_the_gyros_heading():
    rng = np.random.default_rng(7)
    _, _, _, q_m, c_m = _mice_solve(rng, 3)
    mice = GyroFusion(NOISE, T, "mice")
    q, c, said = mice.window(q_m.tolist(), c_m.tolist(), 0.02, True)
    assert q == q_m.tolist() and c == c_m.tolist() and not said.used
    gyro = GyroFusion(NOISE, T, "gyro")
    gyro.state.bias = 0.1
    q, c, _ = gyro.window(q_m.tolist(), c_m.tolist(), 0.02, True)
    assert q[2] == pytest.approx(0.02 - 0.1 * T, rel=1e-12)
    # the translation moves along the mice's own correlation with the heading
    k = c_m[:2, 2] / c_m[2, 2]
    assert np.allclose(q[:2], q_m[:2] + k * (q[2] - q_m[2]), rtol=1e-12)
    r = NOISE.density**2 * T + T * T * (NOISE.bias_sigma**2 + NOISE.bias_walk**2 * T)
    r += (q_m[2] * SCALE_SIGMA) ** 2  # the scale's uncertainty in a turn
    assert c[2][2] == pytest.approx(r, rel=1e-12)


def test_no_samples_or_no_rank_learns_nothing_and_invents_no_motion():
    fusion = GyroFusion(NOISE, T, "both")
    q0, c0 = [1e-3, 0.0, 2e-3], np.diag([1e-8, 1e-8, 1e-6]).tolist()
    for turn, ok in ((None, True), (0.5, False)):
        q, c, said = fusion.window(q0, c0, turn, ok)
        assert q == q0 and c == c0 and not said.used and fusion.state.bias == 0.0


@pytest.mark.parametrize("use", ["both", "mice", "gyro"])
def test_the_bias_is_learnt_at_standstill_with_an_honest_sigma(use):
    """At a standstill the mice say nothing turned, exactly (C_aa = 0): each window is a
    reading of the bias alone.  Over 200 seeds the learnt bias's error, in units of its
    own sigma, has unit variance (NEES of a scalar: mean 1)."""
    nees = []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        bias = rng.normal(0.0, NOISE.bias_sigma)
        fusion = GyroFusion(NOISE, T, use)
        for _ in range(100):  # one second still
            bias += rng.normal(0.0, NOISE.bias_walk * math.sqrt(T))
            turn = bias * T + rng.normal(0.0, NOISE.density * math.sqrt(T))
            _, _, said = fusion.window([0.0, 0.0, 0.0], [[0.0] * 3] * 3, turn, True)
        nees.append(((said.bias - bias) / said.bias_sigma) ** 2)
    # mean of 200 chi-square(1): 1 +- 0.1 (its standard deviation is sqrt(2/200))
    assert 0.7 < np.mean(nees) < 1.3
    assert said.bias_sigma < math.radians(0.05)  # a second still pins it to 0.05 deg/s


def test_the_agreement_statistic_is_chi_square_when_both_tell_the_truth():
    rng = np.random.default_rng(3)
    fusion = GyroFusion(NOISE, T, "both")
    bias = math.radians(0.3)
    stats = []
    for _ in range(4000):
        _, _, d, q_m, c_m = _mice_solve(rng, 3)
        truth = q_m[2] + rng.normal(0.0, math.sqrt(c_m[2, 2]))  # the mice's error, drawn
        turn = truth + bias * T + rng.normal(0.0, NOISE.density * math.sqrt(T))
        _, _, said = fusion.window(q_m.tolist(), c_m.tolist(), float(turn), True)
        stats.append(said.stat)
    assert np.mean(stats[1000:]) == pytest.approx(1.0, abs=0.12)


def test_a_standstill_measures_the_bias_alone_and_keeps_the_heading():
    """The robot stood still (a zero-velocity update), whatever variance the mice's
    noise model gives a window without counts: the heading stays, and once a span the
    summed turns are a reading of the bias alone (gyrobias.py)."""
    fusion = GyroFusion(NOISE, T, "both")
    c = np.diag([1e-8, 1e-8, 1e-6]).tolist()
    n = round(SPAN_S / T)
    for _ in range(n):
        q, c2, said = fusion.window([0.0, 0.0, 0.0], c, 2e-4, True, still=True)
        assert q == [0.0, 0.0, 0.0] and c2 == c and not said.used
    prior = NOISE.bias_sigma**2 + n * NOISE.bias_walk**2 * T
    s = (n * T) ** 2 * prior + n * NOISE.density**2 * T  # the mice's C_aa taken as 0
    assert fusion.state.bias == pytest.approx(n * T * prior * n * 2e-4 / s, rel=1e-9)


@pytest.mark.parametrize("scale", [-0.03, 0.0, 0.02])
def test_the_scale_is_learnt_in_turns(scale):
    """A gyro reading (1 + s) times the turn (an MPU-6050 is within 3 %): learnt from the
    mice's turns, span by span, to a tenth of a percent in a minute of turning."""
    rng = np.random.default_rng(5)
    fusion = GyroFusion(NOISE, T, "both")
    bias = math.radians(0.4)
    for k in range(6000):
        rate = 1.5 * math.sin(k * T * 0.7)  # rad/s: turning one way and the other
        a = rate * T
        c = np.diag([1e-8, 1e-8, 1e-8]).tolist()
        a_mice = a + rng.normal(0.0, 1e-4)
        turn = (1 + scale) * a + bias * T + rng.normal(0.0, NOISE.density * math.sqrt(T))
        fusion.window([0.0, 0.0, a_mice], c, turn, True)
    assert fusion.state.scale == pytest.approx(scale, abs=1e-3)
    assert fusion.state.bias == pytest.approx(bias, abs=math.radians(0.02))
