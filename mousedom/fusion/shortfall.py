"""Whether a mouse reads short of its motion: the shortfall's rule (docs/models.md, "A mouse
short of its motion"), on floats, one window at a time.

``robust.Screen`` sums what a mouse that reads short missed (module step 1b), the common
case (``steady.steady_window``) leaves a window with one to the decision, and replay's
batch (``screenbatch._fast_rows``) holds the same rule on arrays.  In the compiled core
where it is built (csrc/steady.c, inside the common case); this is its specification.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

# A mouse reads short of its motion (``reads_short``, robust.Screen._quiet_blame) where it reads
# less than SHORT_ALONE of the solve with it (a lift reads nothing or noise), or less than
# SHORT of what the others moved it (the solve without it) and SHORT_OF_ALL of the solve
# with it, along it.  The first rule alone missed under-reads: the solve with the mouse
# bends towards it, and one reading half beside two healthy ones read three quarters of
# it.  Where an under-read's first windows passed the test, the noise model then learnt
# them as noise and the fault was never found (an offset ring's mouse reading half for 3 s
# on a healthy rig: 553 mm off at the end, told the fault 6.9 mm).  The others' word is
# bent where one of them is the faulty one: healthy mice beside a lift read short of it
# too, and were held out (1-7 m off at the end), which the solve with every mouse, read in
# full, tells; and beside a mouse reading 44 % more, a healthy one read short of both (a
# drive 0.93 m off, told 5 mm): the others' word on the faulty mouse is not bent by it, on
# the others it is, so only the mouse that reads the most out of proportion to the
# others' word counts, and only where it reads short.  What a mouse must read to count as
# sound again (readmission.Readmission.waiting) is SHORT of what the others moved it.
SHORT = 0.75
SHORT_OF_ALL = 0.9
SHORT_ALONE = 0.25


def others_word(
    dx: float, dy: float, px: float, py: float, gain: Sequence[float]
) -> tuple[float, float]:
    """What the others moved a used mouse (the solve without it: ``d - gain (d - p)``,
    block deletion) from its reading (dx, dy), the prediction with it (px, py) and its
    ``others_gain_list`` row (m00, m01, m10, m11; meaningless where all zero)."""
    g0, g1, g2, g3 = gain
    rx, ry = dx - px, dy - py
    return dx - (g0 * rx + g1 * ry), dy - (g2 * rx + g3 * ry)


def reads_short(
    d: Sequence[float], p: Sequence[Sequence[float]], gains: Sequence[Sequence[float]],
    considered: Sequence[bool], used: Sequence[bool],
) -> list[bool]:  # fmt: skip
    """Which of the ``considered`` mice (live, and moved beyond their sigma) read short of
    their motion (SHORT, above).  ``d``: the readings flattened (x1, y1, x2, ...); ``p``:
    the solve's predictions (N, 2), of the ``used`` mice; ``gains``: ``others_gain_list``'s
    rows (m00, m01, m10, m11), with which a used mouse's residual becomes its residual
    under the others (all zero: they cannot place it).  A mouse reads short where it reads
    less than SHORT_ALONE of the solve (for a mouse not used, that is the others' word);
    or, used, less than SHORT of what the others moved it and SHORT_OF_ALL of the solve
    with it, where of the mice the others place it reads the most out of proportion to
    their word (its ratio to that word, or that ratio's inverse, the largest; a reading
    of nothing or against it, infinite).  screenbatch._fast_rows holds the same rule on
    arrays."""
    n = len(gains)
    alone = [False] * n
    odd, odd_by, odd_short = -1, 0.0, False
    for i in range(n):
        if not considered[i]:
            continue
        dx, dy = d[2 * i], d[2 * i + 1]
        px, py = p[i]
        along, p2 = dx * px + dy * py, px * px + py * py
        alone[i] = along < SHORT_ALONE * p2
        g0, g1, g2, g3 = gains[i]
        if not used[i] or not (g0 or g1 or g2 or g3):
            continue
        ox, oy = others_word(dx, dy, px, py, gains[i])
        o2 = ox * ox + oy * oy
        if not o2 > 0.0:
            continue
        ratio = (dx * ox + dy * oy) / o2
        by = max(ratio, 1.0 / ratio) if ratio > 0.0 else math.inf
        if by > odd_by:
            odd, odd_by = i, by
            odd_short = ratio < SHORT and along < SHORT_OF_ALL * p2
    if odd_short:
        alone[odd] = True
    return alone
