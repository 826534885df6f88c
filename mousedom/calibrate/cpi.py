"""CPI from straight pushes of known length: Bonarini et al. (2004), section 4.2.

Bonarini moved the mice 10 times along a 20 cm track and took the average count of the
mouse's Δy.  A push that is not exactly along the mouse's axis (the mouse sits a little
skewed on the track) shortens the count along the axis by cos(skew); the counts across
the axis measure the skew, so each run's length along the axis is corrected with them:
along = sqrt(L^2 - across^2), ``across`` in inches from the configured CPI of the other
axis (its error only enters at second order in the skew).  Each run gives one CPI; the
result is their mean with its standard error, and a warning when runs disagree by more
than ``tolerance`` (2 %).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from mousedom.calibrate.runs import run_number, run_spread
from mousedom.fusion.units import INCH

AXES = ("x", "y")
MAX_SKEW = np.radians(15.0)  # beyond this a push is along the wrong axis, not askew


@dataclass(frozen=True)
class CpiResult:
    axis: str
    cpi: float
    stderr: float
    runs: int
    per_run: np.ndarray  # CPI of each run
    skew_deg: np.ndarray  # angle between each push and the mouse's axis
    warnings: list[str] = field(default_factory=list)  # the runs disagree: not stored
    hints: list[str] = field(default_factory=list)  # far from the config: said, stored
    numbers: list[int] = field(default_factory=list)  # each run's number in the session

    def as_json(self) -> dict:
        return {
            "axis": self.axis,
            "cpi": round(self.cpi, 3),
            "stderr": round(self.stderr, 3),
            "runs": self.runs,
        }


class CpiError(ValueError):
    """The runs cannot give a CPI (too few, no motion, longer across than the push)."""


def cpi_per_run(
    along: np.ndarray,
    across: np.ndarray,
    distance: float,
    cpi_across: float,
    numbers: Sequence[int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(cpi, skew) per run from counts along and across the axis, for pushes of ``distance`` m.

    Returns arrays of the CPI along the axis and the skew angle (radians) of each push.
    ``numbers``: each run's number in the user's session (errors name it); 1, 2, ...
    """
    along = np.abs(np.asarray(along, dtype=float))
    across_in = np.abs(np.asarray(across, dtype=float)) / cpi_across
    length_in = distance / INCH
    if np.any(across_in >= length_in):
        k = int(np.argmax(across_in >= length_in))
        raise CpiError(
            f"run {run_number(numbers, k)}: the mouse moved {across_in[k] * INCH * 1000:.1f} mm "
            "across its axis, "
            f"more than the push length {distance * 1000:.1f} mm: wrong --axis or --distance?"
        )
    along_in = np.sqrt(length_in**2 - across_in**2)
    return along / along_in, np.arcsin(across_in / length_in)


def calibrate_cpi(
    counts: np.ndarray,
    distance: float,
    axis: str = "y",
    cpi_across: float = 1000.0,
    tolerance: float = 0.02,
    min_runs: int = 2,
    numbers: Sequence[int] | None = None,
) -> CpiResult:
    """CPI along ``axis`` from ``counts`` (n_runs, 2) = per-run (REL_X, REL_Y) sums.

    ``cpi_across`` is the configured CPI of the other axis (for the skew correction).
    ``numbers``: each run's number in the user's session, which errors and warnings name
    (runs left out before, as bumps, keep theirs); 1, 2, ... where not given.
    """
    if axis not in AXES:
        raise ValueError(f"axis must be x or y, got {axis!r}")
    if not distance > 0:
        raise CpiError(f"the push distance must be positive, got {distance}")
    counts = np.asarray(counts, dtype=float).reshape(-1, 2)
    i = AXES.index(axis)
    along, across = counts[:, i], counts[:, 1 - i]
    min_runs = max(min_runs, 2)  # one run has no standard error (it would be NaN in JSON)
    if len(counts) < min_runs:
        raise CpiError(f"{len(counts)} run(s), need at least {min_runs} for a standard error")
    still = np.flatnonzero(along == 0)
    if len(still):
        raise CpiError(
            f"run {run_number(numbers, still[0])}: no counts along {axis} (the mouse did not "
            "move, lost the "
            f"floor, or was pushed along the other axis)"
        )
    per_run, skew = cpi_per_run(along, across, distance, cpi_across, numbers)
    if np.any(skew > MAX_SKEW):
        k = int(np.argmax(skew > MAX_SKEW))
        raise CpiError(
            f"run {run_number(numbers, k)}: the push was {np.degrees(skew[k]):.0f} deg off the "
            f"mouse's {axis} "
            "axis (more than 15): wrong --axis, or the mouse sits askew on the track"
        )
    mean, stderr, off = run_spread(per_run, tolerance)
    warnings = []
    if len(off):
        bad = ", ".join(f"run {run_number(numbers, k)}: {per_run[k]:.1f}" for k in off)
        warnings.append(
            f"runs disagree by more than {tolerance:.0%} (mean {mean:.1f}; {bad}): "
            "check the track length and that the mouse stays on the floor"
        )
    return CpiResult(axis, mean, stderr, len(per_run), per_run, np.degrees(skew), warnings,
                     numbers=[run_number(numbers, k) for k in range(len(per_run))])  # fmt: skip
