"""A mouse whose scale steps beyond the learner's bounds during a drive (onto a floor it
reads 12-25 % more or less on): no CPI within ``robust.scale_limit`` fits it, so the
screen holds it out while the evidence says so, and the windows since the change in which
it was used are given back at its scale as learnt, not clipped.

Before, its scale was clipped to the bound and the mouse kept in use, 2-15 % off in every
window (each window's test and its run's re-admission let that by), and only a block's own
scale beyond the bound by 15 % of it was excluded (``ScaleLearner._faults``): on a broad
sweep of random rigs of 3-6 mice (USB gaps, late stamps), steps of 10-30 % ended a median
158 mm off against an oracle's 6 (the mouse left out of the config)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_scale_change import random_step

from mousedom.fusion import robust, scenarios, sim
from mousedom.fusion.drives import drive

# reads 12-25 % more or less (scales 0.80-0.89 and 1.14-1.33: those above 1.28, reading
# over 22 % less, are a block's own fault too, ScaleLearner._faults)
BEYOND = (0.12, 0.25)


def _run(seed: int, rig_of=lambda base, bad: base, steps: tuple[float, float] = BEYOND):
    base, duration, bad, start, size = random_step(seed, steps)
    mice = list(base.mice)
    # to the drive's end (``drive`` may run a little past ``duration``)
    mice[bad] = dataclasses.replace(mice[bad], scale=((start, math.inf, size),))
    result = sim.simulate(dataclasses.replace(base, mice=tuple(mice)), drive(duration, seed),
                          seed=seed)  # fmt: skip
    rig = rig_of(base, bad)
    names = {m.name for m in rig.mice}
    kept = {k: v for k, v in result.reports.items() if k in names}
    batch, tracker = scenarios.run(dataclasses.replace(result, reports=kept),
                                   scenarios.config(rig))  # fmt: skip
    e = scenarios.end_pose_error(result, batch)
    return math.hypot(e[0], e[1]), batch, tracker, bad, size, start


def _oracle(base: sim.Rig, bad: int) -> sim.Rig:
    return dataclasses.replace(base, mice=base.mice[:bad] + base.mice[bad + 1 :])


@pytest.mark.parametrize("seed", [1, 2, 4, 6, 7])
def test_a_mouse_stepping_beyond_the_bounds_is_held_out(seed):
    """The stepped mouse alone is held out (excluded to the end once found), its scale
    learnt within 2 % of the truth although beyond the bound (from the evidence up to its
    exclusion: nothing is learnt while a mouse is out), and the drive ends within 30 mm of
    the same drive without that mouse configured at all (before: 0.15-1.2 m)."""
    on, batch, tracker, bad, size, start = _run(seed)
    oracle, *_ = _run(seed, _oracle)
    assert on < oracle + 0.03, (on, oracle)
    learner = tracker.scales
    assert learner.beyond == [bad]
    lo, hi = learner.bounds
    assert not lo <= learner.scale[bad, 0] <= hi
    assert learner.scale[bad] == pytest.approx([1.0 / size] * 2, rel=0.02)
    state = np.asarray(batch.state)
    t = np.asarray(batch.t)
    out = np.flatnonzero(state[:, bad] == robust.EXCLUDED)
    assert out.size and t[out[0]] > start
    assert np.all(state[out[0] :, bad] == robust.EXCLUDED)  # held: never re-admitted
    assert not np.any(np.delete(state, bad, axis=1) == robust.EXCLUDED)


# reads 25-45 % more or less (scales 0.69-0.8 and 1.33-1.82): a block's own fault
# (ScaleLearner._faults), found in the block of the step or the next
FAULTY = (0.25, 0.45)


@pytest.mark.parametrize("seed", [3, 8, 37, 46, 60, 67])
def test_a_mouse_stepping_far_beyond_the_bounds_is_given_back_the_block_it_was_found_in(seed):
    """A step so large that a block finds the mouse faulty: it is excluded, and the turn
    and walk of the block's windows it was used in are given back at the block's scale
    of it (``ScaleLearner._give_back_faults``): the drive ends within 50 mm of the same
    drive without that mouse configured (before: 80-670 mm on these seeds; the last three
    have the mouse suspect in some of the block's windows, still used).  Over seeds 1-80 of
    this generator (``bench/scale_steps.py``), 75 drives end so (before: 50;
    docs/models.md, "A mouse out of proportion to its motion", says why not the others)."""
    on, batch, *_ = _run(seed, steps=FAULTY)
    oracle, *_ = _run(seed, _oracle, steps=FAULTY)
    assert on < oracle + 0.05, (on, oracle)


def test_windows_the_screen_took_back_are_not_given_back_again(monkeypatch):
    """Seed 80 of that sweep: the screen held the mouse out inside the block that then
    found it faulty, and took back the windows since its fault's onset
    (``Screen._take_back``); the block's give-back leaves those out
    (``ScaleLearner._not_taken``).  Before, it gave them back a second time: 59 mm off
    against 5 without the mouse; now 7."""
    seed = 80
    handed: list[tuple[int, int, int]] = []
    hand_taken = robust.Screen.hand_taken

    def spy(self):
        taken = hand_taken(self)
        handed.extend(taken)
        return taken

    monkeypatch.setattr(robust.Screen, "hand_taken", spy)
    on, batch, tracker, bad, size, start = _run(seed, steps=FAULTY)
    assert any(i == bad for i, _, _ in handed)  # (the drive takes back: the test can tell)
    oracle, *_ = _run(seed, _oracle, steps=FAULTY)
    assert on < oracle + 0.01, (on, oracle)


@pytest.mark.parametrize("seed", range(40, 46))
def test_no_mouse_is_held_beyond_on_a_healthy_rig(seed):
    """The same rigs, hosts and drives without the step: nobody is beyond the bounds."""
    base, duration, *_ = random_step(seed, BEYOND)
    result = sim.simulate(base, drive(duration, seed), seed=seed)
    batch, tracker = scenarios.run(result, scenarios.config(base))
    assert getattr(tracker.scales, "beyond", []) == []
    assert not np.any(np.asarray(batch.state) == robust.EXCLUDED)


@pytest.mark.parametrize("seed", [2, 4, 8, 10, 11, 13])
def test_a_mouse_back_within_the_bounds_is_let_back(seed):
    """The same drives with the mouse back on its floor halfway from its step to the end:
    held out meanwhile, it is let back once a block of its readings needs a scale within
    the bounds again (``ScaleLearner._released``), learning starts over with it, and the
    drive ends within 0.1 m (before: 56 mm to 1.7 m, the mouse used at the bound
    throughout).  Held out for good, nothing more would be learnt for any mouse."""
    base, duration, bad, start, size = random_step(seed, BEYOND)
    back = start + 0.5 * (duration - start)
    mice = list(base.mice)
    mice[bad] = dataclasses.replace(mice[bad], scale=((start, back, size),))
    result = sim.simulate(dataclasses.replace(base, mice=tuple(mice)), drive(duration, seed),
                          seed=seed)  # fmt: skip
    batch, tracker = scenarios.run(result, scenarios.config(base))
    e = scenarios.end_pose_error(result, batch)
    assert math.hypot(e[0], e[1]) < 0.1, e
    state = np.asarray(batch.state)
    t = np.asarray(batch.t)
    assert np.any(state[(t > start) & (t < back), bad] == robust.EXCLUDED)
    assert state[-1, bad] == robust.TRACKING
    learner = tracker.scales
    assert learner.beyond == [] and learner.groups > 0
    assert learner.scale[bad] == pytest.approx([1.0, 1.0], abs=0.01)


def test_a_held_mouse_back_in_use_by_another_way_is_held_out_again():
    """A held mouse unplugged and plugged back (the tracker told: MISSING, then TRACKING
    at once) is held out again at the next block end, not left in use at its unclipped
    scale (the review's reproducer: a 0.3 s unplug 2 s after it was held out; it was then
    in use, beyond the bounds, in every window after)."""
    base, duration, bad, start, size = random_step(4, BEYOND)
    mice = list(base.mice)
    mice[bad] = dataclasses.replace(mice[bad], scale=((start, math.inf, size),))
    result = sim.simulate(dataclasses.replace(base, mice=tuple(mice)), drive(duration, 4), seed=4)
    first, _ = scenarios.run(result, scenarios.config(base))
    t = np.asarray(first.t)
    held = t[np.flatnonzero(np.asarray(first.state)[:, bad] == robust.EXCLUDED)[0]]
    name = base.mice[bad].name
    gap = (name, held + 2.0, held + 2.3)
    batch, tracker = scenarios.run(result, scenarios.config(base), dead=(gap,))
    state = np.asarray(batch.state)[:, bad]
    t = np.asarray(batch.t)
    assert tracker.scales.beyond == [bad]
    after = state[t > held + 2.3 + 0.6]  # from the block end after it is back
    assert after.size and np.all(after == robust.EXCLUDED), np.unique(after)
