"""The one way a heading is shown: degrees wrapped to (-180, 180].

The daemon's theta is continuous (radians, counting whole turns: +7.85 rad is a quarter
turn past a full one), which integrators and tests need; a person reading a heading wants
where the robot faces.  ``mousedom watch``, ``mousedom replay``'s summary and
``mousedom.client.Pose.heading_deg`` all show it through :func:`wrap_degrees`, so one
pose reads the same in each.
"""

from __future__ import annotations

import math


def wrap_degrees(rad: float) -> float:
    """Radians -> degrees in (-180, 180] (-180 shows as +180; nan stays nan)."""
    d = math.degrees(rad) % 360.0
    return d - 360.0 if d > 180.0 else d
