"""Distance between two mice from a turn by a known angle: Bonarini et al. (2004), (18)-(19).

Bonarini turns both mice by eta about a point on the line joining them and takes
D = (|Δy1| + |Δy2|) / eta (eq. 19; eq. 18 is the midpoint case).  That holds when both
mice face the same way, square to the joining line, and the pivot lies between them.

Here the same idea is written without those conditions.  During a rotation by Θ about any
point c fixed to the body, a mouse at p moves (summed over the turn, in body axes) by
Θ J (p - c) with J the 90° rotation, exactly, whatever the path speed.  So
d1 - d2 = Θ J (p1 - p2) and D = |d1 - d2| / |Θ|: the pivot may be anywhere, also outside
the segment or off the line, and the mice may face any way (their mount yaws turn their
counts into body axes).  The component of d1 - d2 along the joining line must vanish; it
is reported as a rigidity check.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from mousedom.calibrate.runs import run_number, run_spread


@dataclass(frozen=True)
class DistanceResult:
    distance: float
    stderr: float
    runs: int
    per_run: np.ndarray
    # per run: |component of d1 - d2 along the joining line the runs measure| / |d1 - d2|
    along: np.ndarray
    warnings: list[str] = field(default_factory=list)  # the runs disagree: not stored
    hints: list[str] = field(default_factory=list)  # far from the config: said, stored
    numbers: list[int] = field(default_factory=list)  # each run's number in the session

    def as_json(self) -> dict:
        return {
            "distance": round(self.distance, 6),
            "stderr": round(self.stderr, 6),
            "runs": self.runs,
        }


# Mice whose motions in a run differ by less than this fraction of it moved alike: no turn
# (a turn about a point more than 1/ALIKE times their distance away is no calibration turn).
ALIKE = 0.01


class DistanceError(ValueError):
    """The runs cannot give a distance."""


def bonarini_distance(dy1: float, dy2: float, eta: float) -> float:
    """Bonarini eq. (19): D = (|Δy1| + |Δy2|) / eta (metres, radians)."""
    return (abs(dy1) + abs(dy2)) / abs(eta)


def calibrate_distance(
    d1: np.ndarray,
    d2: np.ndarray,
    angle: float,
    line: np.ndarray | None = None,
    tolerance: float = 0.02,
    min_runs: int = 2,
    numbers: Sequence[int] | None = None,
) -> DistanceResult:
    """Distance from per-run body-frame displacements d1, d2 (n_runs, 2) in metres.

    ``angle`` is the known turn of each run (radians, sign ignored); ``line`` is the
    configured direction from mouse 1 to mouse 2, for the rigidity check.  ``numbers``:
    each run's number in the user's session, which errors and warnings name (runs left
    out before, as bumps, keep theirs); 1, 2, ... where not given.
    """
    d1 = np.asarray(d1, dtype=float).reshape(-1, 2)
    d2 = np.asarray(d2, dtype=float).reshape(-1, 2)
    if not abs(angle) > 0:
        raise DistanceError("the turn angle must not be zero")
    min_runs = max(min_runs, 2)  # one run has no standard error (it would be NaN in JSON)
    if len(d1) < min_runs:
        raise DistanceError(f"{len(d1)} run(s), need at least {min_runs} for a standard error")
    diff = d1 - d2
    norm = np.hypot(diff[:, 0], diff[:, 1])
    for k in range(len(d1)):
        for j, d in ((1, d1), (2, d2)):
            if not np.any(d[k]):
                raise DistanceError(f"run {run_number(numbers, k)}: mouse {j} did not move")
    # In a turn about a point near the mice their motions differ by D times the turn; a
    # push (or an arc about a point far from both) moves them nearly alike, and the
    # difference left is noise, not the distance: a straight push read as 0.2 mm.
    moved = np.maximum(np.hypot(d1[:, 0], d1[:, 1]), np.hypot(d2[:, 0], d2[:, 1]))
    alike = norm < ALIKE * moved
    if np.any(alike):
        k = int(np.argmax(alike))
        raise DistanceError(
            f"run {run_number(numbers, k)}: both mice moved alike (their difference "
            f"{norm[k] / moved[k]:.2%} of their motion): that was no turn, or a turn about a "
            f"point more than {1 / ALIKE:.0f} times their distance away; turn the robot on "
            "the spot, about a point near the mice"
        )
    per_run = norm / abs(angle)
    mean, stderr, off = run_spread(per_run, tolerance)
    warnings, hints = [], []
    # The joining line as the runs measure it: each run's d1 - d2 is the turn times the
    # line turned by 90 degrees, whatever the mounts say.  The runs must agree on it (a
    # rigid rig: a mouse that slipped or lost the floor in a run turns that run's); the
    # configured mounts are only compared with it, as a hint: a few mm off on a short
    # pair is what this calibration is run to put right, not a reason to refuse it.
    across = diff / norm[:, None]
    across *= np.where(across @ across[0] < 0, -1.0, 1.0)[:, None]  # turns either way
    mean_across = across.sum(axis=0)
    u_measured = np.array([-mean_across[1], mean_across[0]]) / np.hypot(*mean_across)
    along = np.abs(diff @ u_measured) / norm
    if np.max(along) > tolerance:
        warnings.append(
            f"the runs disagree on the mice's joining line by up to {np.max(along):.1%} of "
            "the turn: a mouse slipped or lost the floor in a run"
        )
    if line is not None and np.hypot(*line) > 0:
        u = np.asarray(line, dtype=float) / np.hypot(*line)
        off_line = math.degrees(
            math.asin(min(1.0, abs(float(u[0] * u_measured[1] - u[1] * u_measured[0]))))
        )
        if off_line > math.degrees(math.asin(tolerance)):
            hints.append(
                f"the mice's joining line as measured is {off_line:.1f} degrees from the "
                "configured mounts' (or their yaws are off, or a mouse's `flip` is wrong, "
                "which puts the distance off too): check the mounts (calibrate mounts finds "
                "positions and yaws, and says a wrong flip)"
            )
    if len(off):
        bad = ", ".join(f"run {run_number(numbers, k)}: {per_run[k] * 1000:.1f} mm" for k in off)
        warnings.append(
            f"runs disagree by more than {tolerance:.0%} (mean {mean * 1000:.1f} mm; {bad}): "
            "check the angle of each turn"
        )
    return DistanceResult(mean, stderr, len(d1), per_run, along, warnings, hints,
                          numbers=[run_number(numbers, k) for k in range(len(d1))])  # fmt: skip
