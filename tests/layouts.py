"""Random rig layouts for the generated tests (one definition: the same draws whichever
test asks)."""

from __future__ import annotations

import math

import numpy as np


def random_layout(rng: np.random.Generator, n: int, kind: str) -> np.ndarray:
    """n mice' (x, y) of a rig of ``kind``: "ring", "scatter", "bunched" (most close
    together, one far) or "near-line" (along a line, small offsets across it); none
    closer than 4 cm.  The generated sweeps' layouts (tests/test_stall_catchup.py,
    tests/test_scale_one_axis.py draw from the same stream)."""
    while True:
        if kind == "ring":
            r = rng.uniform(0.05, 0.25)
            a0 = rng.uniform(0, 2 * math.pi)
            ang = a0 + 2 * math.pi * np.arange(n) / n + rng.uniform(-0.3, 0.3, n)
            c = rng.uniform(-0.15, 0.15, 2)
            xy = np.c_[c[0] + r * np.cos(ang), c[1] + r * np.sin(ang)]
        elif kind == "scatter":
            xy = rng.uniform(-0.25, 0.25, (n, 2))
        elif kind == "bunched":  # most bunched, one far
            xy = rng.uniform(-0.08, 0.08, (n, 2))
            xy[0] += rng.uniform(0.2, 0.4) * np.array([1.0, rng.uniform(-0.5, 0.5)])
        else:  # near-line
            ang = rng.uniform(0, math.pi)
            along = np.sort(rng.uniform(-0.25, 0.25, n))
            across = rng.uniform(-0.015, 0.015, n)
            u = np.array([math.cos(ang), math.sin(ang)])
            v = np.array([-u[1], u[0]])
            c = rng.uniform(-0.1, 0.1, 2)
            xy = c + along[:, None] * u + across[:, None] * v
        d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
        d[np.diag_indices(n)] = 1.0
        if d.min() >= 0.04:
            return xy
