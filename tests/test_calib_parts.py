"""Runs, windows, counts conversion, REF.csv and the calibration file."""

from __future__ import annotations

import math
import os
import stat

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.calibrate import calfile
from mousedom.calibrate.counts import body_frame, mouse_frame
from mousedom.calibrate.reference import (
    WheelGeometry,
    check_coverage,
    parse_reference,
    wheel_twist,
    window_twist,
)
from mousedom.calibrate.runs import cumulative, run_counts, split_runs, window_counts
from mousedom.calibrate.synth import build_motion, twist_csv
from mousedom.config import load_config, parse_config
from mousedom.errors import UserError
from mousedom.fusion.units import INCH
from mousedom.sources.base import Reports

RIG = """\
mice:
  left: {cpi: 400, mount: {x: 0.0, y: 0.1, yaw: 90}}
  right: {cpi: {x: 400, y: 420}, mount: {x: 0.0, y: -0.1}, flip: true}
"""


def test_split_runs_at_idle_gaps_over_all_mice():
    a = Reports("a", [0.0, 0.1, 0.2, 2.0, 2.1], [1, 1, 1, 1, 1], [0, 0, 0, 0, 0])
    b = Reports("b", [0.3, 0.75, 1.0, 5.0], [0, 1, 0, 1], [1, 0, 0, 1])  # 1.0: not motion
    runs = split_runs({"a": a, "b": b}, gap=0.5)
    assert [(r.t0, r.t1) for r in runs] == [(0.0, 0.75), (2.0, 2.1), (5.0, 5.0)]
    assert len(split_runs({"a": a, "b": b}, gap=2.0)) == 2
    counts = run_counts({"a": a, "b": b}, runs, ["b", "a"])
    np.testing.assert_array_equal(counts[0], [[1, 1], [3, 0]])
    np.testing.assert_array_equal(counts[2], [[1, 1], [0, 0]])
    assert split_runs({"a": Reports("a", [], [], [])}) == []


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0.0005, 0.05), st.integers(-20, 20)), min_size=1, max_size=40),
    st.lists(st.floats(-0.1, 2.5), min_size=1, max_size=10),
)
def test_window_counts_conserve_every_count(steps, cuts):
    """However the windows are cut, they hold every count exactly once."""
    t = np.cumsum([s[0] for s in steps])
    v = np.array([s[1] for s in steps], dtype=float)
    edges = np.sort(np.concatenate([[-1.0], cuts, [t[-1] + 1]]))
    w = window_counts(t, v, edges, period=0.008)
    assert w.sum() == pytest.approx(v.sum(), abs=1e-9)
    x, y = cumulative(t, v, 0.008)
    assert np.all(np.diff(x) >= 0)


def test_window_counts_split_a_report_in_proportion_to_time():
    """A report at t = 1.0 covers (0.992, 1.0]; a cut at 0.996 halves it."""
    w = window_counts(np.array([1.0]), np.array([10.0]), np.array([0.0, 0.996, 2.0]), 0.008)
    np.testing.assert_allclose(w, [5.0, 5.0])
    # A report never reaches back past the previous one; one stamped under half a period
    # after it (held up on its way) joins its span, as in the fusion (countfunction).
    w = window_counts(
        np.array([1.0, 1.0, 1.002]),
        np.array([2.0, 2.0, 4.0]),
        np.array([0.0, 1.0, 1.001, 5.0]),
        0.008,
    )
    np.testing.assert_allclose(w, [2.0, 3.0, 3.0])


def test_a_catch_up_report_covers_the_polls_the_host_skipped():
    """A 125 Hz mouse moving at a steady 10 counts a report whose host skips polls for
    30 ms gets one report of 40 counts: within the bridge (late_report_s) it covers the
    32 ms since the previous report, as in the fusion, and windows cut inside the gap
    get the steady rate (one period back, as before, put all 40 in the last 8 ms)."""
    period = 0.008
    t = np.concatenate([np.arange(1, 11) * period, [0.112], 0.112 + np.arange(1, 11) * period])
    v = np.where(np.isclose(t, 0.112), 40.0, 10.0)
    edges = np.array([0.0, 0.08, 0.096, 0.112, 0.3])
    np.testing.assert_allclose(window_counts(t, v, edges, period, bridge=0.15), [100, 20, 20, 100])
    np.testing.assert_allclose(window_counts(t, v, edges, period), [100, 0, 40, 100])
    # A report after a rest longer than the bridge covers one period, as before.
    w = window_counts(np.array([0.0, 1.0]), np.array([5.0, 8.0]), np.array([-1, 0.5, 0.996, 2]),
                      period, bridge=0.15)  # fmt: skip
    np.testing.assert_allclose(w, [5.0, 4.0, 4.0])


def test_counts_follow_the_evdev_convention():
    """DESIGN.md: REL_Y + = backwards, REL_X + = right; flip mirrors REL_X; yaw turns."""
    cfg = parse_config(RIG, "rig.yaml", need_sources=False)
    left, right = cfg.mouse("left"), cfg.mouse("right")
    np.testing.assert_allclose(mouse_frame(left, 0, -400), [INCH, 0], atol=1e-15)
    np.testing.assert_allclose(mouse_frame(left, -400, 0), [0, INCH], atol=1e-15)
    np.testing.assert_allclose(body_frame(left, 0, -400), [0, INCH], atol=1e-15)  # yaw 90
    np.testing.assert_allclose(mouse_frame(right, 400, -420), [INCH, INCH], atol=1e-15)
    np.testing.assert_allclose(body_frame(left, 0, -800, cpi=(400, 800)), [0, INCH], atol=1e-15)


def test_reference_twist_integrates_exactly():
    motion = build_motion([(0.3, 0.0, 0.5, 2.0), (0.0, 0.1, -1.0, 1.5)])
    ref = parse_reference(twist_csv(motion, sample_hz=50), "REF.csv")
    assert ref.kind == "twist"
    edges = np.array([0.0, 0.7, 1.3, 3.0, 5.9])
    np.testing.assert_allclose(
        window_twist(ref, edges), np.diff(motion.integral(edges), axis=0), atol=1e-9
    )


def test_reference_wheels_follow_mcgill():
    """McGill notes: dC = (drho r_R + dlambda r_L) / 2, dtheta = (drho r_R - dlambda r_L) / w."""
    geo = WheelGeometry(0.03, 0.031, 0.25, 360.0)
    q = wheel_twist(np.array([1.0]), np.array([2.0]), geo)
    np.testing.assert_allclose(q, [[(2 * 0.031 + 0.03) / 2, 0.0, (2 * 0.031 - 0.03) / 0.25]])
    ref = parse_reference("t,left,right\n0,0,0\n1,360,720\n2,360,720\n", "REF.csv")
    w = window_twist(ref, np.array([0.0, 0.5, 2.0]), geo)
    two_pi = 2 * math.pi
    np.testing.assert_allclose(
        w.sum(axis=0), wheel_twist(np.array([two_pi]), np.array([2 * two_pi]), geo)[0]
    )
    with pytest.raises(UserError, match="wheel geometry"):
        window_twist(ref, np.array([0.0, 1.0]))


@pytest.mark.parametrize(
    "text, message",
    [
        ("t,vx,omega\n0,0,0\n", "REF.csv:1: header must be t,vx,vy,omega"),
        ("# made by hand\nt,left\n0,0\n", "REF.csv:2: header must be"),
        ("t,vx,vy,omega\n0,0,0,0\n1,0,x,0\n", "REF.csv:3: vy: not a number: 'x'"),
        ("t,vx,vy,omega\n0,0,0,0\n1,0,0\n", "REF.csv:3: 3 fields, the header has 4"),
        ("t,vx,vy,omega\n0,0,0,0\n0,0,0,0\n", "REF.csv:3: t: time 0.0 does not increase"),
        ("t,vx,vy,omega\n0,0,0,nan\n1,0,0,0\n", "REF.csv:2: omega: not a finite number"),
        ("t,vx,vy,omega\n0,0,0,0\n", "REF.csv: 1 sample(s), need at least 2"),
        ("", "REF.csv: empty reference file"),
    ],
)
def test_reference_errors_name_file_line_column(text, message):
    with pytest.raises(UserError) as e:
        parse_reference(text, "REF.csv")
    assert message in str(e.value)


def test_reference_columns_in_any_order_and_coverage():
    ref = parse_reference("omega,t,vy,vx\n0.5,0,0,1\n0.5,2,0,1\n", "R")
    np.testing.assert_allclose(window_twist(ref, np.array([0, 2.0])), [[2.0, 0.0, 1.0]])
    check_coverage(ref, 0.0, 2.0, 0.01)
    with pytest.raises(UserError, match="share one time base"):
        check_coverage(ref, 5.0, 6.0, 0.01)


def test_calibration_file_merges_and_the_config_applies_it(tmp_path):
    cal = tmp_path / "rig.calib.yaml"
    (tmp_path / "rig.yaml").write_text(RIG + "calibration: rig.calib.yaml\n")
    assert calfile.read_calibration(str(cal)) == {}
    data = calfile.merge_mouse({}, "left", cpi={"y": 455.2})
    data = calfile.merge_mouse(data, "left", cpi={"x": 451.0})
    data = calfile.merge_mouse(data, "right", mount={"x": 0.01, "y": -0.11, "yaw": 1.5}, scale=1.01)
    data = calfile.merge_section(data, "distance", {"distance": 0.2})
    calfile.write_calibration(str(cal), data)
    assert calfile.read_calibration(str(cal)) == data
    assert cal.read_text().startswith("#")
    cfg = load_config(tmp_path / "rig.yaml", need_sources=False)
    assert (cfg.mouse("left").cpi_x, cfg.mouse("left").cpi_y) == (451.0, 455.2)
    r = cfg.mouse("right")
    assert (r.mount.x, r.mount.y, math.degrees(r.mount.yaw)) == pytest.approx((0.01, -0.11, 1.5))
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp left


def test_the_written_header_says_what_a_write_keeps_of_hand_edits(tmp_path):
    """A value edited by hand survives a merge; a comment does not, and the header that
    every write puts first says so (it said "edits are kept": a user's notes vanished)."""
    cal = tmp_path / "rig.calib.yaml"
    cal.write_text(
        "# measured on the lab floor\nmice:\n  left: {cpi: 450, scale: 1.02}  # by hand\n"
    )
    data = calfile.merge_mouse(calfile.read_calibration(str(cal)), "left", cpi={"x": 451.0})
    calfile.write_calibration(str(cal), data)
    text = cal.read_text()
    assert calfile.read_calibration(str(cal))["mice"]["left"]["scale"] == 1.02
    assert "lab floor" not in text and "by hand" not in text
    assert text.startswith(calfile.HEADER) and "comments are not" in calfile.HEADER


def test_calibration_file_errors(tmp_path):
    bad = tmp_path / "c.yaml"
    bad.write_text("mice: [1, 2\n")
    with pytest.raises(UserError, match="c.yaml:2: invalid YAML"):
        calfile.read_calibration(str(bad))
    bad.write_text("- 1\n")
    with pytest.raises(UserError, match="must be a mapping"):
        calfile.read_calibration(str(bad))
    assert yaml.safe_load(calfile.HEADER) is None


@settings(max_examples=150, deadline=None)
@given(st.text(alphabet="tvxyomegaleftrighdirectionc,.-0123456789e\n #", max_size=200))
def test_csv_parsers_take_any_text_without_a_traceback(text):
    """Malformed REF.csv and RUNS.csv: a UserError naming the file, or a result; nothing else."""
    from mousedom.calibrate.umbmark import parse_runs

    for parse in (parse_reference, parse_runs):
        try:
            parse(text, "F.csv")
        except UserError as e:
            assert str(e).startswith("F.csv")


def test_calibration_file_is_readable_by_the_daemon(tmp_path):
    """Regression: the file was written through mkstemp and came out 0600, so a daemon
    running as another user could not read it.  A new file gets 0666 minus the umask, a
    replaced one keeps its mode."""
    cal = tmp_path / "new.calib.yaml"
    old = os.umask(0o022)
    try:
        calfile.write_calibration(str(cal), {"umbmark": {"e_max_syst": 0.1}})
    finally:
        os.umask(old)
    assert stat.S_IMODE(cal.stat().st_mode) == 0o644
    cal.chmod(0o640)
    calfile.write_calibration(str(cal), {"umbmark": {"e_max_syst": 0.2}})
    assert stat.S_IMODE(cal.stat().st_mode) == 0o640
    assert calfile.read_calibration(str(cal))["umbmark"]["e_max_syst"] == 0.2


def test_csv_files_with_a_byte_order_mark_are_read(tmp_path):
    """Regression: a spreadsheet's CSV starts with U+FEFF, and the header 't,vx,vy,omega'
    was refused as '\\ufefft,vx,vy,omega'."""
    from mousedom.calibrate.umbmark import parse_runs

    ref = parse_reference("\ufefft,vx,vy,omega\n0,1,0,0\n1,1,0,0\n", "REF.csv")
    assert ref.kind == "twist" and len(ref.t) == 2
    dirs, err = parse_runs("\ufeffdirection,dx,dy\ncw,0.1,0\n", "RUNS.csv")
    assert dirs == ["cw"] and err.tolist() == [[0.1, 0.0]]


def test_csv_lines_are_numbered_as_editors_number_them():
    """A form feed or other str.splitlines separator inside a row split it in two and put
    every later line number off by one; \\r\\n, \\n and a lone \\r end lines."""
    from mousedom.calibrate.csvtext import content_lines

    text = "h\nx\fy\r\nz\rw\n\n# c\nq\x1c1\u2028"
    assert content_lines(text) == [(1, "h"), (2, "x\fy"), (3, "z"), (4, "w"), (7, "q\x1c1\u2028")]
