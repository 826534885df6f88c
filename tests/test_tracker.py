"""The tracker: windows, watermarks, proportional splitting, conservation of counts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.fusion import sim
from mousedom.fusion.covariance import CovarianceState, propagate
from mousedom.fusion.tracker import PoseBatch, Tracker


def rig3(**kw) -> sim.Rig:
    return sim.three_mouse_rig(**kw)


def poses_until(p: PoseBatch, t: float) -> PoseBatch:
    sel = p.t <= t
    return PoseBatch(**{k: None if v is None else v[sel] for k, v in vars(p).items()})


def stream(tracker: Tracker, result: sim.SimResult, chunk: float) -> PoseBatch:
    """Feed reports in time chunks like a live source would, polling after each."""
    out = []
    end = result.duration
    for lo in np.arange(0.0, end + chunk, chunk):
        hi = lo + chunk
        for name, r in result.reports.items():
            sel = (r.t > lo) & (r.t <= hi) if lo > 0 else r.t <= hi
            tracker.push(name, r.t[sel], r.dx[sel], r.dy[sel])
        tracker.complete_until(hi)
        out.append(tracker.poll())
    out.append(tracker.finish())
    return PoseBatch.concat(out)


@pytest.mark.parametrize("rate_hz", [7.0, 100.0, 333.0, 2000.0])
def test_exact_recovers_a_constant_twist_arc(rate_hz):
    """DESIGN 'exact' integrator: without quantization the pose is exact, any window length."""
    rig = sim.Rig(
        tuple(
            sim.SimMouse(n, x, y, yaw, quantize=False, report_hz=125, phase=ph)
            for n, x, y, yaw, ph in [
                ("a", 0.2, 0.0, 0.0, 0.0),
                ("b", -0.1, 0.15, 30.0, 0.003),
                ("c", -0.1, -0.15, -60.0, 0.0051),
            ]
        ),
        rate_hz=rate_hz,
    )
    res = sim.simulate(rig, sim.arc(0.7, 2.0, 0.25))
    poses, _ = sim.run_tracker(res)
    # Windows ending a report period before the motion stops: after that, the last
    # reports spread motion that had already ended over their whole period.
    poses = poses_until(poses, res.duration - 1 / 125)
    assert len(poses) >= rate_hz * 5
    truth = res.truth(poses.t)
    assert np.abs(poses.x - truth[:, 0]).max() < 1e-9
    assert np.abs(poses.y - truth[:, 1]).max() < 1e-9
    assert np.abs(poses.theta - truth[:, 2]).max() < 1e-9


def test_streaming_equals_one_batch():
    res = sim.simulate(rig3(), sim.sequence(sim.arc(0.5, 1.0), sim.turn(-1.0), sim.straight(0.3)))
    batch, _ = sim.run_tracker(res)
    streamed = stream(Tracker(sim.rig_config(res.rig), t0=0.0), res, chunk=0.0137)
    # Streaming also closes the empty windows that pass after the motion ended.
    assert len(streamed) > len(batch)
    assert not streamed.counts[len(batch) :].any()
    streamed = poses_until(streamed, batch.t[-1] + 1e-9)
    for key in ("t", "x", "y", "theta", "vx", "omega"):
        assert np.allclose(getattr(streamed, key), getattr(batch, key), atol=1e-9), key
    assert np.allclose(streamed.counts, batch.counts, atol=1e-9)
    assert np.allclose(streamed.cov, batch.cov, atol=1e-12, rtol=1e-9)


report_lists = st.lists(
    st.tuples(
        st.integers(0, 2),  # mouse
        st.floats(0.0, 0.5, allow_nan=False),  # time
        st.integers(-127, 127),
        st.integers(-127, 127),
    ),
    max_size=80,
)


@settings(max_examples=200, deadline=None)
@given(
    report_lists,
    st.lists(st.floats(0.0, 0.6), max_size=6),
    st.floats(20, 2000),
    st.sampled_from([0.0, 1000.000021, 123456.789]),
)
def test_no_count_is_ever_lost(reports, cuts, rate_hz, offset):
    """DESIGN 'Counts are never lost': counts in == counts out, in any feeding order, with
    stamps rounded to microseconds far from zero as real clocks give them."""
    cfg = sim.rig_config(sim.Rig(rig3().mice, rate_hz=rate_hz))
    tracker = Tracker(cfg)
    cuts = sorted(round(offset + c, 6) for c in cuts) + [math.inf]
    reports = [(i, round(offset + t, 6), dx, dy) for i, t, dx, dy in reports]
    by_mouse = {i: sorted(r[1:] for r in reports if r[0] == i) for i in range(3)}
    pos = {i: 0 for i in range(3)}
    windows = []
    for cut in cuts:
        for i, rs in by_mouse.items():
            part = [r for r in rs[pos[i] :] if r[0] <= cut]
            pos[i] += len(part)
            if part:
                t, dx, dy = map(np.array, zip(*part, strict=True))
                tracker.push(i, t, dx, dy)
        if cut != math.inf:
            tracker.complete_until(cut)
            windows.append(tracker.poll())
    windows.append(tracker.finish())
    out = PoseBatch.concat(windows, 3)
    total_in = np.zeros((3, 2))
    for i, rs in by_mouse.items():
        for _, dx, dy in rs:
            total_in[i] += (dx, dy)
    assert np.allclose(tracker.counts_in, total_in)
    assert np.allclose(out.counts.sum(axis=0), total_in, atol=1e-9)
    assert np.allclose(tracker.counts_out, total_in, atol=1e-9)
    assert np.all(np.diff(out.t) > 0)


def test_split_in_proportion_to_time():
    cfg = sim.rig_config(sim.Rig(rig3().mice, rate_hz=100.0))  # 10 ms windows
    tr = Tracker(cfg, t0=0.0)
    # Mouse 0 reports at 6 ms and 14 ms (8 ms period): the second report spans the edge at
    # 10 ms and is split 4:4 between the first two windows.
    tr.push(0, np.array([0.006, 0.014]), np.array([0.0, 0.0]), np.array([-8.0, -8.0]))
    out = tr.finish()
    assert out.counts[:, 0, 1] == pytest.approx([-12.0, -4.0])


def test_a_silent_mouse_holds_windows_until_declared_complete():
    cfg = sim.rig_config(rig3())
    tr = Tracker(cfg, t0=0.0)
    tr.push("front", np.arange(1, 20) * 0.008, np.zeros(19), -np.ones(19))
    assert len(tr.poll()) == 0  # left and right have said nothing yet
    tr.complete_until(0.1)
    out = tr.poll()
    # Motion is final up to the last report (0.152) for 'front' and up to 0.1 - 1/125
    # for the silent ones: windows up to 0.09 close.
    assert out.t[-1] == pytest.approx(0.09)
    assert len(out) == 9


@pytest.mark.parametrize("report_hz", [60.0, 125.0, 500.0, 1000.0, 8000.0])
def test_a_window_closes_once_every_silent_mouse_is_complete_a_report_period_past_it(
    report_hz,
):
    """A silent mouse's motion is final up to its completion time less its own report
    period (a later report covers at most one period back), not the window's: window k
    closes once every mouse is complete to its end plus the report period, not before."""
    from mousedom.config import parse_config

    mice = "".join(
        f"  {n}: {{cpi: 1000, mount: {{x: {x}, y: {y}}}, report_hz: {report_hz}}}\n"
        for n, x, y in (("a", 0.1, 0.0), ("b", -0.1, 0.0), ("c", 0.0, 0.1))
    )
    cfg = parse_config(f"rate_hz: 100\nmodel: lsq\nmice:\n{mice}", need_sources=False)
    tr = Tracker(cfg, t0=0.0)
    report_period = 1.0 / report_hz
    closed = 0
    for k in range(1, 6):
        end = 0.01 * k
        tr.complete_until(end + 0.75 * report_period)  # final up to a quarter before the end
        closed += len(tr.poll())
        assert closed == k - 1
        tr.complete_until(end + 1.25 * report_period)
        closed += len(tr.poll())
        assert closed == k


def test_late_and_backwards_reports_are_kept_and_counted():
    cfg = sim.rig_config(rig3())
    tr = Tracker(cfg, t0=0.0)
    tr.complete_until(0.1)
    first = tr.poll()
    tr.push("front", np.array([0.05, 0.12, 0.11]), np.array([1.0, 2.0, 3.0]), np.zeros(3))
    rest = tr.finish()
    assert first.counts.sum() == 0
    assert rest.counts[:, 0, 0].sum() == pytest.approx(6.0)
    assert tr.stats()["front"] == {"late": 1, "backwards": 1}


@pytest.mark.parametrize("small", [True, False])
def test_a_push_that_starts_behind_the_last_one_is_clamped(monkeypatch, small):
    """Each push in order, the second starting before the first ended (two reads of a
    clock that stepped back): clamped to the last stamp and counted, by the list path
    and by the array path (whose shortcut for sorted stamps must look across pushes)."""
    if not small:
        monkeypatch.setattr(Tracker, "_INGEST_SMALL", 0)
    cfg = sim.rig_config(rig3())
    tr = Tracker(cfg, t0=0.0)
    tr.push("front", np.array([0.020, 0.030]), np.array([1.0, 1.0]), np.zeros(2))
    assert tr.stats()["front"]["backwards"] == 0  # the first push becomes knots
    tr.push("front", np.array([0.025, 0.026]), np.array([2.0, 4.0]), np.zeros(2))
    out = tr.finish()
    assert tr.stats()["front"]["backwards"] == 2
    assert out.counts[:, 0, 0].sum() == pytest.approx(8.0)
    # the clamped reports land at 0.030, in the window ending there
    assert out.counts[np.isclose(out.t, 0.03), 0, 0].sum() == pytest.approx(7.0)


def test_degraded_operation_keeps_going_with_rank_and_holds_without():
    res = sim.simulate(rig3(), sim.straight(0.5, 0.25))
    cfg = sim.rig_config(res.rig)
    tr = Tracker(cfg, t0=0.0)
    tr.set_live("left", False, 0.5)
    tr.set_live("left", True, 1.2)
    for name, r in res.reports.items():
        keep = ~((r.t > 0.5) & (r.t < 1.2)) if name == "left" else slice(None)
        tr.push(name, r.t[keep], r.dx[keep], r.dy[keep])
    out = tr.finish()
    assert set(np.unique(out.used)) == {2, 3}
    assert out.ok.all()
    assert out.x[-1] == pytest.approx(0.5, abs=5e-4)

    two = sim.Rig(rig3().mice[:2])
    res2 = sim.simulate(two, sim.straight(0.5, 0.25))
    tr2 = Tracker(sim.rig_config(two), t0=0.0)
    tr2.set_live("left", False, 1.0)
    for name, r in res2.reports.items():
        keep = r.t < 1.0 if name == "left" else slice(None)
        tr2.push(name, r.t[keep], r.dx[keep], r.dy[keep])
    out2 = tr2.finish()
    held = ~out2.ok
    assert held.any() and np.all(out2.t[held] > 1.0)
    # While not updated the pose stays put: no invented motion.
    assert np.ptp(out2.x[held]) == 0.0
    assert out2.x[-1] == pytest.approx(0.25, abs=5e-3)


def test_reset_and_fix():
    res = sim.simulate(rig3(), sim.arc(0.5, 1.0))
    tr = Tracker(sim.rig_config(res.rig), t0=0.0)
    for name, r in res.reports.items():
        tr.push(name, r.t, r.dx, r.dy)
    tr.poll()
    tr.complete_until(res.duration)
    tr.poll()
    assert tr.pose_cov[0, 0] > 0
    tr.fix(y=1.0)
    x, y, th = tr.pose
    assert y == 1.0
    cov = tr.pose_cov
    assert cov[1, 1] == 0 and cov[0, 1] == 0 and cov[0, 0] > 0 and cov[2, 2] > 0
    tr.reset(2.0, 3.0, 0.5)
    assert tr.pose == (2.0, 3.0, 0.5) and not tr.pose_cov.any()


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 30), st.integers(0, 2**31 - 1))
def test_batched_covariance_equals_the_recursion(n, seed):
    """P_k = F_k P_{k-1} F_k^T + G_k, with F_k = S(p_k - p_{k-1}), done by cumulative sums."""
    rng = np.random.default_rng(seed)
    positions = np.cumsum(rng.normal(0, 1, (n, 2)), axis=0)
    a = rng.normal(0, 0.1, (n, 3, 3))
    noise = a @ np.swapaxes(a, 1, 2)
    b = rng.normal(0, 0.1, (3, 3))
    start = CovarianceState(cov=b @ b.T, position=rng.normal(0, 1, 2))
    got, state = propagate(start, positions, noise)
    p = start.cov
    prev = start.position
    for k in range(n):
        d = positions[k] - prev
        f = np.array([[1, 0, -d[1]], [0, 1, d[0]], [0, 0, 1.0]])
        p = f @ p @ f.T + noise[k]
        prev = positions[k]
        assert np.allclose(got[k], p, atol=1e-9)
    assert np.allclose(state.cov, p) and np.allclose(state.position, positions[-1])


def test_umbmark_square_accuracy():
    """Issue figure: lsq + exact on the 4 m square, 3 mice, 450 CPI, 125 Hz, quantized."""
    for cw in (True, False):
        res = sim.simulate(rig3(), sim.umbmark_square(cw=cw))
        poses, tr = sim.run_tracker(res)
        truth = res.truth(poses.t[-1])[0]
        assert math.hypot(poses.x[-1] - truth[0], poses.y[-1] - truth[1]) < 0.002
        assert abs(math.degrees(poses.theta[-1] - truth[2])) < 0.05
        assert np.array_equal(tr.counts_out.round(6), tr.counts_in)


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 12), st.integers(0, 2**31 - 1))
def test_small_and_large_batches_of_covariance_agree(n, seed):
    """The daemon's one-window path (plain recursion) equals the batched cumulative sums."""
    import mousedom.fusion.covariance as covariance

    rng = np.random.default_rng(seed)
    positions = np.cumsum(rng.normal(0, 1, (n, 2)), axis=0)
    a = rng.normal(0, 0.1, (n, 3, 3))
    noise = a @ np.swapaxes(a, 1, 2)
    start = CovarianceState(cov=np.eye(3) * 0.01, position=np.zeros(2))
    small, _ = covariance._propagate_stepwise(start, positions, noise)
    saved = covariance._SMALL
    covariance._SMALL = 0
    try:
        big, _ = covariance.propagate(start, positions, noise)
    finally:
        covariance._SMALL = saved
    assert np.allclose(small, big, atol=1e-10)


def test_finish_outputs_every_count_with_microsecond_stamps_far_from_zero():
    """Review finding: a last stamp a rounding error past a window edge was left behind."""
    cfg = sim.rig_config(sim.Rig(rig3().mice, rate_hz=100.0))
    tr = Tracker(cfg)
    tr.push(0, np.array([1000.000021]), np.array([1.0]), np.array([0.0]))
    tr.push(2, np.array([1000.430021, 1000.430021]), np.array([5.0, 7.0]), np.zeros(2))
    tr.finish()
    assert np.allclose(tr.counts_out, tr.counts_in, atol=1e-9)


def test_batch_equals_stream_for_a_stamp_one_ulp_before_an_edge():
    cfg = sim.rig_config(sim.Rig(rig3().mice, rate_hz=100.0))
    t0 = 1000.000021
    t = np.nextafter(t0 + 0.01 * 6, 0)

    def run(stream: bool) -> np.ndarray:
        tr = Tracker(cfg, t0=t0)
        out = []
        for i in range(3):
            tr.push(i, np.array([t]), np.array([1.0]), np.array([0.0]))
        if stream:
            out.append(tr.poll())
        tr.push(0, np.array([t]), np.array([100.0]), np.array([0.0]))
        out.append(tr.finish())
        return PoseBatch.concat(out, 3).counts[:, 0, 0]

    assert np.array_equal(run(False), run(True))


def test_covariance_does_not_depend_on_where_the_frame_starts():
    res = sim.simulate(rig3(), sim.sequence(sim.arc(0.5, 1.0), sim.turn(-1.0), sim.straight(0.3)))

    def run(x: float, y: float) -> PoseBatch:
        tr = Tracker(sim.rig_config(res.rig), t0=0.0)
        tr.reset(x, y, 0.0)
        for name, r in res.reports.items():
            tr.push(name, r.t, r.dx, r.dy)
        return tr.finish()

    a, b = run(0.0, 0.0), run(5e5, 5e6)
    assert np.allclose(a.cov, b.cov, rtol=1e-6, atol=1e-15)
    assert np.linalg.eigvalsh(b.cov).min() >= -1e-15


@pytest.mark.parametrize(
    "t, dx, dy, words",
    [
        ([0.01, 0.02, 0.03], [5.0], [1.0], "one length"),
        ([0.01], [float("nan")], [1.0], "finite"),
        ([float("inf")], [1.0], [1.0], "finite"),
    ],
)
@pytest.mark.parametrize("as_lists", [False, True])
def test_push_refuses_malformed_input_at_once(t, dx, dy, words, as_lists):
    """Arrays, or Python lists (a live source's few reports, queued without numpy)."""
    tr = Tracker(sim.rig_config(rig3()), t0=0.0)
    with pytest.raises(ValueError, match=words):
        if as_lists:
            tr.push(0, t, dx, dy)
        else:
            tr.push(0, np.array(t), np.array(dx), np.array(dy))
    tr.push(0, np.array([0.01]), np.array([1.0]), np.array([0.0]))
    tr.finish()
    assert tr.counts_out[0, 0] == pytest.approx(1.0)


def test_pushing_lists_equals_pushing_arrays():
    """The list fast path of push (ints and floats) feeds the same windows as arrays."""
    res = sim.simulate(rig3(), sim.arc(0.3, 0.4, 0.12), seed=3)  # 1 s of motion

    def run(as_lists):
        tr = Tracker(sim.rig_config(res.rig), t0=0.0)
        out = []
        for lo in np.arange(0.0, 1.2, 0.01):
            for name, r in res.reports.items():
                sel = (r.t > lo) & (r.t <= lo + 0.01)
                t, dx, dy = r.t[sel], r.dx[sel], r.dy[sel]
                if as_lists:
                    t, dx, dy = t.tolist(), dx.astype(int).tolist(), dy.astype(int).tolist()
                tr.push(name, t, dx, dy)
            tr.complete_until(lo + 0.01)
            out.append(tr.poll())
        out.append(tr.finish())
        return PoseBatch.concat(out, 3), tr.counts_in

    (a, a_in), (b, b_in) = run(False), run(True)
    assert len(a) > 90
    assert np.array_equal(a_in, b_in)
    for key in ("t", "x", "y", "theta", "cov", "counts", "residual"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key


@pytest.mark.parametrize("bad", ["1", None, 1j])
def test_push_of_lists_refuses_what_is_not_a_real_number(bad):
    """Lists are queued without numpy's conversion: anything else than real numbers is a
    ValueError at once, not a TypeError later inside a window."""
    tr = Tracker(sim.rig_config(rig3()), t0=0.0)
    with pytest.raises(ValueError, match="finite numbers"):
        tr.push(0, [0.01, 0.02], [1, bad], [0, 0])
    tr.push(0, [0.01], [1], [0])
    tr.finish()
    assert tr.counts_out[0].tolist() == [1.0, 0.0]


def test_one_window_with_a_mouse_far_ahead_takes_the_array_path():
    """Regression: one window closing while a mouse had hundreds of reports queued ahead
    (too many knots for the float path) went to the float solver with arrays and raised
    TypeError (unhashable).  It must give what the array path gives."""

    def run(small):
        cfg = sim.rig_config(rig3())
        tr = Tracker(cfg, t0=0.0)
        tr._SMALL = small
        # 2 s of mouse 0 at once, every 5 ms (none joins the one before): ~800 knots
        t = np.arange(1, 400) * 0.005
        tr.push(0, t, np.ones_like(t), -np.ones_like(t))
        for i in (1, 2):  # the others have just passed the first window's end
            tr.push(i, [0.0101], [1], [0])
        # ... and nothing of theirs can join that report any more (half a period on)
        tr.complete_until(0.0101 + 0.5 / cfg.mice[1].report_hz)
        first = tr.poll()
        return first, tr.finish()

    (a, a_end), (b, b_end) = run(1), run(0)
    assert len(a) == len(b) == 1
    for key in ("t", "x", "y", "theta", "cov", "counts", "residual", "used", "ok"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
        assert np.array_equal(getattr(a_end, key), getattr(b_end, key)), key


def test_a_model_override_the_mice_cannot_support_is_refused():
    """--model on the tracker is checked like the config's own model (issue 17, item 7)."""
    from mousedom.config import parse_config
    from mousedom.fusion.tracker import Tracker

    one = parse_config(
        "model: diff-drive\nmice:\n  m: {cpi: 400, mount: {x: 0.1, y: 0}}\n", need_sources=False
    )
    with pytest.raises(ValueError, match="model lsq: needs at least two mice"):
        Tracker(one, model="lsq")
    Tracker(one, model="diff-drive")  # the config's own model is fine


def test_bonarini_on_the_one_window_path_equals_the_array_path():
    """The daemon closes one window per poll; bonarini (a numerical model) then takes the
    array solver for that window: the poses equal one batch's."""
    from mousedom.fusion import sim
    from mousedom.fusion.tracker import Tracker

    rig = sim.Rig(
        (sim.SimMouse("l", 0.0, 0.1, report_hz=125.0), sim.SimMouse("r", 0.0, -0.1, report_hz=125.0,
                                                                   phase=0.003)),
        model="bonarini",
    )  # fmt: skip
    result = sim.simulate(rig, sim.sequence(sim.straight(0.2), sim.arc(0.3, 1.0)), seed=1)
    batch, _ = sim.run_tracker(result)
    config = sim.rig_config(rig)
    live = Tracker(config, t0=float(result.motion.starts[0]))
    rows = [r for b in sim.run_tracker_live(result, live) for r in b.rows()]
    assert len(rows) == len(batch)
    got = np.array([[r.x, r.y, r.theta] for r in rows])
    want = np.column_stack([batch.x, batch.y, batch.theta])
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_many_live_reads_queued_without_a_poll_keep_every_count():
    """A live read queues Python ints; past 64 queued reports they become knots on the
    array path, which once failed on int arrays (numpy cannot add floats into them in
    place) when one mouse held the windows back for a while (a lifted mouse)."""
    tracker = Tracker(sim.rig_config(sim.three_mouse_rig()), t0=0.0)
    for k in range(100):
        tracker.push("front", [0.001 * k], [1], [2])
    assert tracker.finish().counts.sum(axis=0)[0].tolist() == [100.0, 200.0]


@pytest.mark.parametrize("scale", [1, 2**40])
def test_integer_and_float_counts_close_the_same_windows(scale):
    """Whole counts are summed as int64 (CountFunction.ingest), floats as floats: the same
    windows bit for bit, and counts so large that an int64 sum could wrap or a float one
    round (2**40 per report) take the float sum for both."""
    res = sim.simulate(rig3(), sim.arc(0.3, 0.4, 0.12), seed=5)

    def run(as_float):
        tr = Tracker(sim.rig_config(res.rig), t0=0.0)
        for name, r in res.reports.items():
            dx, dy = (np.asarray(c, dtype=np.int64) * scale for c in (r.dx, r.dy))
            if as_float:
                dx, dy = dx.astype(float), dy.astype(float)
            tr.push(name, r.t, dx, dy)
        return tr.finish(), tr.counts_in

    (a, a_in), (b, b_in) = run(False), run(True)
    assert len(a) > 90
    assert np.array_equal(a_in, b_in)
    for key in ("x", "y", "theta", "counts"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key


def test_world_step_noise_is_m_q_m_transposed():
    """G = M Q M^T with M = blockdiag(R(theta), 1) d(step)/dq, against numpy's matmul."""
    from mousedom.fusion import integrate
    from mousedom.fusion.covariance import world_step_noise

    rng = np.random.default_rng(7)
    n = 500
    q = rng.normal(0, 0.02, (n, 3)) * np.array([1, 1, 20])
    theta = rng.uniform(-7, 7, n)
    a = rng.normal(0, 1e-3, (n, 3, 3))
    q_cov = a @ np.swapaxes(a, 1, 2)
    rot = np.zeros((n, 3, 3))
    rot[:, 0, 0] = rot[:, 1, 1] = np.cos(theta)
    rot[:, 1, 0], rot[:, 0, 1] = np.sin(theta), -np.sin(theta)
    rot[:, 2, 2] = 1.0
    m = rot @ integrate.step_jacobian(q)
    want = m @ q_cov @ np.swapaxes(m, 1, 2)
    got = world_step_noise(theta, integrate.step_partials(q), q_cov)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-22)
    assert np.array_equal(got, np.swapaxes(got, 1, 2))
