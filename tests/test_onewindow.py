"""The daemon's one-window path (mousedom.fusion.onewindow, OneWindowPath.solve) equals the
array path."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.fusion import covariance, integrate, onewindow, sim
from mousedom.fusion.tracker import PoseBatch, Tracker

floats = st.floats(-8.0, 8.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(floats, floats, floats, st.sampled_from(integrate.INTEGRATORS))
def test_scalar_step_and_jacobian_equal_the_array_functions(ux, uy, a, method):
    """Both branches of sinc (|a/2| below and above the switch), every integrator."""
    q = np.array([[ux, uy, a]])
    assert onewindow.sinc(a) == pytest.approx(float(integrate.sinc(a)), rel=1e-14, abs=1e-300)
    assert onewindow.dsinc(a) == pytest.approx(float(integrate.dsinc(a)), rel=1e-12, abs=1e-15)
    want = integrate.body_step(q, method)[0]
    got = onewindow.body_step(ux, uy, a, method)
    assert np.allclose(got, want[:2], rtol=1e-13, atol=1e-13)
    rng = np.random.default_rng(abs(hash((ux, uy, a))) % 2**32)
    m = rng.normal(0, 0.1, (3, 3))
    q_cov = m @ m.T
    theta = float(rng.uniform(-7, 7))
    want_g = covariance.world_step_noise(np.array([theta]), integrate.step_partials(q), q_cov)
    got_g = onewindow.noise(theta, ux, uy, a, q_cov)
    assert np.allclose(got_g, want_g[0], rtol=1e-12, atol=1e-14)


def run(model: str, integrator: str, reports, deaths, small: int, rate_hz: float) -> list:
    """Stream the reports window by window through a tracker with ``_SMALL = small``."""
    cfg = sim.rig_config(sim.Rig(sim.three_mouse_rig().mice, rate_hz=rate_hz))
    tracker = Tracker(cfg, t0=0.0, model=model, integrator=integrator)
    tracker._SMALL = small
    tracker._INGEST_SMALL = 64 if small else 0
    period = 1.0 / rate_hz
    out = []
    for k in range(int(0.25 / period) + 1):
        lo, hi = k * period, (k + 1) * period
        for mouse, at, live in deaths:
            if lo < at <= hi:
                tracker.set_live(mouse, live, at)
        for i in range(3):
            part = [r[1:] for r in reports if r[0] == i and lo < r[1] <= hi]
            if part:
                t, dx, dy = (np.array(c, dtype=float) for c in zip(*part, strict=True))
                # now and then out of order: the tracker clamps and counts "backwards"
                tracker.push(i, t if k % 2 else np.sort(t), dx, dy)
        # now and then far ahead: several windows close and later reports are "late"
        tracker.complete_until(hi if k % 7 else hi + 0.03)
        out.append(tracker.poll(one_by_one=small > 1))  # (several windows: the daemon's)
        for m in tracker._mice:  # _rebase relies on it (a slice, not a mask)
            assert (np.diff(m.knots[0]) >= 0).all(), "knot times must never decrease"
    out.append(tracker.finish())
    out.append(tracker.stats())
    out.append(tracker.counts_in)
    return out


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from(["lsq", "diff-drive"]),
    st.sampled_from(integrate.INTEGRATORS),
    st.lists(
        st.tuples(
            st.integers(0, 2),
            st.floats(0.0, 0.25, allow_nan=False),
            st.integers(-127, 127),
            st.integers(-127, 127),
        ),
        max_size=120,
    ),
    st.lists(st.tuples(st.integers(0, 2), st.floats(0.001, 0.25), st.booleans()), max_size=6),
    st.sampled_from([50.0, 100.0, 333.0]),
)
def test_one_window_path_equals_the_array_path(model, integrator, reports, deaths, rate_hz):
    """Same windows, same poses, covariances, residuals, counts, used and ok flags, with
    mice dying and coming back (rank loss included: two dead mice of three) and now and
    then several windows closing at once (one by one on floats up to ``Tracker._SMALL``,
    beyond it the array path); the reports turned into knots on floats (_ingest_small)
    give the same counts and late/backwards statistics as the array path."""
    *fast, fast_stats, fast_in = run(model, integrator, reports, deaths, Tracker._SMALL, rate_hz)
    *slow, slow_stats, slow_in = run(model, integrator, reports, deaths, 0, rate_hz)
    assert fast_stats == slow_stats
    assert np.array_equal(fast_in, slow_in)
    assert [len(b) for b in fast] == [len(b) for b in slow]
    a, b = PoseBatch.concat(fast, 3), PoseBatch.concat(slow, 3)
    for key in ("t", "used", "ok"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
    # Several windows closed at once: the array path takes each window's counts as the
    # difference of F at its edges, the float path F at each end after rebasing on the
    # one before; equal but for rounding, and summing to the same counts.
    assert np.allclose(a.counts, b.counts, rtol=1e-12, atol=1e-12)
    assert np.allclose(a.counts.sum(axis=0), b.counts.sum(axis=0), rtol=0, atol=1e-9)
    for key in ("x", "y", "theta", "vx", "vy", "omega", "residual"):
        assert np.allclose(getattr(a, key), getattr(b, key), rtol=1e-12, atol=1e-15), key
    assert np.allclose(a.cov, b.cov, rtol=1e-9, atol=1e-18)
