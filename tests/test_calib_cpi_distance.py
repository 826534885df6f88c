"""CPI (Bonarini 4.2) and mouse distance (Bonarini eqs. 18-19) on simulated runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mousedom.calibrate.cpi import CpiError, calibrate_cpi, cpi_per_run
from mousedom.calibrate.distance import DistanceError, bonarini_distance, calibrate_distance
from mousedom.calibrate.runs import run_counts, split_runs
from mousedom.calibrate.synth import SynthMouse, build_motion, mouse_reports
from mousedom.fusion import sim
from mousedom.fusion.units import INCH
from mousedom.sources.base import Reports


def pushes(n: int, length: float, skew: float = 0.0, seconds: float = 1.5):
    """n pushes forth and back along a track at ``skew`` radians to the mouse's axis."""
    ux, uy = length * math.cos(skew), length * math.sin(skew)
    return build_motion([(ux * (-1) ** k, uy * (-1) ** k, 0.0, seconds) for k in range(n)])


def test_bonarini_track_10_runs_of_20_cm_recovers_cpi():
    """Bonarini section 4.2: 10 pushes on a 20 cm track; their mice came out at 450 cpi
    (17.73 counts/mm).  With 1 % per-report noise the error stays under 0.3 %."""
    assert 17.73 * 25.4 == pytest.approx(450, abs=0.5)
    mouse = SynthMouse("m", 0.0, 0.0, cpi_x=440, cpi_y=450.3, rel_noise=0.01, abs_noise=0.3)
    rec = {"m": mouse_reports(mouse, pushes(10, 0.2), seed=1)}
    runs = split_runs(rec)
    assert len(runs) == 10
    counts = run_counts(rec, runs, ["m"])[:, 0, :]
    res = calibrate_cpi(counts, 0.2, "y", cpi_across=400)
    assert res.runs == 10 and not res.warnings
    assert abs(res.cpi / 450.3 - 1) < 0.003
    assert res.stderr < 0.5 and abs(res.cpi - 450.3) < 4 * res.stderr + 0.5
    assert res.as_json() == {
        "axis": "y",
        "cpi": round(res.cpi, 3),
        "stderr": round(res.stderr, 3),
        "runs": 10,
    }


def test_cpi_x_axis_sideways_pushes():
    mouse = SynthMouse("m", 0.0, 0.0, cpi_x=812, cpi_y=800)
    rec = {"m": mouse_reports(mouse, pushes(6, 0.15, skew=math.pi / 2))}
    counts = run_counts(rec, split_runs(rec), ["m"])[:, 0, :]
    res = calibrate_cpi(counts, 0.15, "x", cpi_across=800)
    assert res.cpi == pytest.approx(812, rel=5e-4)


def test_skewed_track_is_corrected_by_the_cross_counts():
    """A mouse 6 degrees askew on its track reads cos(6 deg) = 0.55 % short along y; the
    counts across the axis give the skew back."""
    mouse = SynthMouse("m", 0.0, 0.0, cpi_x=1000, cpi_y=1000)
    rec = {"m": mouse_reports(mouse, pushes(4, 0.2, skew=math.radians(6)))}
    counts = run_counts(rec, split_runs(rec), ["m"])[:, 0, :]
    naive = np.mean(np.abs(counts[:, 1])) / (0.2 / INCH)
    assert naive == pytest.approx(1000 * math.cos(math.radians(6)), rel=5e-4)
    res = calibrate_cpi(counts, 0.2, "y", cpi_across=1000)
    assert res.cpi == pytest.approx(1000, rel=3e-4)
    np.testing.assert_allclose(res.skew_deg, 6, atol=0.05)


def test_cpi_per_run_formula():
    """One run: 5 inch pushes: 1000 counts along -> 200 cpi; 3-4-5 triangle: 3 in across."""
    cpi, skew = cpi_per_run(np.array([1000.0, 800.0]), np.array([0.0, 600.0]), 5 * INCH, 200)
    np.testing.assert_allclose(cpi, [200.0, 200.0])
    np.testing.assert_allclose(np.degrees(skew), [0, math.degrees(math.asin(0.6))])


def test_cpi_warns_when_runs_disagree_and_refuses_bad_runs():
    counts = np.array([[0, 1000], [0, -1000], [0, 1030], [0, -1000]], dtype=float)
    res = calibrate_cpi(counts, 2 * INCH, "y")
    assert len(res.warnings) == 1 and "run 3" in res.warnings[0] and "2%" in res.warnings[0]
    with pytest.raises(CpiError, match="1 run"):
        calibrate_cpi(counts[:1], 2 * INCH)
    with pytest.raises(CpiError, match="run 2: no counts along y"):
        calibrate_cpi(np.array([[0, 1000], [5, 0]]), 2 * INCH)
    with pytest.raises(CpiError, match="run 2: the push was 30 deg off the mouse's y axis"):
        calibrate_cpi(np.array([[0, 1000], [500, 866]]), 1000 / 1000 * INCH, "y", 1000)
    with pytest.raises(CpiError, match="more than the push length"):
        calibrate_cpi(np.array([[3000, 10], [3000, 10]]), 2 * INCH, "y", cpi_across=1000)


def test_bonarini_eq_18_19_and_the_vector_form_agree():
    """Bonarini eq. (19) (pivot on the joining line) and eq. (18) (midpoint): the vector
    form |d1 - d2| / eta gives the same D when their conditions hold."""
    eta = math.pi / 2
    for pivot in (0.0, 0.05, -0.1):  # along the joining line (body y), mice at y = +-D/2
        d = 0.27
        p1, p2 = np.array([0, d / 2]), np.array([0, -d / 2])
        c = np.array([0, pivot])
        d1 = eta * np.array([-(p1 - c)[1], (p1 - c)[0]])
        d2 = eta * np.array([-(p2 - c)[1], (p2 - c)[0]])
        assert bonarini_distance(d1[0], d2[0], eta) == pytest.approx(d)
        res = calibrate_distance(np.array([d1, d1]), np.array([d2, d2]), eta, line=p2 - p1)
        assert res.distance == pytest.approx(d)
    assert bonarini_distance(0.27 * eta / 2, 0.27 * eta / 2, eta) == pytest.approx(0.27)  # (18)


def test_distance_from_simulated_turns_with_noise():
    """Two mice 270 mm apart (Bonarini's rig), turned by 90 degrees about a point 40 mm
    off their midpoint, 4 runs, 1 % noise: D within 0.5 mm."""
    eta = math.pi / 2
    pivot = np.array([0.0, 0.04])
    # A turn about ``pivot``: body twist v = -w x c = (w c_y, -w c_x).
    motion = build_motion(
        [(eta * pivot[1] * s, -eta * pivot[0] * s, eta * s, 2.5) for s in (1, -1, 1, -1)]
    )
    left = SynthMouse("left", 0.0, 0.135, cpi_x=450, cpi_y=450, rel_noise=0.01, abs_noise=0.3)
    right = SynthMouse(
        "right", 0.0, -0.135, cpi_x=450, cpi_y=450, rel_noise=0.01, abs_noise=0.3, phase=0.5
    )
    rec = {m.name: mouse_reports(m, motion, seed=i) for i, m in enumerate((left, right))}
    runs = split_runs(rec)
    counts = run_counts(rec, runs, ["left", "right"])
    to_m = INCH / 450

    def body(c):  # yaw 0: forward = -REL_Y, left = -REL_X
        return np.column_stack([-c[:, 1], -c[:, 0]]) * to_m

    res = calibrate_distance(body(counts[:, 0]), body(counts[:, 1]), eta, line=[0, -1])
    assert res.runs == 4 and not res.warnings
    assert abs(res.distance - 0.27) < 5e-4
    assert res.as_json()["runs"] == 4


def test_distance_on_the_core_simulator():
    """mousedom.fusion.sim: turn on the spot of a rig whose mice are off the body origin."""
    mice = (
        sim.SimMouse("a", 0.05, 0.1, cpi_x=800, cpi_y=800),
        sim.SimMouse("b", 0.05, -0.15, yaw=180.0, cpi_x=800, cpi_y=800, phase=0.003),
    )
    traj = sim.sequence(
        sim.pause(0.3),
        sim.turn(1.0),
        sim.pause(1),
        sim.turn(-1.0),
        sim.pause(1),
        sim.turn(1.0),
        sim.pause(0.3),
    )
    res = sim.simulate(sim.Rig(mice), traj, seed=0)
    cfg = sim.rig_config(sim.Rig(mice))
    rec = {n: Reports(n, r.t, r.dx, r.dy) for n, r in res.reports.items()}
    runs = split_runs(rec)
    counts = run_counts(rec, runs, ["a", "b"])
    from mousedom.calibrate.counts import body_frame

    d1 = body_frame(cfg.mouse("a"), counts[:, 0, 0], counts[:, 0, 1])
    d2 = body_frame(cfg.mouse("b"), counts[:, 1, 0], counts[:, 1, 1])
    out = calibrate_distance(d1, d2, 1.0, line=[0, -0.25])
    assert out.distance == pytest.approx(0.25, abs=2e-4)


def test_distance_refuses_bad_runs():
    with pytest.raises(DistanceError, match="1 run"):
        calibrate_distance(np.ones((1, 2)), -np.ones((1, 2)), 1.0)
    with pytest.raises(DistanceError, match="run 2: mouse 2 did not move"):
        calibrate_distance(np.ones((2, 2)), np.array([[-1.0, -1], [0, 0]]), 1.0)
    with pytest.raises(DistanceError, match="no turn"):
        calibrate_distance(np.ones((2, 2)), np.ones((2, 2)), 1.0)
    with pytest.raises(DistanceError, match="zero"):
        calibrate_distance(np.ones((2, 2)), -np.ones((2, 2)), 0.0)
    slip = calibrate_distance(
        np.array([[0.1, 0.0], [0.1, 0.02]]), np.array([[-0.1, 0.0]] * 2), 1.0, line=[0, 1]
    )
    assert any("joining line" in w for w in slip.warnings)


def test_cpi_on_the_core_simulator_with_noise():
    """mousedom.fusion.sim: 10 pushes of 20 cm forth and back, 0.5 count noise per report."""
    m = sim.SimMouse("m", 0.0, 0.0, cpi_x=455.0, cpi_y=455.0, noise=0.5)
    legs = [sim.straight(0.2 * (-1) ** k, 0.25) + sim.pause(0.8) for k in range(10)]
    res = sim.simulate(sim.Rig((m,)), sim.sequence(sim.pause(0.5), *legs), seed=4)
    r = res.reports["m"]
    rec = {"m": Reports("m", r.t, r.dx, r.dy)}
    counts = run_counts(rec, split_runs(rec), ["m"])[:, 0, :]
    assert len(counts) == 10
    # sim's forward motion along body x with yaw 0 is -REL_Y: 'y' axis pushes.
    out = calibrate_cpi(counts, 0.2, "y", cpi_across=455)
    assert abs(out.cpi / 455 - 1) < 0.003  # issue 7's target
    # The target alone is 7 standard errors wide here: hold the estimate to its own
    # standard error too, so that a bias of a few counts per push cannot hide in it.
    assert 0 < out.stderr < 0.5 and abs(out.cpi - 455) < 4 * out.stderr


def test_distance_names_runs_by_the_numbers_it_is_given():
    """The session passes each kept run's own number (runs before it may have been left out
    as bumps): a disagreeing turn and a turn one mouse missed are named by it."""
    eta = math.pi / 2
    d1 = np.array([[0.0, 0.1], [0.0, 0.1], [0.0, 0.11]]) * eta
    d2 = -d1
    res = calibrate_distance(d1, d2, eta, numbers=[1, 3, 4])
    assert res.numbers == [1, 3, 4] and "run 4: 220.0 mm" in res.warnings[-1]
    d1[1] = 0.0
    with pytest.raises(DistanceError, match="run 3: mouse 1 did not move"):
        calibrate_distance(d1, d2, eta, numbers=[1, 3, 4])
    assert calibrate_distance(-d2, d2, eta).numbers == [1, 2, 3]  # none given: 1, 2, ...


@pytest.mark.parametrize("seed", range(30))
def test_distance_takes_the_joining_line_from_the_runs_not_the_mounts(seed):
    """Turns about a point near a random pair (40-300 mm apart, any orientation), the
    configured mounts up to 5 mm off: the distance exact, no warning (a few mm off on a
    short pair is what the calibration is for: 15 of 40 such seeds were warned of a slip
    and refused --write); the mounts' line compared only as a hint.  A slip in one run
    turns that run's line: warned."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.04, 0.3)
    phi = rng.uniform(-math.pi, math.pi)
    p1 = rng.uniform(-0.2, 0.2, 2)
    p2 = p1 + d * np.array([math.cos(phi), math.sin(phi)])
    eta = math.radians(rng.choice([45.0, 90.0, 180.0]))

    def turn(p, c, th):  # mouse at p, turned by th about c: th J (p - c), body axes
        return th * np.array([-(p - c)[1], (p - c)[0]])

    runs = [(rng.uniform(-0.1, 0.1, 2) + (p1 + p2) / 2, eta * s) for s in (1, -1, 1, -1)]
    d1 = np.array([turn(p1, c, th) for c, th in runs])
    d2 = np.array([turn(p2, c, th) for c, th in runs])
    off = rng.uniform(-0.005, 0.005, 2)
    configured = p2 + off - p1
    res = calibrate_distance(d1, d2, eta, line=configured)
    assert res.distance == pytest.approx(d, rel=1e-9) and not res.warnings
    angle = abs(math.degrees(math.atan2(configured[1], configured[0]) - phi) + 180) % 360 - 180
    assert bool(res.hints) == (
        abs(angle) > math.degrees(math.asin(0.02)) + 1e-9
        and 180 - abs(angle) > math.degrees(math.asin(0.02)) + 1e-9
    )
    slipped = d1.copy()
    slipped[2] += 0.05 * np.hypot(*(d1[2] - d2[2])) * (p2 - p1) / d  # along the line
    assert any("joining line" in w for w in calibrate_distance(slipped, d2, eta).warnings)


@pytest.mark.parametrize("seed", range(10))
def test_distance_refuses_pushes_as_no_turn(seed):
    """Straight pushes (or arcs about a far point) move both mice nearly alike: the noise
    left in their difference is no distance (a push read as 0.18 mm, exit 0)."""
    rng = np.random.default_rng(seed)
    push = (
        rng.uniform(0.1, 0.5)
        * np.array([[1.0, 0.0], [-1.0, 0.0]] * 2)
        @ np.array([[math.cos(a := rng.uniform(0, 6.3)), math.sin(a)], [-math.sin(a), math.cos(a)]])
    )
    d1 = push + rng.normal(0, 2e-4, push.shape)
    d2 = push + rng.normal(0, 2e-4, push.shape)
    with pytest.raises(DistanceError, match="moved alike"):
        calibrate_distance(d1, d2, math.pi / 2)
