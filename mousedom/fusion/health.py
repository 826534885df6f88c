"""A mouse's health as the fault-tolerant fusion keeps it (``robust.Screen``): its state,
the reason for it, and the count toward re-admission.  The values are what the pose
batches, the replay CSV, SOURCE and the metrics carry."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


class Health(IntEnum):
    """A mouse's health after a window.  The value is what PoseBatch.state, the replay
    CSV's state_<mouse> and the metrics carry; STATES[value] is what SOURCE says."""

    __str__ = int.__repr__  # "2", as an int prints (Python 3.10's IntEnum would say the name)

    TRACKING = 0
    SUSPECT = 1  # used, but flagged
    EXCLUDED = 2  # left out of the solve
    MISSING = 3  # no live sensor
    # left out of the solve while its counts are owed: it is short by the motion of its last
    # moments (a USB host's stall, stamps late), and what it owes is added back when they
    # arrive; past robust.late_s, or owing what no lateness explains, it is EXCLUDED
    LATE = 4


class Reason(IntEnum):
    """Why a mouse is suspect or excluded (PoseBatch.reason, the CSV's reason_<mouse>);
    REASONS[value] is its text."""

    __str__ = int.__repr__

    NONE = 0
    INCONSISTENT = 1
    SILENT = 2  # silent while the others move
    SATURATED = 3
    LOW_QUALITY = 4
    GYRO = 5  # its motion disagrees with the gyro's turn (fusion/gyro.py)


TRACKING, SUSPECT, EXCLUDED, MISSING, LATE = Health
STATES = tuple(h.name.lower() for h in Health)  # ("tracking", "suspect", ...)
NONE, INCONSISTENT, SILENT, SATURATED, LOW_QUALITY, GYRO = Reason
REASONS = ("", "inconsistent", "silent while others move", "saturated", "low quality",
           "disagrees with the gyro")  # fmt: skip
assert len(REASONS) == len(Reason)


@dataclass
class MouseHealth:
    state: int = TRACKING
    reason: int = NONE
    good: int = 0  # consecutive windows of agreement toward re-admission
    # An excluded mouse's re-admission (robust.Screen._held_out): over those windows, its
    # fit of a reading in proportion to the motion (the information-weighted residual along
    # its predicted motion, and the information); and while it is behind (a window it
    # disagreed in, to be paid back by the next as a late mouse's counts are), the windows
    # behind, their residual and its covariance summed.
    fit_r: float = 0.0
    fit_info: float = 0.0
    behind: int = 0
    behind_r: np.ndarray = field(default_factory=lambda: np.zeros(2))
    behind_cov: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    # Where windows are shorter than the evidence's group (readmission.EVIDENCE_S), the windows
    # of the group going on, and their reading, prediction, variances and prediction's
    # covariance summed (readmission.Readmission.grouped)
    group_n: int = 0
    group: np.ndarray = field(default_factory=lambda: np.zeros(10))
