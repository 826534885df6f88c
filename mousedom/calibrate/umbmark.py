"""UMBmark (Borenstein & Feng, 1994): systematic odometry error from 4 m squares.

The robot drives a square clockwise and counter-clockwise, several times each; each run
gives the odometry's end position minus the true end position (dx, dy).  For each
direction the centre of gravity of those errors is (mean dx, mean dy), at distance r
from the origin; the measure of systematic error is E_max,syst = max(r_cw, r_ccw).

RUNS.csv has the header ``direction,dx,dy`` (more columns are ignored), one run per line,
direction ``cw`` or ``ccw``, errors in metres.  ``umbmark_row`` makes such a line from a
run with known truth (``mousedom replay`` uses it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from mousedom.calibrate.csvtext import content_lines, fields, finite, header_names
from mousedom.errors import UserError, located

# A RUNS.csv holds a row per run, about a hundred bytes: past this it is not one (read by
# ``mousedom umbmark`` and appended to by ``replay --umbmark-csv``; 10,000 runs fit).
MAX_RUNS_BYTES = 1 << 20

DIRECTIONS = ("cw", "ccw")
HEADER = "direction,dx,dy"
RECOMMENDED_RUNS = 5  # per direction, as Borenstein & Feng do
# Borenstein & Feng's square is 4 m a side.  An end error beyond a side is no odometry's
# on it (it lost the square), and a file whose errors are tens to hundreds "of metres" is
# one in millimetres: 50 mm read as 50 m scores 1,000 times too high (a run of errors
# under 1e4 passed parse_runs' bound without a word).  Warned of, not refused: a broken
# odometry's first runs may really end that far off.
SIDE_M = 4.0


@dataclass(frozen=True)
class Centre:
    x: float
    y: float
    runs: int

    @property
    def r(self) -> float:
        return math.hypot(self.x, self.y)

    def as_json(self) -> dict:
        return {"x": round(self.x, 6), "y": round(self.y, 6), "r": round(self.r, 6)}


@dataclass(frozen=True)
class UmbResult:
    cw: Centre
    ccw: Centre
    warnings: list[str] = field(default_factory=list)

    @property
    def e_max_syst(self) -> float:
        return max(self.cw.r, self.ccw.r)

    def as_json(self) -> dict:
        return {
            "e_max_syst": round(self.e_max_syst, 6),
            "cw": self.cw.as_json(),
            "ccw": self.ccw.as_json(),
        }


def umbmark(directions: Sequence[str], errors: np.ndarray) -> UmbResult:
    """Centres of gravity per direction and E_max,syst from per-run errors (n, 2) metres."""
    errors = np.asarray(errors, dtype=float).reshape(-1, 2)
    dirs = np.asarray(directions)
    if len(dirs) != len(errors):
        raise ValueError("one direction per run")
    centres = {}
    warnings = []
    for d in DIRECTIONS:
        sel = errors[dirs == d]
        if len(sel) == 0:
            raise ValueError(f"no {d} run: UMBmark needs runs in both directions")
        if len(sel) < RECOMMENDED_RUNS:
            warnings.append(
                f"only {len(sel)} {d} run(s); Borenstein & Feng use "
                f"{RECOMMENDED_RUNS} per direction"
            )
        centres[d] = Centre(float(sel[:, 0].mean()), float(sel[:, 1].mean()), len(sel))
    far = np.hypot(errors[:, 0], errors[:, 1])
    if far.size and far.max() > SIDE_M:
        warnings.append(
            f"{int(np.sum(far > SIDE_M))} run(s) end more than {SIDE_M:g} m (the square's "
            f"side) off, up to {far.max():g} m: RUNS.csv is in metres; is it in millimetres?"
        )
    return UmbResult(centres["cw"], centres["ccw"], warnings)


# The largest end error a RUNS.csv row may hold (metres): beyond it a file is not one of
# metres (parse_runs refuses it), and replay writes no such row (umbmark_row).
MAX_END_ERROR_M = 1e4


def umbmark_row(direction: str, final_pose: Sequence[float], true_pose: Sequence[float]) -> str:
    """One RUNS.csv line (no newline): odometry end position minus true end position."""
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be cw or ccw, got {direction!r}")
    dx = float(final_pose[0]) - float(true_pose[0])
    dy = float(final_pose[1]) - float(true_pose[1])
    if not (abs(dx) <= MAX_END_ERROR_M and abs(dy) <= MAX_END_ERROR_M):
        # parse_runs refuses such a row: written, it would spoil the file for every later
        # run and for the score
        raise UserError(
            f"the end error ({dx:g}, {dy:g}) m is beyond {MAX_END_ERROR_M:g} m, which no "
            "UMBmark run has (is the true end in metres?): no row written"
        )
    return f"{direction},{dx:.6f},{dy:.6f}"


def parse_runs(text: str, path: str | None = None) -> tuple[list[str], np.ndarray]:
    """Parse RUNS.csv text; errors name the file, line and column."""
    lines = content_lines(text)
    if not lines:
        raise UserError(located(path, None, f"empty file: expected the header {HEADER}"))
    head_no, head = lines[0]
    names = header_names(head, path, head_no)
    missing = [c for c in ("direction", "dx", "dy") if c not in names]
    if missing:
        raise UserError(
            located(
                path,
                head_no,
                f"header must have the columns {HEADER}; "
                f"missing {', '.join(missing)} (got {head.strip()!r})",
            )
        )
    twice = sorted({c for c in ("direction", "dx", "dy") if names.count(c) > 1})
    if twice:
        raise UserError(
            located(path, head_no, f"column {', '.join(twice)} appears more than once", None)
        )
    col = {c: names.index(c) for c in ("direction", "dx", "dy")}
    directions, errors = [], []
    for no, line in lines[1:]:
        row = fields(line, path, no)
        if len(row) != len(names):
            raise UserError(located(path, no, f"{len(row)} fields, the header has {len(names)}"))
        d = row[col["direction"]].strip().lower()
        if d not in DIRECTIONS:
            raise UserError(located(path, no, f"must be cw or ccw, got {d!r}", "direction"))
        directions.append(d)
        # An end error of a 4 m square: metres, not light years (1e308 printed "inf m").
        errors.append([finite(row[col[c]], path, no, c, MAX_END_ERROR_M) for c in ("dx", "dy")])
    return directions, np.asarray(errors, dtype=float).reshape(-1, 2)
