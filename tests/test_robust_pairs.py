"""Two mice faulty together (issue 31, item 2): no wrong blame locks in.

The drives that used to end metres off: on the square, a mouse under-reading while
another is lifted, in a pivot (the diagonal pair cannot tell an under-read from a shifted
pivot, and the previous window's solution was already bent by the creeping fault), and two
mice on one side under-reading in an arc.  Each is run against the informed reference
(plain least squares, both faulty spans removed by hand) and the same drive without the
faults (scenarios.pair_trial)."""

from __future__ import annotations

import pytest

from mousedom.fusion import scenarios

CASES = [
    # (layout, kinds, mice, during, seed)
    ("square", ("lift", "under-read"), ("fr", "fl"), "turn", 1),
    ("square", ("lift", "under-read"), ("fl", "fr"), "turn", 1),
    ("square", ("lift", "under-read"), ("rr", "fr"), "turn", 1),
    ("square", ("under-read", "under-read"), ("fl", "rl"), "arc", 0),
    ("square", ("lift", "under-read"), ("fl", "rl"), "arc", 0),
    ("square", ("under-read", "jumps"), ("rl", "rr"), "turn", 0),
    ("pentagon", ("lift", "lift"), ("fl", "fr"), "straight", 0),
    ("pentagon", ("under-read", "jumps"), ("fl", "rr"), "turn", 2),
    ("kite", ("lift", "under-read"), ("nose", "tail"), "arc", 1),
]


@pytest.mark.parametrize("layout, kinds, mice, during, seed", CASES)
def test_two_faults_at_once_end_near_the_informed_reference(layout, kinds, mice, during, seed):
    names = [n for n, *_ in scenarios.LAYOUTS[layout]]
    mice = tuple(m if m in names else names[-1] for m in mice)
    trial = scenarios.pair_trial(layout, kinds, mice, during, seed, 60.0)
    default, informed, clean = trial.default, trial.informed, trial.clean
    # within twice the informed reference (+20 mm), and within 5 times the same drive
    # without the faults (the 2 is not met everywhere yet: docs/models.md)
    assert default.position <= 2 * informed.position + 0.020, trial
    assert default.position <= 5 * clean.position + 0.005, trial
    assert default.heading <= 2 * informed.heading + 0.02, trial


def test_a_wrong_blame_is_revisited_when_the_kept_mice_fail():
    """Square rig, fr lifted (silent) and held out; rl, healthy, held out too by a wrong
    blame (set by hand); fl reads half.  The kept pair {fl, rr} cannot explain a general
    motion and cannot blame either of its two: the choice is revisited over all live mice,
    fl is excluded and rl comes back (suspect until it agrees for readmit_s)."""
    import numpy as np

    from mousedom.config import RobustConfig
    from mousedom.fusion import robust

    xy = np.array([[0.1, 0.08], [0.1, -0.08], [-0.1, 0.08], [-0.1, -0.08]])
    screen = robust.Screen("lsq", xy, np.full(4, 1e-5), np.full(4, 0.001), 0.01,
                           RobustConfig(), None)  # fmt: skip
    screen.noise.lam_f[:] = 1.0
    screen.noise._sync()
    q = np.array([0.003, 0.0005, 0.02])  # forward, a little sideways, turning
    d = screen.predict(q)
    d[0] *= 0.5  # fl under-reads
    d[1] = 0.0  # fr lifted
    for i, why in ((1, robust.SILENT), (2, robust.INCONSISTENT)):
        screen.health[i].state, screen.health[i].reason = robust.EXCLUDED, why
    screen.accepted(screen.predict(q)[None], screen.predict(q)[None], [True, False, False, True])
    dec = screen.decide(d, np.ones(4, dtype=bool))
    assert dec.used.tolist() == [False, False, True, True]
    # fl, newly blamed, reads half its motion: after one window that is what a mouse late
    # by half a window reads too, so it is held out as late (health.LATE), not yet excluded
    assert [h.state for h in screen.health] == [robust.LATE, robust.EXCLUDED,
                                                robust.SUSPECT, robust.TRACKING]  # fmt: skip
