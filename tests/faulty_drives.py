"""Helpers for tests that run one of scripts/fault_sweep.py's faulty drives: its end errors
with fault handling and for the informed reference, and who was held out."""

from __future__ import annotations

import numpy as np

from mousedom.fusion import robust, scenarios
from mousedom.fusion.conditions import condition_config, faulty_drive


def ends(layout: str, cond, fault: scenarios.Fault, seed: int):
    """A 20 s drive on ``layout`` under ``cond`` with ``fault``, run by the default engine:
    (the rig, its batch, its end error (x, y, theta), the informed reference's end error)."""
    base, c, _, traj, result = faulty_drive(layout, cond, fault, seed, 20.0)
    batch, _ = scenarios.run(result, condition_config(base, c))
    off = condition_config(base, c, robust=False)
    informed, _ = scenarios.run(result, off, scenarios.informed_dead(fault, base, traj))
    return (base, batch, scenarios.end_pose_error(result, batch),
            scenarios.end_pose_error(result, informed))  # fmt: skip


def assert_only_the_faulty_held_out(base, batch, fault: scenarios.Fault) -> None:
    """No healthy mouse was ever held out (excluded or late), and the faulty one was
    during its fault."""
    j = [m.name for m in base.mice].index(fault.mouse)
    out = np.isin(np.asarray(batch.state), (robust.EXCLUDED, robust.LATE))
    assert not np.delete(out, j, axis=1).any(), "a healthy mouse was held out"
    during = (np.asarray(batch.t) > fault.start) & (np.asarray(batch.t) < fault.end)
    assert out[during, j].any(), "the faulty mouse was never held out"
