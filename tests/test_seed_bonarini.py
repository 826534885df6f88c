"""Seed: A. Bonarini, M. Matteucci, M. Restelli, "Dead reckoning for mobile robots using two
optical mice" (2004) (seeds/bonarini-two-mice-dead-reckoning.md).

``bonarini`` evaluates their eqs. (3)-(14) in their frame (x along the joining line from the
left mouse to the right one, y forward, origin at the midpoint) and maps the step to the body
origin; eqs. (15)-(16) are replaced by ``integrate.compose`` (a rotation, no arctan).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from mousedom.fusion import models
from mousedom.fusion.geometry import design_matrix
from mousedom.fusion.integrate import body_step, compose


def rigid(q: np.ndarray, positions: np.ndarray) -> np.ndarray:
    return (q @ design_matrix(positions).T).reshape(len(q), -1, 2)


def random_arcs(rng: np.random.Generator, n: int) -> np.ndarray:
    """Twist increments covering forward and backward, left and right turns, large turns."""
    q = np.column_stack(
        [
            rng.uniform(-0.05, 0.05, n),
            rng.uniform(-0.05, 0.05, n),
            rng.uniform(-1.5, 1.5, n) * rng.choice([1e-4, 1e-2, 1.0], n),
        ]
    )
    special = np.array(
        [
            [0.03, 0.0, 0.0],  # straight ahead
            [-0.03, 0.0, 0.0],  # straight back
            [0.0, 0.02, 0.0],  # sideways left
            [0.0, -0.02, 0.0],  # sideways right
            [0.01, -0.02, 0.0],  # oblique
            [0.0, 0.0, 0.3],  # pure rotation about the body origin, CCW
            [0.0, 0.0, -0.3],  # and CW
            [-0.02, 0.01, 0.4],  # backwards while turning left
            [-0.02, -0.01, -0.4],  # backwards while turning right
            [0.0, 0.0, 0.0],  # standing still
        ]
    )
    return np.concatenate([q, special])


GEOMETRIES = [
    np.array([[0.0, 0.1], [0.0, -0.1]]),  # their Figure 1: side by side, centred
    np.array([[0.05, 0.1], [0.02, -0.09]]),  # not symmetric about the body origin
    np.array([[0.1, -0.02], [-0.12, 0.03]]),  # roughly one behind the other
    np.array([[-0.2, 0.0], [0.1, 0.0]]),  # exactly on the body x axis
    np.array([[0.3, 0.3], [0.25, 0.32]]),  # far off-centre and close together
]


@pytest.mark.parametrize("pos", GEOMETRIES)
def test_noise_free_arcs_give_the_same_step_as_lsq_exact(pos):
    """Eqs. (3)-(14) on noise-free two-mouse arcs equal lsq + exact to 1e-9 (and the truth)."""
    rng = np.random.default_rng(7)
    q = random_arcs(rng, 500)
    d = rigid(q, pos)
    bon = models.solve("bonarini", d, pos, 1e-5)
    lsq = models.solve("lsq", d, pos, 1e-5)
    assert bon.ok.all()
    step_b = body_step(bon.q, "exact")
    step_l = body_step(lsq.q, "exact")
    np.testing.assert_allclose(step_b, step_l, atol=1e-9)
    np.testing.assert_allclose(step_b, body_step(q, "exact"), atol=1e-9)
    np.testing.assert_allclose(bon.residual, 0, atol=1e-9)
    # swapping which mouse is listed first changes nothing
    swapped = models.solve("bonarini", d[:, ::-1], pos[::-1], 1e-5)
    np.testing.assert_allclose(swapped.q, bon.q, atol=1e-12)


def test_their_midpoint_step_is_reproduced():
    """bonarini + exact at the midpoint = their (dx, dy, dtheta) of eqs. (13)-(14), (8).

    Check against the geometry of Figure 5: the midpoint, in their frame, turns by dtheta
    about the centre of the arc; and against eq. (9)-(12) evaluated literally (r = l/|dtheta|).
    """
    dist = 0.2
    pos = np.array([[0.0, dist / 2], [0.0, -dist / 2]])  # left mouse at +y: their Figure 1
    rng = np.random.default_rng(8)
    for _ in range(50):
        q = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(-1, 1)])
        d = rigid(q[None], pos)
        # their frame: x from left to right = body -y, y = body x.  Readings:
        xl, yl = -d[0, 0, 1], d[0, 0, 0]
        xr, yr = -d[0, 1, 1], d[0, 1, 0]
        mx, my, dth = models.bonarini_mid(
            np.array([xl]), np.array([yl]), np.array([xr]), np.array([yr]), dist
        )
        # literal eqs. (3), (4), (6)-(7), (9)-(14) in plain floats (dtheta is not 0 here)
        lit = []
        for x, y, off in ((xr, yr, dist / 2), (xl, yl, -dist / 2)):
            alpha = np.arctan(y / x)
            ln = y / np.sin(alpha)
            r = ln / abs(dth[0])
            lit.append(
                (
                    r * (np.sin(alpha + dth[0]) - np.sin(alpha)) * np.sign(dth[0]) + off,
                    r * (np.cos(alpha) - np.cos(alpha + dth[0])) * np.sign(dth[0]),
                )
            )
        np.testing.assert_allclose([mx[0], my[0]], np.mean(lit, axis=0), rtol=1e-9, atol=1e-13)
        # the body origin is the midpoint here, their y is body x and their x is body -y
        step = body_step(models.solve("bonarini", d, pos, 1e-5).q, "exact")[0]
        np.testing.assert_allclose(step, [my[0], -mx[0], dth[0]], atol=1e-13)
        np.testing.assert_allclose(dth[0], q[2], atol=1e-12)  # eq. (8) is the true turn


def test_the_one_deviation_signed_length_at_alpha_zero():
    """Eq. (4) says l = |x| when alpha = 0.  For a slide along the joining line towards the
    left mouse (x < 0, y = 0) that turns the step around; mousedom keeps l = x (signed)."""
    x = np.array([-0.01])
    y = np.array([0.0])
    mx, my, dth = models.bonarini_mid(x, y, x, y, 0.2)
    np.testing.assert_allclose([mx[0], my[0], dth[0]], [-0.01, 0.0, 0.0], atol=1e-17)
    # The same slide the other way is its mirror image: the sign follows the motion, as
    # the literal |x| (+0.01 both ways) would not.
    mx2, my2, dth2 = models.bonarini_mid(-x, y, -x, y, 0.2)
    np.testing.assert_allclose([mx2[0], my2[0], dth2[0]], [0.01, 0.0, 0.0], atol=1e-17)


def test_backwards_motion_composes_correctly_unlike_eqs_15_16():
    """Eqs. (15)-(16) put the step at Theta + arctan(dy/dx), which folds a step with dx < 0
    into the opposite direction (arctan loses the quadrant).  integrate.compose rotates the
    step instead.  Robot backing away to its left: their dx < 0 and dy < 0."""
    pos = np.array([[0.0, 0.1], [0.0, -0.1]])  # their Figure 1: the body origin is the midpoint
    q = np.array([[-0.01, 0.01, 0.0]])
    d = rigid(q, pos)
    sol = models.solve("bonarini", d, pos, 1e-5)
    pose = compose(np.zeros(3), body_step(sol.q, "exact"))[-1]
    np.testing.assert_allclose(pose, [-0.01, 0.01, 0.0], atol=1e-15)
    # their frame: x = body -y, y = body x
    mx, my, dth = models.bonarini_mid(-d[:, 0, 1], d[:, 0, 0], -d[:, 1, 1], d[:, 1, 0], 0.2)
    assert mx[0] < 0 and my[0] < 0
    theta = 0.0  # eq. (15)-(16) with the world axes = their start axes
    big_x = np.hypot(mx[0], my[0]) * np.cos(theta + np.arctan(my[0] / mx[0]))
    big_y = np.hypot(mx[0], my[0]) * np.sin(theta + np.arctan(my[0] / mx[0]))
    np.testing.assert_allclose([big_x, big_y], [-mx[0], -my[0]], rtol=1e-12)  # reflected


def test_with_noise_lsq_has_the_smaller_heading_error_and_bonarini_is_biased_up():
    """With noise, eq. (8)'s |dtheta| = |d_r - d_l| / D also counts the noise along the
    joining line, so it is biased upward; lsq uses only the across-line difference and is
    unbiased.  Fixed seed; a run of 20000 windows (100 Hz): straight, then a gentle left arc
    (0.1 rad/s), then straight; sigma = 1 count at 450 CPI per axis per window.

    The bias adds up window after window, so the heading along the run drifts with bonarini
    and not with lsq.  (Per window, on a turning window whose turn is comparable to the
    noise, bonarini's RMS error is about the same as lsq's; on straight windows it is sqrt(2)
    times larger, since sqrt(dx^2 + dy^2) >= |dy|.)
    """
    rng = np.random.default_rng(2004)
    dist = 0.2
    pos = np.array([[0.03, dist / 2], [0.03, -dist / 2]])
    sigma = 0.0254 / 450
    m = 20000
    q_true = np.tile([2e-3, 0.0, 0.0], (m, 1))
    arc = slice(m // 4, 3 * m // 4)
    q_true[arc, 2] = 1e-3
    d = rigid(q_true, pos) + rng.normal(scale=sigma, size=(m, 2, 2))
    bon = models.solve("bonarini", d, pos, sigma)
    lsq = models.solve("lsq", d, pos, sigma)
    head_true = np.cumsum(q_true[:, 2])
    head_b = compose(np.zeros(3), body_step(bon.q))[:, 2]
    head_l = compose(np.zeros(3), body_step(lsq.q))[:, 2]
    rms_b = np.sqrt(np.mean((head_b - head_true) ** 2))
    rms_l = np.sqrt(np.mean((head_l - head_true) ** 2))
    assert rms_l < rms_b / 3
    assert abs(head_l[-1] - head_true[-1]) < abs(head_b[-1] - head_true[-1]) / 3
    # the upward bias of |dtheta| on the arc, and none for lsq
    err_b = bon.q[arc, 2] - q_true[arc, 2]
    err_l = lsq.q[arc, 2] - q_true[arc, 2]
    se = np.std(err_l) / np.sqrt(len(err_l))
    assert abs(err_l.mean()) < 5 * se
    assert err_b.mean() > 10 * se
    # lsq's reported heading variance 2 sigma^2 / D^2 per window is the observed scatter
    np.testing.assert_allclose(np.var(err_l), lsq.cov[0, 2, 2], rtol=5 * np.sqrt(2 / len(err_l)))
    # on the straight windows lsq's per-window heading error is smaller
    straight = np.ones(m, bool)
    straight[arc] = False
    assert np.sqrt(np.mean(lsq.q[straight, 2] ** 2)) < np.sqrt(np.mean(bon.q[straight, 2] ** 2))


def test_straight_runs_always_read_a_bigger_turn_with_bonarini():
    """On a straight run (true dtheta = 0) |dtheta_bonarini| >= |dtheta_lsq| in every window:
    sqrt(dx^2 + dy^2) >= |dy|, eq. (8)."""
    rng = np.random.default_rng(5)
    pos = np.array([[0.0, 0.1], [0.0, -0.1]])
    d = rigid(np.tile([3e-3, 0.0, 0.0], (2000, 1)), pos) + rng.normal(scale=1e-4, size=(2000, 2, 2))
    bon = models.solve("bonarini", d, pos, 1e-4)
    lsq = models.solve("lsq", d, pos, 1e-4)
    assert np.all(np.abs(bon.q[:, 2]) >= np.abs(lsq.q[:, 2]) - 1e-15)


def test_bonarini_covariance_linearises_to_lsq_for_small_noise():
    """Noise-free, the two-mouse map linearises to the same estimator as equal-weight lsq."""
    pos = np.array([[0.05, 0.1], [0.02, -0.09]])
    rng = np.random.default_rng(9)
    q = random_arcs(rng, 50)
    q = q[np.abs(q[:, 2]) > 1e-3]  # away from the cone point of eq. (8) at dtheta = 0
    d = rigid(q, pos)
    bon = models.solve("bonarini", d, pos, 1e-5)
    lsq = models.solve("lsq", d, pos, 1e-5)
    np.testing.assert_allclose(bon.cov, lsq.cov, rtol=1e-4, atol=1e-16)


@pytest.mark.parametrize("pos", GEOMETRIES, ids=range(len(GEOMETRIES)))
def test_bonarini_covariance_stays_finite_where_eq_8_turns_sign(pos):
    """Straight windows with noise: the two forward readings cross, and eq. (8)'s turn jumps
    sign there.  The linearisation is taken on the window's own side of the jump: no window
    is far above the lsq heading variance, and a drive's summed variance is the lsq one
    (central differences across the jump had given up to 2.4e7 times it in one window)."""
    rng = np.random.default_rng(5)
    sigma = 0.0254 / 450  # one count at 450 CPI
    n = 20000
    d = rigid(np.tile([0.003, 0.0, 0.0], (n, 1)), pos) + rng.normal(0, sigma, (n, 2, 2))
    bon = models.solve("bonarini", d, pos, sigma)
    lsq = models.solve("lsq", d, pos, sigma)
    ratio = bon.cov[:, 2, 2] / lsq.cov[:, 2, 2]
    assert ratio.max() < 10, ratio.max()
    assert bon.cov[:, 2, 2].sum() / lsq.cov[:, 2, 2].sum() == pytest.approx(1.0, rel=0.1)
    assert np.all(np.linalg.eigvalsh(bon.cov) > -1e-18)


@settings(max_examples=300, deadline=None)
@example(p=(0.25, 0.0, 0.0, 0.0), q=(0.027007315427299533, 0.0, 1.401298464324817e-45))
@example(p=(5e-324, 0.0625, 0.0, 0.0), q=(0.0, 0.046875, 0.0))
@given(
    p=st.tuples(*[st.floats(-0.3, 0.3) for _ in range(4)]),
    q=st.tuples(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05), st.floats(-2.0, 2.0)),
)
def test_noise_free_any_geometry_any_arc(p, q):
    """Eqs. (3)-(14) + the frame mapping equal lsq + exact for any two distinct mounts and
    any constant-twist window (hypothesis).  The first @example is a nearly straight window
    where eq. (8)'s law of cosines, evaluated literally, kept only half the digits (2e-9 rad);
    the second moves along the joining line, where alpha is tiny but not zero and eq. (4)'s
    y / sin(alpha) lost every digit."""
    pos = np.array(p).reshape(2, 2)
    assume(np.hypot(*(pos[0] - pos[1])) > 0.02)
    qa = np.array([q])
    d = rigid(qa, pos)
    bon = models.solve("bonarini", d, pos, 1e-5)
    np.testing.assert_allclose(body_step(bon.q), body_step(qa), atol=1e-9)
