"""REF.csv: the reference motion for ``calibrate mounts``, and its twist per window.

Two forms, told apart by the header:

- ``t,vx,vy,omega``: body twist samples (s, m/s, m/s, rad/s) at the body origin.
  Integrated with the trapezoid rule (exact for a twist linear between samples).
- ``t,left,right``: cumulative wheel-encoder ticks of a differential drive.  The McGill
  model turns wheel angle increments (dlambda left, drho right, radians) into
  dC = (drho r_R + dlambda r_L) / 2 along body x and dtheta = (drho r_R - dlambda r_L) / w,
  and a wheeled robot does not slide sideways at its axle (U_y = 0).

Both give, per window, the body twist integrated over it, w = (U_x, U_y, Θ), which is
exactly what the mice integrate.  The reference and the captures share one time base.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mousedom import saferead
from mousedom.calibrate.csvtext import content_lines, fields, finite, header_names
from mousedom.config import WheelsConfig
from mousedom.errors import UserError, located
from mousedom.fusion import models

TWIST = ("t", "vx", "vy", "omega")
WHEELS = ("t", "left", "right")


@dataclass(frozen=True)
class Reference:
    kind: str  # "twist" or "wheels"
    t: np.ndarray
    values: np.ndarray  # (n, 3) vx, vy, omega or (n, 2) left, right ticks
    path: str | None = None


# The config's wheels: section has exactly these fields; one class, not two to keep in step.
WheelGeometry = WheelsConfig


def parse_reference(text: str, path: str | None = None) -> Reference:
    """Parse REF.csv text; every error names the file, line and column."""
    rows = content_lines(text)
    if not rows:
        raise UserError(
            located(
                path, None, "empty reference file: expected a header t,vx,vy,omega or t,left,right"
            )
        )
    head_no, head = rows[0]
    names = header_names(head, path, head_no)
    cols: tuple[str, ...]
    if set(names) == set(TWIST) and len(names) == 4:
        kind, cols = "twist", TWIST
    elif set(names) == set(WHEELS) and len(names) == 3:
        kind, cols = "wheels", WHEELS
    else:
        raise UserError(
            located(
                path,
                head_no,
                "header must be t,vx,vy,omega (body twist) "
                f"or t,left,right (wheel ticks), got {head.strip()!r}",
            )
        )
    order = [names.index(c) for c in cols]
    data = np.empty((len(rows) - 1, len(cols)))
    for k, (no, line) in enumerate(rows[1:]):
        row = fields(line, path, no)
        if len(row) != len(names):
            raise UserError(located(path, no, f"{len(row)} fields, the header has {len(names)}"))
        for j, c in enumerate(cols):
            data[k, j] = finite(row[order[j]], path, no, c)
        if k and data[k, 0] <= data[k - 1, 0]:
            raise UserError(
                located(
                    path,
                    no,
                    f"time {data[k, 0]} does not increase (previous {data[k - 1, 0]})",
                    "t",
                )
            )
    if len(data) < 2:
        raise UserError(located(path, None, f"{len(data)} sample(s), need at least 2"))
    return Reference(kind, data[:, 0], data[:, 1:], path)


def read_reference(path: str) -> Reference:
    try:
        text = saferead.read_text(path)
    except FileNotFoundError:
        raise UserError(f"{path}: reference file not found") from None
    except UnicodeDecodeError as e:
        raise UserError(f"{path}: byte offset {e.start}: not UTF-8 text") from None
    except OSError as e:
        raise UserError(f"{path}: cannot read: {e.strerror}") from None
    return parse_reference(text, path)


def _cumulative_twist(ref: Reference) -> np.ndarray:
    dt = np.diff(ref.t)[:, None]
    steps = 0.5 * (ref.values[1:] + ref.values[:-1]) * dt
    return np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


def wheel_twist(d_left: np.ndarray, d_right: np.ndarray, geo: WheelGeometry) -> np.ndarray:
    """McGill: wheel angle increments (rad) -> (n, 3) integrated twist (dC, 0, dtheta)."""
    return models.wheels(d_left, d_right, geo.radius_left, geo.radius_right, geo.track).q


def window_twist(ref: Reference, edges: np.ndarray, geo: WheelGeometry | None = None) -> np.ndarray:
    """(len(edges) - 1, 3) body twist integrated over each window (edges[k], edges[k+1]]."""
    edges = np.asarray(edges, dtype=float)
    if ref.kind == "twist":
        cum = _cumulative_twist(ref)
        at = np.stack([np.interp(edges, ref.t, cum[:, j]) for j in range(3)], axis=-1)
        return np.diff(at, axis=0)
    if geo is None:
        raise UserError(
            "a wheel-tick reference needs the wheel geometry: --wheel-radius, "
            "--ticks-per-rev and --track, or a wheels: section in the config"
        )
    ticks = np.stack([np.interp(edges, ref.t, ref.values[:, j]) for j in range(2)], axis=-1)
    angles = np.diff(ticks, axis=0) * (2 * math.pi / geo.ticks_per_rev)
    return wheel_twist(angles[:, 0], angles[:, 1], geo)


def check_coverage(ref: Reference, t0: float, t1: float, slack: float) -> None:
    """Raise when motion at [t0, t1] lies outside the reference's time span."""
    if t0 < ref.t[0] - slack or t1 > ref.t[-1] + slack:
        raise UserError(
            located(
                ref.path,
                None,
                f"covers t = {ref.t[0]:.3f} .. {ref.t[-1]:.3f} s but the mice "
                f"moved at t = {t0:.3f} .. {t1:.3f} s: the reference and the "
                "captures must share one time base and cover every run",
            )
        )
