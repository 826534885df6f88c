"""Integrators and pose composition (mousedom.fusion.integrate)."""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mousedom.fusion import integrate
from mousedom.fusion.integrate import INTEGRATORS, body_step, compose, inverse_exact, step_jacobian

EPS = np.finfo(float).eps


def _reference_sc(a: float, prec: int = 60) -> tuple[float, float]:
    """(sin a / a, (1 - cos a)/a) from their power series in 60-digit Decimal arithmetic.

    S = sum (-1)^k a^(2k) / (2k+1)!,  C = sum (-1)^k a^(2k+1) / (2k+2)!  (no 1 - cos a).
    """
    with localcontext() as ctx:
        ctx.prec = prec
        x = Decimal(a)
        s, c = Decimal(0), Decimal(0)
        term = Decimal(1)  # x^j / (j+1)!
        for j in range(120):
            sign = 1 if (j // 2) % 2 == 0 else -1
            if j % 2 == 0:
                s += sign * term
            else:
                c += sign * term
            term = term * x / (j + 2)
        return float(s), float(c)


ANGLES = np.concatenate(
    [
        [0.0, 5e-324, 1e-300, 1e-20, 1e-12, 1e-8],
        np.geomspace(1e-6, 6.0, 300),
        2.0 * np.array([1 - 1e-15, 1.0, 1 + 1e-15]),  # a = 2 is where the sinc series switches
    ]
)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_exact_coefficients_accurate_to_rounding_everywhere(sign):
    """S = sin(a)/a and C = (1 - cos a)/a to a few ulp from a = 0 through a = 6, both signs.

    The naive (1 - cos a)/a loses every digit as a -> 0; the sinc(a/2)-based form must not.
    """
    a = sign * ANGLES
    s, c = integrate.exp_coefficients(a)
    for ai, si, ci in zip(a, s, c, strict=True):
        rs, rc = _reference_sc(float(ai))
        assert abs(si - rs) <= 4 * EPS * abs(rs), (ai, si, rs)
        assert abs(ci - rc) <= 4 * EPS * abs(rc) + 1e-320, (ai, ci, rc)


def test_naive_formula_would_fail_the_same_check():
    """The accuracy test above can fail: (1 - cos a)/a at a = 1e-6 is off by far more."""
    a = 1e-6
    _, rc = _reference_sc(a)
    naive = (1 - math.cos(a)) / a
    assert abs(naive - rc) > 1e3 * EPS * rc


def test_sinc_series_and_closed_form_meet_continuously():
    """Around the switch point the series and sin(h)/h agree to rounding (no jump)."""
    h = np.linspace(0.8, 1.2, 4001)
    series = integrate._horner(h * h, integrate._SINC_COEF)
    closed = np.sin(h) / h
    assert np.max(np.abs(series - closed)) <= 3 * EPS
    dseries = h * integrate._horner(h * h, integrate._DSINC_COEF)
    dclosed = (h * np.cos(h) - np.sin(h)) / (h * h)
    assert np.max(np.abs(dseries - dclosed)) <= 8 * EPS
    # and the public functions step across it smoothly
    sw = integrate._SINC_SWITCH
    below, above = np.nextafter(sw, 0), sw
    assert abs(integrate.sinc(below) - integrate.sinc(above)) < 3 * EPS
    assert abs(integrate.dsinc(below) - integrate.dsinc(above)) < 8 * EPS


def test_exact_step_is_the_se2_exponential():
    """exact = (u_x sin a - u_y (1 - cos a), u_x (1 - cos a) + u_y sin a)/a where a is large."""
    rng = np.random.default_rng(2)
    q = rng.normal(size=(200, 3))
    q[:, 2] = rng.uniform(0.5, 3.0, 200) * rng.choice([-1, 1], 200)
    ux, uy, a = q.T
    want = np.stack(
        [
            (ux * np.sin(a) - uy * (1 - np.cos(a))) / a,
            (ux * (1 - np.cos(a)) + uy * np.sin(a)) / a,
            a,
        ],
        axis=1,
    )
    np.testing.assert_allclose(body_step(q, "exact"), want, rtol=1e-13, atol=1e-15)


def test_zero_rotation_is_a_plain_translation_for_every_integrator():
    q = np.array([[0.3, -0.2, 0.0], [-1.0, 0.0, 0.0]])
    for method in INTEGRATORS:
        np.testing.assert_array_equal(body_step(q, method), q)


def test_approximate_integrators_are_the_seed_formulas():
    """taylor: Hong's approximation; euler: Hong's "previous approximation" R(a) u;
    midpoint: McGill's R(a/2) u (Hong, section 3 table; McGill, Derivation 2)."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(50, 3))
    ux, uy, a = q.T
    taylor = np.stack([ux * (1 - a**2 / 6) - uy * a / 2, ux * a / 2 + uy * (1 - a**2 / 6), a], 1)
    euler = np.stack([ux * np.cos(a) - uy * np.sin(a), ux * np.sin(a) + uy * np.cos(a), a], 1)
    h = a / 2
    mid = np.stack([ux * np.cos(h) - uy * np.sin(h), ux * np.sin(h) + uy * np.cos(h), a], 1)
    np.testing.assert_allclose(body_step(q, "taylor"), taylor, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(body_step(q, "euler"), euler, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(body_step(q, "midpoint"), mid, rtol=1e-14, atol=1e-15)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="unknown integrator"):
        body_step(np.zeros((1, 3)), "rk4")
    with pytest.raises(ValueError, match="shape"):
        body_step(np.zeros((3,)), "exact")
    with pytest.raises(ValueError, match="shape"):
        compose(np.zeros(3), np.zeros((2, 2)))


def _fd_jacobian(q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    jac = np.zeros((len(q), 3, 3))
    for j in range(3):
        dq = np.zeros(3)
        dq[j] = h
        jac[:, :, j] = (body_step(q + dq) - body_step(q - dq)) / (2 * h)
    return jac


def test_step_jacobian_matches_finite_differences():
    """The analytic d(step)/dq against central differences, near 0, at the switch and beyond."""
    rng = np.random.default_rng(4)
    a = np.concatenate([[0.0, 1e-9, -1e-5, 0.01, 1.999, 2.0, 2.001, -2.0], rng.uniform(-3, 3, 40)])
    q = np.column_stack([rng.normal(size=len(a)), rng.normal(size=len(a)), a])
    np.testing.assert_allclose(step_jacobian(q), _fd_jacobian(q), rtol=1e-7, atol=1e-8)


def test_step_jacobian_is_smooth_across_the_series_switch():
    a = np.array([2 * np.nextafter(1.0, 0), 2.0])
    q = np.column_stack([[0.7, 0.7], [-0.4, -0.4], a])
    jac = step_jacobian(q)
    assert np.max(np.abs(jac[0] - jac[1])) < 1e-14


finite = st.floats(-10, 10, allow_nan=False)
angle = st.floats(-6.0, 6.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(ux=finite, uy=finite, a=angle)
def test_inverse_exact_undoes_body_step(ux, uy, a):
    q = np.array([[ux, uy, a]])
    back = inverse_exact(body_step(q, "exact"))
    np.testing.assert_allclose(back, q, rtol=1e-10, atol=1e-12)


def _compose_loop(start, steps):
    """The recursion p_k = p_{k-1} + R(theta_{k-1}) step_k written out one step at a time."""
    x, y, th = start
    out = []
    for dx, dy, da in steps:
        x += math.cos(th) * dx - math.sin(th) * dy
        y += math.sin(th) * dx + math.cos(th) * dy
        th += da
        out.append((x, y, th))
    return np.array(out).reshape(-1, 3)


def test_compose_equals_the_step_by_step_recursion():
    rng = np.random.default_rng(5)
    steps = rng.normal(size=(500, 3)) * [0.01, 0.01, 0.2]
    start = np.array([1.0, -2.0, 0.3])
    np.testing.assert_allclose(compose(start, steps), _compose_loop(start, steps), atol=1e-13)


def test_compose_known_paths():
    # four quarter-turn arcs of radius 1 close the circle; the heading is unwrapped (2 pi)
    q = np.tile([[np.pi / 2, 0.0, np.pi / 2]], (4, 1))
    poses = compose(np.zeros(3), body_step(q, "exact"))
    np.testing.assert_allclose(poses[0], [1, 1, np.pi / 2], atol=1e-15)
    np.testing.assert_allclose(poses[1], [0, 2, np.pi], atol=1e-15)
    np.testing.assert_allclose(poses[-1], [0, 0, 2 * np.pi], atol=1e-15)
    # a step forward from a start facing +y moves +y
    np.testing.assert_allclose(
        compose([0, 0, np.pi / 2], [[1, 0, 0]]), [[0, 1, np.pi / 2]], atol=1e-16
    )
    assert compose(np.zeros(3), np.zeros((0, 3))).shape == (0, 3)


steps_strategy = arrays(
    float,
    st.tuples(st.integers(0, 60), st.just(3)),
    elements=st.floats(-2, 2, allow_nan=False, width=64),
)


@settings(max_examples=150, deadline=None)
@given(
    steps=steps_strategy,
    cuts=st.lists(st.integers(0, 60), max_size=6),
    start=st.tuples(finite, finite, angle),
)
def test_compose_in_batches_equals_one_batch(steps, cuts, start):
    """Composing batch after batch (start = previous batch's last pose) equals one big batch."""
    whole = compose(np.array(start), steps)
    edges = sorted({min(c, len(steps)) for c in cuts} | {0, len(steps)})
    pose = np.array(start, dtype=float)
    parts = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        part = compose(pose, steps[lo:hi])
        if len(part):
            pose = part[-1]
        parts.append(part)
    batched = np.concatenate(parts) if parts else np.zeros((0, 3))
    np.testing.assert_allclose(batched, whole, rtol=0, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(ux=finite, uy=finite, a=st.floats(-3, 3), k=st.integers(1, 50))
def test_exact_steps_of_a_split_window_compose_to_the_whole(ux, uy, a, k):
    """exp(xi)^k = exp(k xi): k windows of one constant twist give the one-window step."""
    q = np.array([[ux, uy, a]])
    whole = body_step(q)[0]
    poses = compose(np.zeros(3), body_step(np.repeat(q / k, k, axis=0)))
    np.testing.assert_allclose(poses[-1], whole, rtol=1e-11, atol=1e-11)
