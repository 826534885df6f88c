"""The linear map from body twist to mouse displacements, and its rank.

Over a window with constant body twist q = (u_x, u_y, dtheta), a sensor at body
position p = (p_x, p_y) moves, in body axes, by (u_x - dtheta p_y, u_y + dtheta p_x):
Kim & Lee eq. (6), with displacements in place of velocities.  Stacking the mice gives
d = A q with A of shape (2N, 3).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def design_matrix(positions: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
    """A (2N x 3) for mice at ``positions`` (N x 2, metres, body frame); rows x1, y1, x2..."""
    p = np.asarray(positions, dtype=float).reshape(-1, 2)
    a = np.zeros((2 * len(p), 3))
    a[0::2, 0] = 1.0
    a[0::2, 2] = -p[:, 1]
    a[1::2, 1] = 1.0
    a[1::2, 2] = p[:, 0]
    return a


def _rank(a: np.ndarray) -> int:
    if a.size == 0:
        return 0
    s = np.linalg.svd(a, compute_uv=False)
    return int(np.sum(s > 1e-9 * max(1.0, s[0])))


def rank_problem(
    model: str, positions: Sequence[Sequence[float]], names: Sequence[str]
) -> str | None:
    """Why ``model`` cannot recover the twist from mice at ``positions``, or None.

    The message names the mice at fault so the user knows which mount to fix.
    """
    p = np.asarray(positions, dtype=float).reshape(-1, 2)
    listed = ", ".join(names)
    if model == "lsq":
        if len(p) < 2:
            return f"needs at least two mice, has {len(p)} ({listed}); one mouse needs diff-drive"
        if _rank(design_matrix(p)) < 3:
            return f"mice {listed} are all at one point, so rotation cannot be told from sliding"
        return None
    if model == "bonarini":
        if len(p) != 2:
            return f"takes exactly two mice, has {len(p)} ({listed})"
        if np.allclose(p[0], p[1]):
            return f"mice {listed} are at one point; they must be apart (distance D > 0)"
        return None
    if model == "diff-drive":
        reduced = design_matrix(p)[:, [0, 2]]
        if _rank(reduced) < 2:
            return (
                f"mice {listed} cannot see rotation: a differential-drive rig needs a mouse "
                "ahead of or behind the axle (mount x != 0), or two mice apart along y"
            )
        return None
    return f"unknown model {model!r}"
