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

Three or more mice check each one against the others (2N - k >= 3), unless they lie near
one line.  Then in any motion across the line (a pivot about a point of it, a drive across
it) every mouse moves across it, by a linear function of its place along it: a fault breaks
that and is seen, but any two mice are consistent on their own, so which one is at fault is
told only once the robot moves along the line (where a lifted mouse reads nothing of what
the others read alike), and a wrong choice holds (the two left check each other only along
their line).  A review's random
lines of three, 2 cm off a line 30 cm long, middle mouse lifted for 3 s from a turn on the
spot: a healthy end mouse excluded in 8 of 20 drives, ends metres off.  "Near" as for two
mice: every mouse within the test's tolerance (``across_tolerance``) of the line, over the
line's length.
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
    if len(mice) >= 3:
        return _near_a_line(mice, across_tolerance(relative_noise, false_alarm))
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


def _near_a_line(mice: Sequence[tuple[str, float, float]], tol: float) -> list[str]:
    """Three or more mice within ``tol`` of the length of the line that fits them best (the
    module docstring): the note, else none."""
    n = len(mice)
    cx = sum(m[1] for m in mice) / n
    cy = sum(m[2] for m in mice) / n
    sxx = sum((m[1] - cx) ** 2 for m in mice)
    syy = sum((m[2] - cy) ** 2 for m in mice)
    sxy = sum((m[1] - cx) * (m[2] - cy) for m in mice)
    angle = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # the line's direction (principal axis)
    ux, uy = math.cos(angle), math.sin(angle)
    along = [(m[1] - cx) * ux + (m[2] - cy) * uy for m in mice]
    across = [abs(-(m[1] - cx) * uy + (m[2] - cy) * ux) for m in mice]
    length = max(along) - min(along)
    if length <= 0.0 or max(across) > tol * length:
        return []
    names = ", ".join(m[0] for m in mice)
    return [
        f"mice {names} lie near one line (each within {max(across) * 1000:.0f} mm of it over "
        f"{length * 1000:.0f} mm): in any motion across the line any two of them agree on "
        "their own, so a fault is seen but which mouse it is is told only once the robot "
        "moves along the line; a healthy mouse can be excluded in a lifted one's place (the "
        "pose then far off); a mouse well off the line tells them apart"
    ]
