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
    along: np.ndarray  # per-run |component of d1 - d2 along the joining line| / |d1 - d2|
    warnings: list[str] = field(default_factory=list)  # the runs disagree: not stored
    hints: list[str] = field(default_factory=list)  # far from the config: said, stored
    numbers: list[int] = field(default_factory=list)  # each run's number in the session

    def as_json(self) -> dict:
        return {
            "distance": round(self.distance, 6),
            "stderr": round(self.stderr, 6),
            "runs": self.runs,
        }


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
    if np.any(norm == 0):
        k = int(np.argmax(norm == 0))
        raise DistanceError(
            f"run {run_number(numbers, k)}: both mice moved alike: that was no turn"
        )
    per_run = norm / abs(angle)
    mean, stderr, off = run_spread(per_run, tolerance)
    warnings = []
    if line is not None and np.hypot(*line) > 0:
        u = np.asarray(line, dtype=float) / np.hypot(*line)
        along = np.abs(diff @ u) / norm
    else:
        along = np.full(len(d1), np.nan)
    if np.nanmax(along, initial=0.0) > tolerance:
        warnings.append(
            f"the mice moved apart along their joining line by up to {np.nanmax(along):.1%} of "
            "the turn: a mouse slipped or lost the floor, or the mount yaws are wrong"
        )
    if len(off):
        bad = ", ".join(f"run {run_number(numbers, k)}: {per_run[k] * 1000:.1f} mm" for k in off)
        warnings.append(
            f"runs disagree by more than {tolerance:.0%} (mean {mean * 1000:.1f} mm; {bad}): "
            "check the angle of each turn"
        )
    return DistanceResult(mean, stderr, len(d1), per_run, along, warnings,
                          numbers=[run_number(numbers, k) for k in range(len(d1))])  # fmt: skip
