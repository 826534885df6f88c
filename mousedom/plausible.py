"""Values that parse but look like the wrong unit: warnings, not errors.

A mount of ``{y: 135}`` is a valid number of metres; so is a yaw of ``3.14`` degrees and a
CPI of 31496.  Each is far more likely millimetres, radians or counts per metre.  These
checks say so, with the value as read and the value probably meant, and leave the config
as it is (a rig may really be that large).  ``check-config`` prints them, the daemon logs
them at start and reload.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

MAX_MOUNT_M = 2.0  # no mouse sits further than this from a robot's reference point
CPI_RANGE = (100.0, 30000.0)  # what optical mice and sensors report


@dataclass(frozen=True)
class Suspect:
    keys: tuple[str, ...]  # where in the file: ("mice", "left", "mount", "y")
    message: str


def suspects(mice: list[tuple[str, float, float, float, float, float]]) -> list[Suspect]:
    """For each mouse (name, cpi x, cpi y, mount x, mount y, yaw in degrees as written):
    the values that look like another unit."""
    out = []
    for name, cx, cy, x, y, yaw_deg in mice:
        for key, v in (("x", x), ("y", y)):
            if abs(v) > MAX_MOUNT_M:
                out.append(Suspect(("mice", name, "mount", key),
                                   f"{v:g} m from the body origin: if that is millimetres, "
                                   f"{v / 1000:g} m (mounts are in metres)"))  # fmt: skip
        if abs(yaw_deg) > 360.0:  # (1e30 was taken without a word)
            out.append(Suspect(("mice", name, "mount", "yaw"),
                               f"{yaw_deg:g} degrees is more than a turn (yaw is in "
                               "degrees, -180 to 180)"))  # fmt: skip
        elif 0 < abs(yaw_deg) <= 2 * math.pi and yaw_deg != round(yaw_deg):
            meant = math.degrees(yaw_deg)
            out.append(Suspect(("mice", name, "mount", "yaw"),
                               f"{yaw_deg:g} is read as degrees; if it is radians, that is "
                               f"{meant:.4g} degrees (yaw is in degrees)"))  # fmt: skip
        for key, v in (("cpi", cx),) if cx == cy else (("cpi.x", cx), ("cpi.y", cy)):
            problem = cpi_problem(v)
            if problem:
                out.append(Suspect(("mice", name, *key.split(".")), problem))
    return out


def cpi_problem(v: float) -> str | None:
    """Why ``v`` counts per inch is not what a mouse reports (with the unit it may be in),
    or None.  A warning in a config (a new sensor may go beyond the range); a calibration
    result outside it is not stored without --force (it comes from bad runs or data)."""
    lo, hi = CPI_RANGE
    if lo <= v <= hi:
        return None
    hint = ""
    if v > hi:
        hint = f"; if that is counts per metre, {v * 0.0254:.0f} CPI"
    elif v * 25.4 >= lo and v < lo:
        hint = f"; if that is counts per millimetre, {v * 25.4:.0f} CPI"
    return f"{v:g} counts per inch is outside {lo:g}-{hi:g}, what mice report{hint}"


def format_all(items: list[Suspect], where: Callable[[tuple[str, ...]], str]) -> list[str]:
    """The warnings as lines, each ``where(keys): message``."""
    return [f"{where(s.keys)}: {s.message}" for s in items]
