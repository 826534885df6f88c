"""Seed: S. Kim and S. Lee, "Optical Mouse Array Position Calibration for Mobile Robot
Velocity Estimation" (seeds/kim-lee-mouse-array-calibration.md).

mousedom's ``lsq`` is their eq. (7)-(8) with displacements per window in place of
velocities (the window length is a common factor) and optional per-mouse weights.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.fusion import models


def polygon(n: int, r: float, theta: float) -> np.ndarray:
    """Eq. (1): mouse i at r (cos, sin)(theta + (i-1) 2 pi / N)."""
    ang = theta + np.arange(n) * 2 * np.pi / n
    return r * np.column_stack([np.cos(ang), np.sin(ang)])


def test_polygon_is_centred():
    """Eq. (2): sum p_ix = sum p_iy = 0 whatever the heading angle theta."""
    for n in range(3, 9):
        np.testing.assert_allclose(polygon(n, 0.3, 0.7).sum(axis=0), 0, atol=1e-15)


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(3, 8),
    r=st.floats(0.01, 1.0),
    theta=st.floats(-10.0, 10.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_lsq_is_the_simple_average_for_a_regular_polygon(n, r, theta, seed):
    """Eq. (9)-(10): for a regular polygon, v_bx and v_by are the means of the mice's readings
    and omega_b the mean of omega_i = (-sin(phi_i) v_ix + cos(phi_i) v_iy)/r.

    This holds for any readings, rigid or not: it is the least-squares formula itself.
    """
    rng = np.random.default_rng(seed)
    pos = polygon(n, r, theta)
    vs = rng.normal(size=(5, n, 2))
    sol = models.solve("lsq", vs, pos, 1.0)
    phi = theta + np.arange(n) * 2 * np.pi / n
    omega_i = (-np.sin(phi) * vs[:, :, 0] + np.cos(phi) * vs[:, :, 1]) / r  # eq. (10)
    want = np.column_stack([vs[:, :, 0].mean(1), vs[:, :, 1].mean(1), omega_i.mean(1)])
    np.testing.assert_allclose(sol.q, want, rtol=1e-9, atol=1e-12 / r)


def test_variance_sigma_squared_over_n_analytic():
    """Eq. (14): var[v_bx] = var[v_by] = sigma^2 / N, as the reported covariance."""
    sigma = 0.02
    for n in range(3, 9):
        sol = models.solve("lsq", np.zeros((1, n, 2)), polygon(n, 0.3, 0.1), sigma)
        np.testing.assert_allclose(np.diag(sol.cov[0])[:2], sigma**2 / n, rtol=1e-12)
        # and the heading: var[omega_b] = sigma^2 / (N r^2)
        np.testing.assert_allclose(sol.cov[0, 2, 2], sigma**2 / (n * 0.3**2), rtol=1e-12)


def test_variance_sigma_squared_over_n_monte_carlo():
    """Eq. (11)-(14) by simulation: travel along x at mu with i.i.d. noise sigma per reading;
    the estimates have mean (mu, 0) and variance sigma^2/N.

    With M samples the sample variance has relative standard error sqrt(2/(M-1)) and the mean
    has standard error sqrt(sigma^2/N/M); both are asserted within 5 standard errors.
    """
    rng = np.random.default_rng(2008)
    mu, sigma, m = 0.25, 0.01, 20000
    for n in (3, 4, 6, 8):
        pos = polygon(n, 0.3, -np.pi / 6)
        vs = np.zeros((m, n, 2))
        vs[:, :, 0] = mu
        vs += rng.normal(scale=sigma, size=vs.shape)
        sol = models.solve("lsq", vs, pos, sigma)
        se_mean = np.sqrt(sigma**2 / n / m)
        assert abs(sol.q[:, 0].mean() - mu) < 5 * se_mean  # eq. (13)
        assert abs(sol.q[:, 1].mean()) < 5 * se_mean
        tol = 5 * np.sqrt(2 / (m - 1))
        for k in (0, 1):
            assert abs(sol.q[:, k].var(ddof=1) / (sigma**2 / n) - 1) < tol  # eq. (14)
        # more mice, less noise: the scatter really shrinks as 1/N (the test can fail)
        assert sol.q[:, 0].var() < 1.5 * sigma**2 / n


def test_section_v_example_geometry_and_position_error():
    """Eq. (51)-(52) and Section V: the regular triangle r = 0.3, theta = -pi/6; the real
    array is 5 % bigger than the nominal one.  In self-rotation at omega_b = 1/3 rad/s, the
    nominal (wrong) positions overestimate omega_b by exactly that 5 % (noise-free), which is
    why their calibrated estimate lies below the uncalibrated one in Fig. 3.
    """
    nominal = polygon(3, 0.3, -np.pi / 6)
    eq51 = 0.3 * np.array([0.866, -0.500, 0.000, 1.000, -0.866, -0.500])
    np.testing.assert_allclose(nominal.reshape(-1), eq51, atol=0.3 * 5e-4)
    actual = 1.05 * nominal  # eq. (52)
    omega = 1.0 / 3.0
    dt = 0.01
    # Self-rotation by omega dt about the origin: each mouse moves perpendicular to its
    # position vector, d_i = omega dt (-p_iy, p_ix) (eq. (3) with v_b = 0), written out.
    readings = (omega * dt * np.stack([-actual[:, 1], actual[:, 0]], axis=1)).reshape(1, 3, 2)
    with_nominal = models.solve("lsq", readings, nominal, 1.0)
    with_actual = models.solve("lsq", readings, actual, 1.0)
    np.testing.assert_allclose(with_actual.q[0], [0, 0, omega * dt], atol=1e-15)
    np.testing.assert_allclose(with_nominal.q[0], [0, 0, 1.05 * omega * dt], atol=1e-15)
