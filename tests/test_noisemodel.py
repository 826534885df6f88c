"""The noise model's learning (mousedom.fusion.noisemodel): its batch paths equal its
window-by-window one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.fusion.noisemodel import _KEEP, _TAIL, NoiseModel, _medians, norm2


def _model(n: int) -> NoiseModel:
    # window 0.05 s: blocks of 20 windows, so a few hundred rows cross many block ends
    return NoiseModel(np.full(n, 1e-5), 0.03, np.full(n, 0.001), 0.05)


def _state(nm: NoiseModel) -> tuple:
    held = [s.newest(len(s)).tolist() for s in (*nm._floor, *nm._prop)]
    return (nm.lam_f.tolist(), nm.lam_r.tolist(), nm.version, nm.seen, nm._seen_len, held)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 4),
    rows=st.integers(1, 400),
    seen=st.integers(0, 19),
    before=st.integers(0, 300),
    start=st.integers(0, 30),
    scale_step=st.integers(0, 400),
    seed=st.integers(0, 2**32 - 1),
    sampling=st.booleans(),
)
def test_extend_blocks_is_extend_and_end_block_window_by_window(
    n, rows, seen, before, start, scale_step, seed, sampling
):
    """Rows accepted in one run: the same samples held, factors and version as the
    per-window path, which stops after the first block end that changes a factor."""
    rng = np.random.default_rng(seed)
    a, b = _model(n), _model(n)
    for nm in (a, b):  # the same history: samples of earlier blocks and of this one
        r = np.random.default_rng(seed + 1)
        for _ in range(before):
            i = int(r.integers(n))
            nm.sample(i, float(r.exponential(2e-10)), 1e-8, float(r.uniform(0, 4e-8)), 0.3)
            if r.random() < 0.05:
                nm.end_block()
        nm.seen = seen
    total = start + rows
    # values whose level jumps at row scale_step: the medians move, a factor changes there
    level = np.where(np.arange(total) < scale_step, 1.0, 50.0)[:, None]
    fl = rng.exponential(1.0, (total, n)) * level * 100.0
    pr = rng.exponential(1.0, (total, n)) * level
    by_floor = rng.random((total, n)) < 0.7
    by_prop = rng.random((total, n)) < 0.5
    values = (fl, by_floor, pr, by_prop) if sampling else None

    expected_stop = total
    for j in range(start, total):
        v0 = a.version
        if values is not None:
            a.extend(values, slice(j, j + 1))
        a.seen += 1
        if a.seen >= a.block:
            a.end_block()
            if a.version != v0:
                expected_stop = j + 1
                break
    got_stop = b.extend_blocks(values, start, total)
    assert got_stop == expected_stop
    assert _state(b) == _state(a)


def test_estimates_are_the_median_or_the_tails_whichever_is_larger():
    """Below 20 samples the median (numpy's); from 20 on, the larger of the median and
    the tail's quantile (_TAIL) extrapolated as an exponential tail in |r| to the test's
    false alarm (ln 2 ln(1 / alpha) / ln(1 / (1 - _TAIL))^2): timing noise with a heavy
    tail must widen a mouse's tolerance (noisemodel._middles)."""
    rng = np.random.default_rng(3)
    for length in (10, 11, 19):
        arrays = [rng.standard_normal(length) for _ in range(7)]
        assert _medians(arrays) == [float(np.median(x)) for x in arrays]
    for length in (20, 255, 256, _KEEP):
        arrays = [rng.standard_normal(length) for _ in range(5)]
        arrays += [rng.exponential(1.0, length) ** 3 for _ in range(5)]  # heavy tails
        want = []
        for x in arrays:
            tail = np.sort(x)[int(np.floor(_TAIL * (length - 1)))]
            scale = math.log(2) * math.log(1e4) / math.log(1 / (1 - _TAIL)) ** 2
            want.append(max(float(np.median(x)), scale * tail))
        assert _medians(arrays) == pytest.approx(want, rel=1e-12)
        # a chi-square(2) sample's estimate is its median widened by the exponential
        # tail's allowance over a Gaussian's: ln(1e4) / ln(200) = 1.74
        chi2 = rng.chisquare(2, _KEEP) / (2 * math.log(2))
        widened = math.log(1e4) / math.log(1 / (1 - _TAIL))
        assert _medians([chi2])[0] == pytest.approx(widened * float(np.median(chi2)), rel=0.3)


def test_norm2_is_the_sum_of_squares_bit_for_bit():
    v = np.random.default_rng(4).standard_normal((50, 4, 2)) * 1e3
    assert np.array_equal(norm2(v), np.sum(v * v, axis=-1))


@settings(max_examples=200, deadline=None)
@given(
    ratio=st.one_of(
        st.floats(0.85, 1.1),
        st.sampled_from([0.9025, 0.9025 * (1 + 1e-6), 1.05, 1.05 * (1 - 1e-6), 0.0, -1.0]),
    ),
    lam=st.one_of(st.floats(1.0, 1e4), st.sampled_from([1.0, 1.05, 1 / 0.95, 1.0527])),
    length=st.just(_KEEP),
    spread=st.floats(0.0, 0.5),
    nans=st.integers(0, 140),
    seed=st.integers(0, 2**32 - 1),
)
def test_estimates_move_a_factor_exactly_where_the_median_does(
    ratio, lam, length, spread, nans, seed
):
    """The counting shortcut (median surely in the band that moves nothing) decides as the
    exact median does, near the band's edges too, with NaN among the samples."""
    from mousedom.fusion.noisemodel import _estimates, _middles, _moved

    rng = np.random.default_rng(seed)
    rows = ratio * lam * (1.0 + spread * rng.standard_normal((6, length)))
    rows[:, 0] = ratio * lam  # values on the bounds themselves
    rows[rng.random(rows.shape) < nans / length] = np.nan
    lams = np.full(6, lam)
    exact = _middles(rows.copy())
    got = _estimates(rows.ravel(), np.full(6, length), lams, np.arange(6) * length,
                     np.arange(6))  # fmt: skip
    new_exact, moved_exact = _moved(lams, exact)
    new_got, moved_got = _moved(lams, got)
    assert moved_got.tolist() == moved_exact.tolist()
    assert np.array_equal(new_got[moved_got], new_exact[moved_exact])
