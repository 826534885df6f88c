"""An excluded mouse is let back once it shows itself sound (issue 31: Readmission.waiting),
however wide late stamps made its tolerance.

Under long-tailed stamp delays the noise model learns wide errors not in proportion to the
motion, and a window of 10 ms seldom moved a mouse beyond them: such a window shows
nothing, and a mouse lifted for one second stayed excluded to the drive's end in 63 of 155
drives (fault handling off and told the lift: none).  Worse, a healthy far mouse excluded
once behind a close pair was never let back, and when one of the pair was lifted the pair
alone made the pose spin: 7 m and 160 degrees off.  An excluded mouse's windows are now
summed until the others moved it enough to show a fault (``Readmission.grouped``), and the
run's fit of a proportional fault takes off the bias its own noise puts along its reading
(``Readmission.waiting``).

The drives are generated: layouts of three mice and more, which mouse is lifted, when and
for how long, the stamp delays' tail and whether USB gaps come with it, all drawn from a
seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mousedom.config import RobustConfig
from mousedom.fusion import robust, scenarios
from mousedom.fusion.conditions import Condition, condition, condition_config, faulty_drive

DURATION = 20.0
LAYOUTS = sorted(name for name, mice in scenarios.LAYOUTS.items() if len(mice) >= 3)


def _faulty(layout: str, cond: Condition, fault: scenarios.Fault, seed: int):
    """``drive(DURATION, seed)`` on ``layout`` under ``cond`` with ``fault``, through the
    default engine: (the rig as configured, the simulation, the batch)."""
    base, _, _, _, result = faulty_drive(layout, cond, fault, seed, DURATION)
    batch, _ = scenarios.run(result, condition_config(base, cond))
    return base, result, batch


def _back_after(states: np.ndarray, t: np.ndarray, end: float) -> float:
    """Seconds from ``end`` to the first window after it in which the mouse (``states``,
    one per window) is in use again (inf: never)."""
    out = (t > end) & (states != robust.EXCLUDED) & (states != robust.LATE)
    return float(t[np.argmax(out)] - end) if out.any() else math.inf


def _lift_drive(k: int):
    """Generated drive ``k``: a mouse lifted under late stamps.  Returns the lifted mouse's
    states, the windows' stamps, the lift's end, the default engine's end position error
    and that of fault handling off told the lift (the reports removed by hand)."""
    rng = np.random.default_rng((20261207, k))
    layout = LAYOUTS[int(rng.integers(len(LAYOUTS)))]
    mice = scenarios.LAYOUTS[layout]
    mouse = mice[int(rng.integers(len(mice)))][0]
    seed = int(rng.integers(1000))
    name = "late-stamps+usb-gaps" if rng.random() < 0.3 else "late-stamps"
    cond = condition(name, seed, stamp_tail=float(rng.uniform(0.0015, 0.005)))
    start = float(rng.uniform(4.0, 12.0))
    end = start + float(rng.uniform(0.5, 2.0))
    base, result, batch = _faulty(layout, cond, scenarios.Fault("lift", mouse, start, end), seed)
    told, _ = scenarios.run(result, condition_config(base, cond, robust=False),
                            ((mouse, start, end),))  # fmt: skip
    j = [m.name for m in base.mice].index(mouse)
    errors = [math.hypot(*scenarios.end_pose_error(result, b)[:2]) for b in (batch, told)]
    label = f"{layout} {mouse} seed {seed} {name} lift {start:.2f}-{end:.2f}"
    return label, np.asarray(batch.state)[:, j], np.asarray(batch.t), end, errors


DRIVES = 24


@pytest.fixture(scope="module")
def drives():
    return [_lift_drive(k) for k in range(DRIVES)]


def test_a_lifted_mouse_comes_back_under_late_stamps(drives):
    """A lifted mouse is back before the drive ends (63 of 155 were not), most within a
    second and a half of landing.  Some far mice behind a close pair stay out: their
    learnt error is as large as their motion a window, and even a second's group seldom
    moved them beyond it (7 of 96 generated drives; each ended within 20 mm of fault
    handling off told the lift, four better than it)."""
    stuck = [label for label, st, _, _, _ in drives if st[-1] == robust.EXCLUDED]
    assert len(stuck) <= len(drives) // 8, stuck
    back = [_back_after(st, t, end) for _, st, t, end, _ in drives]
    assert np.median(back) < 1.5, back


def test_the_pose_after_a_lift_under_late_stamps_is_as_good_as_told(drives):
    """The end pose is as good as fault handling off told the lift's span: the median
    within 1.25 times its, and no drive more than 60 mm worse.  Before, one generated drive
    ended 6 m off (a far mouse never let back, then one of the close pair lifted) and one
    0.5 m (a lift's whole shortfall taken for a late mouse's paid-back debt, on the
    strength of one window the others barely fixed it in: ``Ledger.paid``)."""
    rob = np.array([e[0] for *_, e in drives])
    told = np.array([e[1] for *_, e in drives])
    assert np.median(rob) <= 1.25 * np.median(told) + 0.001, (np.median(rob), np.median(told))
    worst = int(np.argmax(rob - told))
    assert rob[worst] - told[worst] < 0.06, (drives[worst][0], rob[worst], told[worst])


def test_a_lifts_shortfall_is_not_taken_for_a_paid_back_debt():
    """Regression (generated drive 80): three mice in a line, the front one lifted for
    0.8 s.  Over its exclusion one window's prediction of it from the other two erred by
    41 mm across (1.6 mm typical); held to that window, the lift's whole shortfall, 68 mm,
    passed as paid back, and the heading turned 13 degrees at its return (0.52 m off at
    the end, told the lift 9 mm)."""
    label, st, t, end, (rob, told) = _lift_drive(80)
    assert "line-along f" in label
    assert (st[t > end + 3.0] != robust.EXCLUDED).any()  # it is back: the give-back happened
    assert rob < told + 0.02, (rob, told)


def test_a_far_mouse_behind_a_close_pair_is_let_back():
    """Regression: a far mouse behind a pair 2 cm apart, its stamps late, was excluded
    once and never let back; when one of the pair was lifted, the pair alone read the lift
    as a spin: the drive ended 7 m and 160 degrees off (told the lift: 4 mm)."""
    seed = 11
    cond = condition("late-stamps", seed)
    _, result, batch = _faulty(
        "close-pair-plus", cond, scenarios.Fault("lift", "a", 8.0, 9.0), seed
    )
    e = scenarios.end_pose_error(result, batch)
    assert math.hypot(e[0], e[1]) < 0.02 and abs(e[2]) < math.radians(1.0), e
    far = np.asarray(batch.state)[:, 2]
    during = (batch.t > 8.0) & (batch.t < 9.0)
    assert (far[during] != robust.EXCLUDED).all()


def _excluded_screen(window: float) -> robust.Screen:
    xy = np.array([[0.1, 0.08], [0.1, -0.08], [-0.1, 0.08], [-0.1, -0.08]])
    screen = robust.Screen("lsq", xy, np.full(4, 1e-5), np.full(4, 0.001), window,
                           RobustConfig(), None)  # fmt: skip
    screen.health[0].state = robust.EXCLUDED
    screen.health[0].reason = robust.INCONSISTENT
    screen.hold_beyond([0])  # judged, never re-admitted: the fit runs on
    return screen


@pytest.mark.parametrize("motion_to_noise", [80.0, 150.0, 400.0])
def test_the_run_fit_of_a_healthy_mouse_is_unbiased(motion_to_noise):
    """A healthy excluded mouse's fit of a proportional fault (``run_agrees``) is
    centred on no fault, whatever its noise against its motion: over 24 runs of 400
    windows, its standardised g (g over its error) averages 0 within 0.75, where the
    noise's own bias along the reading put it near 4.5 (motion^2 80 times the noise's
    variance) and failed runs of healthy mice."""
    zs = []
    for seed in range(24):
        rng = np.random.default_rng((77, seed))
        screen = _excluded_screen(0.01)
        h = screen.health[0]
        s2 = 1e-10
        for _ in range(400):
            ang = rng.uniform(0.0, 2.0 * math.pi)
            p = math.sqrt(motion_to_noise * s2) * np.array([math.cos(ang), math.sin(ang)])
            d = p + rng.normal(0.0, math.sqrt(s2), 2)
            screen.readmission.waiting(
                screen.ledger, 0, h, d, p, s2, s2, np.zeros((2, 2)), 1, beyond=True,
                reads_nothing=False,
            )  # fmt: skip
        assert h.fit_info > 0.0
        zs.append(h.fit_r / math.sqrt(h.fit_info))
    assert abs(float(np.mean(zs))) < 0.75, (np.mean(zs), zs)


def test_a_noisy_lifts_shortfall_is_not_paid_back_whole():
    """Regression (a generated fault sweep): the far mouse of close-pair-plus lifted for
    2.5 s, reading noise, with USB gaps and 4.6 ms stamp tails.  One window of its
    exclusion expected an error of 148 mm of it (its learnt error on the lift's noise);
    held to that window, the lift's whole shortfall (0.6 m) passed as paid back at its
    return, and the heading jumped 25 degrees to where fault handling off had it (29
    degrees off at the end).  Held to the mean window's error it is not paid back."""
    seed, tail, start, end = 6044, 0.004579668710217194, 9.535733913200678, 12.064345259992542
    cond = condition("usb-gaps+late-stamps", seed, stamp_tail=tail)
    fault = scenarios.Fault("lift-noisy", "c", start, end)
    base, result, batch = _faulty("close-pair-plus", cond, fault, seed)
    off, _ = scenarios.run(result, condition_config(base, cond, robust=False))
    heading = abs(scenarios.end_pose_error(result, batch)[2])
    heading_off = abs(scenarios.end_pose_error(result, off)[2])
    assert heading_off > math.radians(20.0)  # the drive still shows the lift
    assert heading < 0.5 * heading_off, (math.degrees(heading), math.degrees(heading_off))


@pytest.mark.parametrize("cond_name", ["healthy", "usb-gaps"])
def test_a_far_mouse_lifted_behind_a_close_pair_is_back_within_a_second(cond_name):
    """The far mouse of close-pair-plus lifted for a second, six drives: back within a
    second of landing in every one (0.25-0.27 s).  Its windows are held to its own error
    and to the pair's prediction of it, some twenty times less certain across the line to
    the pair; held to its own error alone, it came back after 0.6-6.7 s or never."""
    late = []
    for seed in range(1, 7):
        fault = scenarios.Fault("lift", "c", 8.0, 9.0)
        _, _, batch = _faulty("close-pair-plus", condition(cond_name, seed), fault, seed)
        back = _back_after(np.asarray(batch.state)[:, 2], np.asarray(batch.t), 9.0)
        if back > 1.0:
            late.append((seed, back))
    assert not late, late
