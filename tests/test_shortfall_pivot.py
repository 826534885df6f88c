"""A mouse at a spin's pivot is not short of its motion (robust.Screen._quiet_blame).

The shortfall test holds out a mouse that reads much less than the others move it, summed
over windows: a lift that late stamps' wide tolerances let pass window by window.  A mouse
at the pivot of a spin truly reads nothing, while the others' prediction of it carries
their errors: their noise, a white walk, and their CPIs' errors, which add up window after
window.  Measured against its floor alone, that sum held a healthy middle mouse out for
seconds (a line of three along the robot, one CPI 5 % off: 0.18 m at the end, told the
true CPI 9 mm).  The sum is now held to what those errors allow."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mousedom.fusion import robust, scenarios, sim
from mousedom.fusion.drives import drive


@pytest.mark.parametrize("seed, which, factor, hz", [
    (276, 0, 0.95, 1000.0), (446, 2, 0.9, 125.0), (277, 2, 1.05, None), (278, 0, 1.1, None),
])  # fmt: skip
def test_the_pivot_mouse_of_a_line_is_kept_under_a_wrong_cpi(seed, which, factor, hz):
    base = scenarios.rig("line-along")
    if hz is not None:
        base = dataclasses.replace(
            base, mice=tuple(dataclasses.replace(m, report_hz=hz) for m in base.mice)
        )
    mice = list(base.mice)
    m = mice[which]
    mice[which] = dataclasses.replace(m, cpi_x=m.cpi_x * factor, cpi_y=m.cpi_y * factor)
    true = dataclasses.replace(base, mice=tuple(mice))
    result = sim.simulate(true, drive(40.0, seed), seed=seed)
    batch, tracker = scenarios.run(result, scenarios.config(base))
    state = np.asarray(batch.state)[:, 1]
    assert not np.isin(state, (robust.EXCLUDED, robust.LATE)).any()
    learnt = scenarios.end_error(result, tracker)[0]
    told = scenarios.end_error(result, scenarios.run(result, scenarios.config(true))[1])[0]
    assert learnt <= 2 * told + 0.020, (learnt, told)
