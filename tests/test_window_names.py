"""POSE's sensor lists (docs/protocol.md): the sensors a window was solved with are the
VERSION's less ``missing`` and ``excluded``, and ``used`` counts them, on drives whose
mice are held out as late (stamps late by a long tail, USB catch-up gaps), where a late
mouse used to be in neither list while ``used`` left it out."""

from __future__ import annotations

import numpy as np
import pytest

from mousedom.fusion import conditions, scenarios, sim
from mousedom.fusion.health import Health
from mousedom.service.slots import window_names


@pytest.mark.parametrize("layout", ["triangle", "square"])
@pytest.mark.parametrize("kind", ["late-stamps", "usb-gaps+late-stamps"])
def test_used_is_the_sensors_less_missing_and_excluded(layout, kind):
    base = scenarios.rig(layout)
    names = [m.name for m in base.mice]
    n = len(names)
    late_windows = given_back = 0
    for seed in (12, 21, 33):
        cond = conditions.condition(kind, seed)
        rig = conditions.apply_condition(base, cond, 15.0)
        result = sim.simulate(rig, scenarios.drive(15.0, seed), seed=seed)
        batch, _ = scenarios.run(result, conditions.condition_config(base, cond))
        states = np.asarray(batch.state)
        for k, (state, used) in enumerate(zip(states.tolist(), batch.used.tolist(), strict=True)):
            missing, excluded, _ = window_names(names, [True] * n, state)
            late_windows += Health.LATE in state
            if used == n - len(missing) - len(excluded):
                continue
            # the one exception: a late mouse's counts given back in this window (late
            # after the window before, tracking after this one), not in its solve
            before = states[k - 1].tolist() if k else [Health.TRACKING] * n
            back = [i for i in range(n)
                    if before[i] == Health.LATE and state[i] == Health.TRACKING]  # fmt: skip
            assert back and used == n - len(missing) - len(excluded) - len(back), (k, state, used)
            given_back += 1
    assert late_windows > 0  # (mice were held out as late: the lists were put to the test)
    assert given_back <= late_windows
