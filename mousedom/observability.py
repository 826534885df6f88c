"""What a rig's layout lets the fault test see, and what it cannot (``check-config`` notes).

Mouse i at mount r_i = (x_i, y_i) reads, over a window whose twist increment is
q = (u_x, u_y, a) (docs/models.md, "The unified model"),

    d_i = u + a J r_i,    J = [[0, -1], [1, 0]]  (a quarter turn).

N mice give 2N readings of k unknowns (k = 3 for ``lsq`` and ``bonarini``; 2 for
``diff-drive``, where u_y = 0), so the residual has 2N - k degrees of freedom: the redundant
readings, all the fault test has to go on.

One mouse: 2 readings, 2 unknowns (``lsq`` needs two mice at all): no redundancy.  Nothing in
the readings can show a fault; only the sensor itself can (an ADNS-3080's SQUAL and overflow
flag, ``min_squal``, ``max_speed``).

Two mice: d_i - d_j = a J (r_i - r_j) is perpendicular to r_i - r_j, so with e the unit
vector along the line joining them, e . d_i = e . d_j is the one redundant reading of
``lsq`` and ``bonarini`` (4 - 3 = 1); ``diff-drive`` adds u_y = 0, the axle not sliding
sideways (4 - 2 = 2).  A fault shows only as a breach of these, and nothing tells which of
the two mice broke it.

A lifted mouse j reads 0.  The readings (d_i, 0) are themselves a legal motion, a pivot about
r_j with a' J (r_i - r_j) = d_i, exactly when d_i is perpendicular to e, that is (e . d_i =
e . d_j) when j's true motion is perpendicular to the joining line: then the lift cannot be
seen.  A pair on a line across the direction of travel (e along body y) hides a lift whenever
the robot drives straight.  Under ``diff-drive`` a pivot about r_j is legal only if x_j = 0
(its u_y = -a' x_j), and every motion of a differential drive moves the points of the axle
(x = 0) along x: a pair on the axle hides a lift in every motion.

Nearly so is as blind.  The lift's disagreement along the line is |d| cos(phi), phi the
angle between the motion and the line, and the test expects errors of about rho |d| a mouse
(``robust.relative_noise``) and flags beyond sqrt(chi2_{1-alpha}(1)) of them (alpha
``robust.false_alarm``): a line within asin(rho sqrt(chi2_{1-alpha}(1))) of the perpendicular
(11 degrees with the defaults; on the simulator, at 10 degrees half the lifted windows were
flagged, at 15 all) hides a lift as well.  For the axle of a differential drive the sideways
check is sharper: mice 2 % of their distance off the axle hid a lift, 4 % did not.

Three or more mice check each one against the others (2N - k >= 3): no note.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

AXLE_TOLERANCE = 0.02  # |x| of both mice, over their distance, for "on the axle" (diff-drive)


def across_tolerance(relative_noise: float, false_alarm: float) -> float:
    """The largest |cos| of the angle between the direction of travel (body x) and a two-
    mouse line at which a lift still hides in the noise: rho sqrt(chi2_{1-alpha}(1))."""
    from mousedom.fusion import chi2

    return min(1.0, relative_noise * math.sqrt(chi2.quantile(1.0 - false_alarm, 1)))


def blind_spots(
    model: str,
    mice: Sequence[tuple[str, float, float]],
    relative_noise: float = 0.05,
    false_alarm: float = 1e-4,
) -> list[str]:
    """What the fault test of a rig of ``mice`` (name, mount x, mount y in metres) under
    ``model`` cannot see, one sentence each (see the module's docstring for the maths);
    empty for three or more mice."""
    unknowns = 2 if model == "diff-drive" else 3
    if len(mice) == 1:
        name = mice[0][0]
        return [
            f"mouse {name} alone: no redundant reading (2 readings, 2 unknowns), so no fault "
            "shows in the readings; only the sensor itself can flag one (an ADNS-3080's SQUAL "
            "and overflow, min_squal, max_speed)"
        ]
    if len(mice) != 2:
        return []
    (a, xa, ya), (b, xb, yb) = mice
    both = f"mice {a} and {b}"
    dist = math.hypot(xa - xb, ya - yb)
    if dist < 1e-9:  # only diff-drive takes two mice at one point
        return [
            f"{both} sit at one point: their readings must be equal; a fault shows only as a "
            "difference, and which of the two is at fault cannot be told"
        ]
    redundant = 4 - unknowns
    checks = "their motion along the line joining them must agree"
    if model == "diff-drive":
        checks += " and the axle must not slide sideways; a fault shows only as a breach of these"
    else:
        checks += (
            "; a fault shows only as a disagreement along that line (a lifted mouse only while "
            "it moves along it)"
        )
    notes = [
        f"{both}: {redundant} redundant reading{'s' if redundant > 1 else ''} (4 readings, "
        f"{unknowns} unknowns): {checks}, and which of the two is at fault cannot be told"
    ]
    if model == "diff-drive":
        if max(abs(xa), abs(xb)) <= AXLE_TOLERANCE * dist:
            notes.append(
                f"{both} are both on the axle (x = 0): every motion of a differential drive "
                "moves them across the line joining them, so a lifted mouse reads as a pivot "
                "about the other, a legal motion: a lift is never detected (a mouse off the "
                "axle would see it)"
            )
        return notes
    tol = across_tolerance(relative_noise, false_alarm)
    if abs(xa - xb) <= tol * dist:
        notes.append(
            f"{both} lie on a line across the direction of travel (within "
            f"{math.degrees(math.asin(tol)):.0f} degrees): while the robot drives straight, a "
            "lifted mouse reads as a pivot about the other, a legal motion, so a lift is not "
            "detected (on a differential drive's axle, never)"
        )
    return notes
