"""The screen's common case for one window on floats, as a pure function (``Screen.fast_one``
holds the state and applies what this returns).

Every live mouse is tracking, the rest missing: the window is accepted when no mouse moved
beyond its speed and the consistency statistic (each live mouse's squared residual from the
rigid prediction over its noise model's variance, summed) is within the chi-square
threshold for its degrees of freedom (docs/models.md, "Faults").  Accepted, each mouse that
moved gives its noise model a sample of each factor whose part of the variance is large
enough to tell (``NoiseModel.sample``).

In the compiled core where it is built (csrc/steady.c, issue 28); this is its
specification, and tests/test_core_window.py holds the two equal bit for bit.
"""

from __future__ import annotations

from typing import NamedTuple

from mousedom import core
from mousedom.fusion.noisemodel import _MEDIAN_CHI2_2, sample_values
from mousedom.fusion.shortfall import others_word, reads_short


class Rig(NamedTuple):
    """What the test needs of the rig and of the noise model as they are now, per mouse
    (lists of floats; ``prev``: the rigid prediction of each mouse's motion in the
    previous window)."""

    xy: list[list[float]]  # each mouse's position on the body (m)
    max2: list[float]  # the squared step beyond which a mouse is saturated
    prev: list[list[float]]
    floor: list[float]  # the variance's floor, lam_f * sig2
    rho2: list[float]  # its part proportional to the squared step, lam_r * rho2
    gran2: list[float]  # its part from the change of motion, lam_r * gran2
    sig2: list[float]  # a mouse moved when its squared step is above this
    lam_r: list[float]


# The accepted window: each mouse's predicted motion (the next window's ``prev``), the
# noise model's samples as (mouse, value): floor factors, then proportional ones, and which
# live mice the solve moved beyond their sigma (each read in full: its shortfall's sum
# starts again).
Accepted = tuple[list[list[float]], list[tuple[int, float]], list[tuple[int, float]], list[bool]]


def steady_window(
    d: list[float], q: list[float], live: tuple[bool, ...], rig: Rig, threshold: float,
    dof: int, leverage: list[float] | None, gains: list[list[float]],
    spans: list[float] | None = None,
) -> Accepted | None:  # fmt: skip
    """The window with body-frame displacements ``d`` (x1, y1, x2, ...) and solved twist
    ``q`` (ux, uy, a) of the ``live`` mice: None where the screen must decide (a mouse
    saturated, the statistic over ``threshold`` with ``dof`` > 0 degrees of freedom, or a
    mouse short of its motion), else what it gives (``Accepted``).  ``leverage``: each
    mouse's hat-matrix block trace under this live pattern (None where dof <= 0: no sample
    is taken then); ``gains``: ``RigidTest.others_gain_list``'s under it.

    ``spans``: each mouse's long report span the window's edges cut (> 0), or None where
    they cut none; ``rig.gran2`` then holds the coefficients for them
    (``NoiseModel.f_gran2_for``).  A cut mouse's change of motion is taken from what the
    others moved it (``others_word``, as ``Screen._span_p``): where they cannot place it
    (its gains all zero), None: decide, which solves without it."""
    native = core.native
    if native is not None:
        done = native.steady_window(d, q, live, rig, threshold, dof, leverage, gains, spans,
                                    _MEDIAN_CHI2_2)  # fmt: skip
        if done is not False:  # False: declined (the types); None: decide
            return done
    ux, uy, a = q
    terms = []
    total = 0.0
    for i, (x, y) in enumerate(rig.xy):
        if not live[i]:
            continue
        px, py = ux - a * y, uy + a * x
        dx, dy = d[2 * i], d[2 * i + 1]
        m2 = max(dx * dx + dy * dy, px * px + py * py)
        if m2 >= rig.max2[i]:
            return None  # saturated: decide
        if spans is not None and spans[i] > 0:
            g0, g1, g2, g3 = gains[i]
            if not (g0 or g1 or g2 or g3):
                return None  # the others cannot place it: decide (the solve without it)
            ox, oy = others_word(dx, dy, px, py, gains[i])
            fx, fy = ox - rig.prev[i][0], oy - rig.prev[i][1]
        else:
            fx, fy = px - rig.prev[i][0], py - rig.prev[i][1]
        floor = rig.floor[i]
        prop = rig.rho2[i] * m2 + rig.gran2[i] * (fx * fx + fy * fy)
        rx, ry = dx - px, dy - py
        r2 = rx * rx + ry * ry
        total += r2 / (floor + prop)
        terms.append((i, r2, floor, prop, m2))
    if dof > 0 and total > threshold:
        return None
    by_floor: list[tuple[int, float]] = []
    by_prop: list[tuple[int, float]] = []
    if dof > 0 and leverage is not None:
        for i, r2, floor, prop, m2 in terms:
            if m2 > rig.sig2[i]:
                by_f, by_p = sample_values(r2, floor, prop, leverage[i], rig.sig2[i], rig.lam_r[i])
                if by_f is not None:
                    by_floor.append((i, by_f))
                if by_p is not None:
                    by_prop.append((i, by_p))
    p = [[ux - a * y, uy + a * x] for x, y in rig.xy]
    heard = [live[i] and px * px + py * py > rig.sig2[i] for i, (px, py) in enumerate(p)]
    if any(reads_short(d, p, gains, heard, live)):
        return None  # short of its motion: decide (the screen's shortfall)
    return p, by_floor, by_prop, heard
