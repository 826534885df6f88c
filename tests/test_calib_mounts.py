"""Mount calibration: Kim & Lee section IV (linearised) and the exact per-mouse fit."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from mousedom.calibrate.mounts import (
    MountError,
    exact_mount,
    exact_system,
    kimlee,
    kimlee_system,
    mirrored,
    motion_problem,
)
from mousedom.calibrate.runs import run_windows, split_runs, window_counts
from mousedom.calibrate.synth import SynthMouse, build_motion, mouse_reports, true_window_twist
from mousedom.fusion import sim
from mousedom.fusion.units import INCH


def kim_lee_example():
    """Kim & Lee eq. (1) with r = 0.3 m, theta = -pi/6: nominal (51) and true (52)."""
    r, th = 0.3, -math.pi / 6
    ang = th + np.arange(3) * 2 * math.pi / 3
    nominal = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    return nominal, 1.05 * nominal


def test_kimlee_reproduces_their_example_53():
    """Kim & Lee section V: eqs. (51)-(52), self-rotation at 1/3 rad/s, M = 10, result (53).

    Noise-free, the stacked system (44)-(46) of a pure rotation has rank 3 < 2N = 6; its
    minimum-norm least-squares solution is their (53).
    """
    nominal, true = kim_lee_example()
    np.testing.assert_allclose(nominal.ravel() / 0.3, [0.866, -0.5, 0, 1, -0.866, -0.5], atol=6e-4)
    w = 1 / 3
    v_m = np.tile([0.0, 0.0, w], (10, 1))
    v_s = np.tile(np.column_stack([-w * true[:, 1], w * true[:, 0]]), (10, 1, 1))
    res = kimlee(v_s, v_m, nominal)
    expected = 0.3 * np.array([0.912, -0.526, 0.000, 1.053, -0.912, -0.526])
    np.testing.assert_allclose(res.positions.ravel(), expected, atol=0.3 * 0.0006)
    assert res.rank == 3 and res.unknowns == 6
    s, b = kimlee_system(v_s, v_m, nominal)
    assert s.shape == (10 + 2, 6) and b.shape == (12,)  # (45)-(46): M + 2 rows


def test_kimlee_system_rows_follow_eqs_38_to_43():
    """Kim & Lee (35)-(43): S_k dp equals dA^T v_s - dP v_m exactly (both linear in dp)."""
    rng = np.random.default_rng(3)
    nominal = rng.normal(size=(3, 2)) * 0.2
    v_m = rng.normal(size=(1, 3))
    v_s = rng.normal(size=(1, 3, 2))
    dp = rng.normal(size=6) * 0.01
    s_full, b = kimlee_system(v_s, v_m, nominal)
    from mousedom.fusion.geometry import design_matrix

    a_bar = design_matrix(nominal)
    d_a = design_matrix(nominal + dp.reshape(3, 2)) - a_bar  # (34)
    d_p = d_a.T @ a_bar + a_bar.T @ d_a  # (25)
    lhs = d_a.T @ v_s[0].ravel() - d_p @ v_m[0]  # left side of (31)
    np.testing.assert_allclose(s_full @ dp, lhs, atol=1e-12)
    np.testing.assert_allclose(b, a_bar.T @ (a_bar @ v_m[0] - v_s[0].ravel()), atol=1e-12)


def _windows_for(mice, motion, window=0.25, cpi_conf=1000.0):
    """Per-mouse mouse-frame readings (configured CPI) and the exact twist per window."""
    recording = {m.name: mouse_reports(m, motion, seed=i) for i, m in enumerate(mice)}
    runs = split_runs(recording)
    edges = run_windows(runs, window, 1 / 125)
    w = np.concatenate([true_window_twist(motion, e) for e in edges])
    readings = {}
    for m in mice:
        rep = recording[m.name]
        parts = []
        for e in edges:
            dx = window_counts(rep.t, rep.dx, e, 1 / m.report_hz)
            dy = window_counts(rep.t, rep.dy, e, 1 / m.report_hz)
            parts.append(np.column_stack([-dy, -dx]) * INCH / cpi_conf)
        readings[m.name] = np.concatenate(parts)
    return readings, w


RICH_MOTION = [(0.3, 0, 0, 2), (0, 0, 1.5, 2), (0.2, 0, 0.8, 2), (0, 0.1, -1, 2), (-0.2, 0, 0, 2)]


def test_exact_recovers_position_yaw_scale_noise_free():
    """Quantised but noise-free counts: positions to 0.1 mm (issue 7), yaw and scale too."""
    mice = [
        SynthMouse("a", 0.12, 0.05, yaw=math.degrees(0.2), cpi_x=1030, cpi_y=1030),
        SynthMouse("b", -0.1, -0.12, yaw=math.degrees(-0.1), cpi_x=990, cpi_y=990, report_hz=500),
        SynthMouse("c", 0.0, 0.2, yaw=180.0, cpi_x=1000, cpi_y=1000, phase=0.4),
    ]
    readings, w = _windows_for(mice, build_motion(RICH_MOTION))
    assert motion_problem(w) is None
    for m in mice:
        fit = exact_mount(readings[m.name], w)
        assert abs(fit.x - m.x) < 1e-4 and abs(fit.y - m.y) < 1e-4
        assert abs(math.remainder(fit.yaw - math.radians(m.yaw), 2 * math.pi)) < 1e-3
        assert fit.scale == pytest.approx(m.cpi_y / 1000.0, rel=2e-4)
        yaw_deg = fit.as_json()["yaw"]
        assert abs(math.remainder(yaw_deg - m.yaw, 360)) < 0.06


def test_exact_is_exact_on_float_counts():
    """Without quantisation the fit is exact to rounding: no linearisation anywhere."""
    rng = np.random.default_rng(5)
    w = rng.normal(size=(12, 3)) * [0.1, 0.05, 0.5]
    p, yaw, scale = np.array([0.07, -0.03]), -0.7, 1.12
    d = np.column_stack([w[:, 0] - w[:, 2] * p[1], w[:, 1] + w[:, 2] * p[0]])
    c, s = math.cos(-yaw), math.sin(-yaw)
    m = np.column_stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]]) * scale
    fit = exact_mount(m, w)
    assert (fit.x, fit.y, fit.yaw, fit.scale) == pytest.approx((0.07, -0.03, -0.7, 1.12), abs=1e-12)
    a, rhs = exact_system(m, w)
    assert a.shape == (24, 4) and rhs.shape == (24,)


def test_pure_rotation_is_flagged_not_solved():
    """Kim & Lee's own self-rotation cannot tell scale from position: say so, add motion."""
    nominal, true = kim_lee_example()
    w = np.tile([0.0, 0.0, 1 / 3], (10, 1))
    problem = motion_problem(w)
    assert "rotation about one point" in problem and "straight" in problem
    # Rotation about an off-centre point is just as degenerate, and the point is named.
    c = np.array([0.2, -0.1])
    w_off = np.column_stack([w[:, 2] * c[1], -w[:, 2] * c[0], w[:, 2]])
    assert "x=0.200, y=-0.100" in motion_problem(w_off)
    m = np.column_stack([-w[:, 2] * true[0, 1], w[:, 2] * true[0, 0]])
    with pytest.raises(MountError):
        exact_mount(m, w)


def test_translation_only_is_flagged():
    w = np.array([[0.2, 0, 0], [0, 0.1, 0], [-0.2, 0.05, 0]])
    assert "no rotation" in motion_problem(w)
    assert "no motion" in motion_problem(np.zeros((3, 3)))


def test_exact_beats_kimlee_with_noise_on_the_core_simulator():
    """mousedom.fusion.sim rig with noise, mounts 5 % off nominal: exact within 1 mm, and better
    than the linearised method (which also cannot see a yaw or CPI error)."""
    true_pos = {"front": (0.16, 0.01), "left": (-0.07, 0.14), "right": (-0.08, -0.13)}
    mice = tuple(
        sim.SimMouse(n, x, y, yaw=0.0, cpi_x=1000, cpi_y=1000, noise=0.3, phase=0.001 * i)
        for i, (n, (x, y)) in enumerate(true_pos.items())
    )
    rig = sim.Rig(mice)
    traj = sim.sequence(
        sim.pause(0.5),
        sim.straight(0.4),
        sim.pause(0.8),
        sim.turn(1.5),
        sim.pause(0.8),
        sim.arc(0.3, 1.0),
        sim.pause(0.8),
        sim.turn(-1.0),
        sim.pause(0.8),
        sim.straight(-0.3),
        sim.pause(0.5),
    )
    res = sim.simulate(rig, traj, seed=2)
    from mousedom.sources.base import Reports

    recording = {n: Reports(n, r.t, r.dx, r.dy) for n, r in res.reports.items()}
    runs = split_runs(recording)
    assert len(runs) == 5
    edges = run_windows(runs, 0.25, 1 / 125)
    # Exact reference twist per window from the simulator's constant-twist segments.
    seg_t = res.motion.starts
    twist = np.array([[s.vx, s.vy, s.omega] for s in res.motion.segments])
    cum = np.vstack([np.zeros(3), np.cumsum(twist * np.diff(seg_t)[:, None], axis=0)])

    def integral(t):
        k = np.clip(np.searchsorted(seg_t, t, side="right") - 1, 0, len(twist) - 1)
        return cum[k] + twist[k] * (np.clip(t, seg_t[0], seg_t[-1]) - seg_t[k])[:, None]

    w = np.concatenate([np.diff(integral(e), axis=0) for e in edges])
    nominal = np.array([[0.15, 0.0], [-0.075, 0.13], [-0.075, -0.13]])
    v_s = np.zeros((len(w), 3, 2))
    errs_exact, errs_kl = [], []
    for j, m in enumerate(mice):
        rep = recording[m.name]
        dx = np.concatenate([window_counts(rep.t, rep.dx, e, 1 / 125) for e in edges])
        dy = np.concatenate([window_counts(rep.t, rep.dy, e, 1 / 125) for e in edges])
        reading = np.column_stack([-dy, -dx]) * INCH / 1000
        v_s[:, j] = reading  # yaw 0: mouse frame = body frame
        fit = exact_mount(reading, w)
        errs_exact.append(math.hypot(fit.x - m.x, fit.y - m.y))
        assert fit.scale == pytest.approx(1.0, abs=2e-3)
    kl = kimlee(v_s, w, nominal)
    truth = np.array(list(true_pos.values()))
    errs_kl = np.hypot(*(kl.positions - truth).T)
    assert max(errs_exact) < 1e-3
    assert max(errs_exact) < max(errs_kl)


def test_kimlee_rank_is_at_most_three_whatever_the_motion():
    """Kim & Lee (38)-(40), (45): the third row of every S_k is w_k (p_true - 2 p_nominal)
    (the translation terms of C1 and C2 cancel), so S has rank <= 3 for any motion; with
    a common scale error (their example) the minimum-norm answer is still right."""
    motion = build_motion(RICH_MOTION)
    edges = np.linspace(0.3, motion.end, 60)
    w = true_window_twist(motion, edges)
    nominal, _ = kim_lee_example()
    for true, exact_expected in (
        (nominal * 1.05, True),
        (nominal + [[0.01, 0], [0, 0.01], [-0.005, 0.003]], False),
    ):
        v_s = np.stack(
            [np.column_stack([w[:, 0] - w[:, 2] * p[1], w[:, 1] + w[:, 2] * p[0]]) for p in true],
            axis=1,
        )
        s, _ = kimlee_system(v_s, w, nominal)
        res = kimlee(v_s, w, nominal)
        assert np.linalg.matrix_rank(s) <= 3 and res.rank <= 3
        err = np.max(np.hypot(*(res.positions - true).T))
        assert (err < 0.0015) == exact_expected


@pytest.mark.parametrize("window, tolerance", [(0.25, 5e-4), (0.0, 1e-4)])
def test_exact_with_a_reference_clock_20_ms_late(window, tolerance):
    """Runs start and end at rest, and their windows reach into the pauses: a reference
    lagging the mice by 20 ms costs little with windows and nothing with whole runs."""
    from mousedom.calibrate import session as sess
    from mousedom.calibrate.reference import parse_reference
    from mousedom.calibrate.synth import twist_csv
    from mousedom.config import parse_config

    motion = build_motion(RICH_MOTION)
    mice = [
        SynthMouse("a", 0.12, 0.05, yaw=math.degrees(0.03), cpi_x=1010, cpi_y=1010),
        SynthMouse("b", -0.1, -0.02, phase=0.5),
    ]
    rec = {m.name: mouse_reports(m, motion, i) for i, m in enumerate(mice)}
    cfg = parse_config(
        "mice:\n  a: {cpi: 1000, mount: {x: 0.1}}\n  b: {cpi: 1000, mount: {x: -0.1}}\n",
        "rig.yaml",
        need_sources=False,
    )
    ref = parse_reference(twist_csv(motion, 200.0, t_offset=0.02), "REF.csv")
    s = sess.make_session(cfg, rec, split_runs(rec))
    res = sess.mounts(s, ref, "exact", window=window)
    for m in mice:
        fit = res.fits[m.name]
        assert math.hypot(fit.x - m.x, fit.y - m.y) < tolerance


# --------------------------------------------------------- a capture cut in a motion


def _cut_session(
    seed: int,
    keep: tuple[float, float],
    ref_noise: float = 0.0,
    lag: float = 0.0,
    pause: float = 1.0,
):
    """A drive of two fixed moves (a push and a turn, so that the motion can give mounts)
    and three random ones, its mice's reports kept only over ``keep`` (a capture cut short),
    and its reference with additive noise (m/s, and rad/s over 0.1 m) ``lag`` s late."""
    from mousedom.calibrate import session as sess
    from mousedom.calibrate.reference import parse_reference
    from mousedom.calibrate.synth import twist_csv
    from mousedom.config import parse_config
    from mousedom.sources.base import Reports

    rng = np.random.default_rng(seed)
    moves = [(0.3, 0, 0, 2), (0, 0, 1.5, 2)]
    moves += [
        (*rng.uniform(-0.3, 0.3, 2), rng.uniform(-1.5, 1.5), rng.uniform(1, 3)) for _ in range(3)
    ]
    motion = build_motion(moves, pause=pause)
    mice = [
        SynthMouse(n, x, y, phase=rng.uniform())
        for n, x, y in (("a", 0.15, 0.0), ("b", -0.075, 0.13), ("c", -0.075, -0.13))
    ]
    rec = {}
    for i, m in enumerate(mice):
        rep = mouse_reports(m, motion, seed + i)
        inside = (rep.t >= keep[0]) & (rep.t <= keep[1])
        rec[m.name] = Reports(m.name, rep.t[inside], rep.dx[inside], rep.dy[inside])
    cfg = parse_config(
        "mice:\n"
        + "".join(f"  {m.name}: {{cpi: 1000, mount: {{x: {m.x}, y: {m.y}}}}}\n" for m in mice),
        "rig.yaml",
        need_sources=False,
    )
    ref = parse_reference(twist_csv(motion, 100.0, t_offset=lag), "REF.csv")
    noise = ref_noise * rng.standard_normal(ref.values.shape) * np.array([1.0, 1.0, 10.0])
    ref = type(ref)(ref.kind, ref.t, ref.values + noise, ref.path)
    return sess, sess.make_session(cfg, rec, split_runs(rec)), ref, motion, mice


def _move_spans(motion) -> list[tuple[float, float]]:
    """(start, end) of each move of a ``build_motion`` drive (its knots come in fours)."""
    return [
        (float(motion.t[1 + 4 * k]), float(motion.t[4 + 4 * k]))
        for k in range((len(motion.t) - 2) // 4)
    ]


@pytest.mark.parametrize("seed", range(8))
def test_mounts_refuse_a_capture_that_ends_or_begins_in_a_motion(seed):
    """Regression: a capture that ended mid-motion was fitted to the reference's whole motion
    with exit 0 (mounts 6-30 mm off, scales up to 2.23).  The mice are still where the
    reference moves: refused, naming the reference and the end or beginning cut."""
    from mousedom.errors import UserError

    rng = np.random.default_rng(1000 + seed)
    _, _, _, motion, _ = _cut_session(seed, (0, np.inf))
    spans = _move_spans(motion)
    k = int(rng.integers(2, len(spans)))
    start, end = spans[k]
    cut = rng.uniform(start + 0.3, end - 0.2)  # in the move's hold: much motion is left
    sess, s, ref, _, _ = _cut_session(seed, (0, cut))
    with pytest.raises(UserError, match=r"REF\.csv: .*captures end in the middle of a motion"):
        sess.mounts(s, ref, "exact")
    begin = rng.uniform(spans[0][0] + 0.3, spans[0][1] - 0.2)
    sess, s, ref, _, _ = _cut_session(seed, (begin, np.inf))
    with pytest.raises(UserError, match=r"captures begin in the middle of a motion"):
        sess.mounts(s, ref, "exact")
    # Cut in a pause instead: every run is whole, and the fit exact.
    pause = rng.uniform(spans[k - 1][1] + 0.1, start - 0.1)
    sess, s, ref, _, mice = _cut_session(seed, (0, pause))
    res = sess.mounts(s, ref, "exact")
    for m in mice:
        assert math.hypot(res.fits[m.name].x - m.x, res.fits[m.name].y - m.y) < 2e-4


@pytest.mark.parametrize("seed", range(6))
def test_mounts_take_a_noisy_reference_a_little_late(seed):
    """The pause check must not refuse a whole capture whose reference has additive noise
    (5 mm/s, 0.05 rad/s a sample at 100 Hz) and a clock up to 20 ms off the mice's."""
    lag = np.random.default_rng(seed).uniform(-0.02, 0.02)
    sess, s, ref, _, mice = _cut_session(seed, (0, np.inf), ref_noise=0.005, lag=lag)
    res = sess.mounts(s, ref, "exact", window=0.0)
    for m in mice:
        assert math.hypot(res.fits[m.name].x - m.x, res.fits[m.name].y - m.y) < 5e-3


@pytest.mark.parametrize("seed", range(3))
def test_mounts_take_a_noisy_reference_over_long_pauses(seed):
    """Regression (review): the whole of each pause was checked, and a noisy reference
    wanders over 10 s of it (its excursion grows as the square root of the time): 2 of
    3 such sessions were refused.  Only the reference within --gap of each run counts."""
    lag = np.random.default_rng(seed).uniform(-0.04, 0.04)
    sess, s, ref, _, mice = _cut_session(seed, (0, np.inf), ref_noise=0.005, lag=lag, pause=10.0)
    res = sess.mounts(s, ref, "exact", window=0.0)
    for m in mice:
        assert math.hypot(res.fits[m.name].x - m.x, res.fits[m.name].y - m.y) < 5e-3


def test_a_mouse_whose_motion_ends_first_is_cut_only_if_the_others_moved_on():
    """``check_whole_captures`` judges by the others' share of the run after a mouse's
    last motion: a rig creeping as it stops (a count now and then on a mouse of high CPI,
    which keeps the run open) is not a cut; half of the run missing is."""
    from mousedom.calibrate.runs import check_whole_captures
    from mousedom.errors import UserError
    from mousedom.sources.base import Reports

    t = np.arange(0.0, 2.0, 0.008)
    ones = np.ones(len(t))
    creep = np.arange(2.2, 3.6, 0.3)
    a = Reports("a", t, 0 * ones, 5 * ones)
    b = Reports("b", np.concatenate([t, creep]), np.zeros(len(t) + len(creep)),
                np.concatenate([60 * ones, np.ones(len(creep))]))  # fmt: skip
    rec = {"a": a, "b": b}
    runs = split_runs(rec)
    assert len(runs) == 1 and runs[0].t1 > 3.0
    check_whole_captures(rec, runs, 0.5)  # creep: not a cut
    cut = t < 1.0
    rec["a"] = Reports("a", t[cut], 0 * ones[cut], 5 * ones[cut])
    with pytest.raises(UserError, match=r"mouse a: its motion ends at t = 0\.99\d s, inside run 1"):
        check_whole_captures(rec, split_runs(rec), 0.5)


SIDEWAYS = [(0.3, 0, 0, 1.5), (0, 0, 1.5, 2), (0.3, 0, 1.0, 2), (0, 0.2, -1, 2), (0.1, 0.1, 0.5, 1)]
NO_SIDEWAYS = [(0.3, 0, 0, 1.5), (0, 0, 1.5, 2), (0.3, 0, 1.0, 2), (-0.3, 0, 0, 1.5)]


@pytest.mark.parametrize("seed", range(8))
def test_a_mouse_read_through_a_mirror_is_refused_not_fitted(seed):
    """A mouse whose ``flip`` is configured wrong reads the motion through a reflection,
    which k R(yaw) cannot represent: the fit once returned it 0.1 m and its CPI 60 % off
    (exit 0, written by --write).  Random rigs, per-axis CPIs, noise: the readings as
    configured fit; the same readings mirrored are refused wherever the motion slides
    sideways (without sideways motion a mirror cannot be seen: ``mirrored`` says so)."""
    rng = np.random.default_rng(seed)
    mice = [
        SynthMouse(
            name,
            float(rng.uniform(-0.2, 0.2)),
            float(rng.uniform(-0.2, 0.2)),
            yaw=float(rng.uniform(-180, 180)),
            cpi_x=float(rng.uniform(400, 3200)),
            cpi_y=0.0,
            flip=bool(rng.random() < 0.5),
            rel_noise=0.01,
            abs_noise=0.3,
            report_hz=float(rng.choice([125, 500, 1000])),
        )
        for name in "abc"
    ]
    mice = [replace(m, cpi_y=m.cpi_x * float(rng.uniform(0.96, 1.04))) for m in mice]
    for moves, seen in ((SIDEWAYS, True), (NO_SIDEWAYS, False)):
        readings, w = _windows_for(mice, build_motion(moves), cpi_conf=1000.0)
        for m in mice:
            # _windows_for reads every mouse as unflipped: undo the flip for "as configured".
            as_configured = readings[m.name] * ([1.0, -1.0] if m.flip else [1.0, 1.0])
            mirror = as_configured * [1.0, -1.0]
            assert not mirrored(as_configured, w)
            assert mirrored(mirror, w) == seen
            if seen:
                with pytest.raises(MountError, match="mirror image.*`flip`"):
                    exact_mount(mirror, w)
            fit = exact_mount(as_configured, w)
            if seen:
                assert math.hypot(fit.x - m.x, fit.y - m.y) < 2e-3


def _skip_polls(rep, period: float, origin: float, gaps) -> object:
    """``rep`` as a host that does not poll in ``gaps`` ([from, to) spans) delivers it: the
    reports stamped in a gap arrive summed at the first poll after it (the report grid of
    ``period`` from ``origin``), as ``sim.simulate``'s usb_gaps do."""
    from mousedom.sources.base import Reports

    t = np.asarray(rep.t, dtype=float).copy()
    for a, b in gaps:
        inside = (t >= a) & (t < b)
        t[inside] = origin + period * np.ceil((b - origin) / period - 1e-9)
    slots, where = np.unique(np.round(t, 9), return_inverse=True)
    dx, dy = np.zeros(len(slots)), np.zeros(len(slots))
    np.add.at(dx, where, rep.dx)
    np.add.at(dy, where, rep.dy)
    keep = (dx != 0) | (dy != 0)
    return Reports(rep.mouse, slots[keep], dx[keep], dy[keep])


@pytest.mark.parametrize("seed", range(12))
def test_mounts_count_a_usb_catch_up_report_where_it_was_measured(seed):
    """A busy USB host skips polls (30 ms, 3-5 times a second: a healthy rig's condition,
    fusion/conditions.py) and then gets the counts of all of them in one report.  The
    windows spread a report over one report period at most, so a catch-up's 30 ms of
    counts landed in the last 8 ms, across window edges: noise-free mounts came out
    0.33 mm (median) and up to 3.2 mm off, and CPI scales up to 0.7 % (which --write
    stores), where without the gaps they are within 0.05 mm and 0.01 %.  As in the
    fusion, a report within late_report_s of its mouse's previous one covers the time
    since.  Random rigs of 2-5 mice, any yaw, flipped or not, 125-1000 Hz."""
    from mousedom.calibrate import session as sess
    from mousedom.calibrate.reference import parse_reference
    from mousedom.calibrate.synth import twist_csv
    from mousedom.config import parse_config

    rng = np.random.default_rng(seed)
    moves = [*RICH_MOTION, (0, 0.3, 0, 2), (0.1, -0.3, 1.0, 2)]
    motion = build_motion([moves[k] for k in rng.permutation(len(moves))])
    mice, rec, lines = [], {}, ["mice:"]
    for i in range(int(rng.integers(2, 6))):
        r, a = rng.uniform(0.03, 0.3), rng.uniform(0, 2 * math.pi)
        hz = float(rng.choice([125, 250, 500, 1000]))
        m = SynthMouse(f"m{i}", r * math.cos(a), r * math.sin(a), yaw=float(rng.uniform(-180, 180)),
                       cpi_x=1000.0 * (1 + rng.uniform(-0.03, 0.03)), report_hz=hz,
                       flip=bool(rng.random() < 0.3), phase=float(rng.uniform()))  # fmt: skip
        m = replace(m, cpi_y=m.cpi_x)
        gaps = sim.usb_gap_spans(rng, motion.end, float(rng.uniform(3, 5)), 0.03, 0.3)
        rec[m.name] = _skip_polls(mouse_reports(m, motion, i), 1 / hz, m.phase / hz, gaps)
        lines.append(f"  {m.name}: {{cpi: 1000, report_hz: {hz}, flip: {str(m.flip).lower()},"
                     f" mount: {{x: 0, y: 0, yaw: {m.yaw + rng.uniform(-2, 2)}}}}}")  # fmt: skip
        mice.append(m)
    cfg = parse_config("\n".join(lines) + "\n", "rig.yaml", need_sources=False, need_model=False)
    ref = parse_reference(twist_csv(motion, 100.0), "REF.csv")
    res = sess.mounts(sess.make_session(cfg, rec, split_runs(rec)), ref, "exact")
    for m in mice:
        fit = res.fits[m.name]
        assert math.hypot(fit.x - m.x, fit.y - m.y) < 1e-4, m
        assert fit.scale == pytest.approx(m.cpi_x / 1000.0, rel=2e-4), m
        assert math.degrees(math.remainder(fit.yaw - math.radians(m.yaw), 2 * math.pi)) == (
            pytest.approx(0.0, abs=0.02)
        ), m
