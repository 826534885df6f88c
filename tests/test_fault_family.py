"""Generated faulty drives: fault handling never ends a drive far worse than switching it off.

The tie break's rules (tests/test_tie_sums.py, tests/test_lifted_tie.py) were each found on
one drive of scripts/fault_sweep.py and are tested there on it; this family draws its own:
a layout of three mice or more, one mouse lifted, lifted with noise or under-reading, for
0.5-3 s from 4-12 s into a 20 s drive, under a healthy rig's conditions.  Before those rules,
drives like these ended 2.9-4.0 m off where fault handling off ended 0.17-0.26 m off; over
1,380 sweep drives, none of these kinds does now.  The long run is the script (README,
"Testing"); these are a few of its kind, drawn from another seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mousedom.fusion import scenarios
from mousedom.fusion.conditions import condition, condition_config, faulty_drive

DURATION = 20.0
LAYOUTS = sorted(name for name, mice in scenarios.LAYOUTS.items() if len(mice) >= 3)
KINDS = ("lift", "lift-noisy", "under-read")
CONDITIONS = ("healthy", "noisy", "stamp-delay", "late-stamps")
DRIVES = 32


def _drive(k: int):
    rng = np.random.default_rng((20261208, k))
    layout = LAYOUTS[k % len(LAYOUTS)]
    mice = scenarios.LAYOUTS[layout]
    mouse = mice[int(rng.integers(len(mice)))][0]
    kind = KINDS[int(rng.integers(len(KINDS)))]
    cond = CONDITIONS[int(rng.integers(len(CONDITIONS)))]
    seed = int(rng.integers(10000))
    start = float(rng.uniform(4.0, 12.0))
    fault = scenarios.Fault(kind, mouse, start, start + float(rng.uniform(0.5, 3.0)))
    label = f"{layout} {mouse} {kind} {cond} seed {seed} {fault.start:.2f}-{fault.end:.2f}"
    return label, faulty_drive(layout, condition(cond, seed), fault, seed, DURATION)


@pytest.mark.parametrize("k", range(DRIVES))
def test_fault_handling_is_not_far_worse_than_off(k):
    """The default engine's end position error is at most twice fault handling off's and
    30 mm, and within 3 times the informed reference's and 0.5 m (a detection limit may
    leave it as far off as off: close-pair-plus's far mouse, docs/models.md)."""
    label, (base, cond, fault, traj, result) = _drive(k)
    off = condition_config(base, cond, robust=False)
    runs = (
        scenarios.measure(result, condition_config(base, cond)),
        scenarios.measure(result, off),
        scenarios.measure(result, off, scenarios.informed_dead(fault, base, traj)),
    )
    default, plain, told = (r.position for r in runs)
    assert default <= 2.0 * plain + 0.03, (label, default, plain, told)
    assert default <= 3.0 * told + 0.5 or math.isclose(default, plain, rel_tol=0.05), (
        label, default, plain, told,
    )  # fmt: skip
