"""Counts to metres, in the mouse's own frame and in the body frame.

The conversion itself is ``mousedom.fusion.units`` (one convention for the whole program); this
adds the mouse's own frame (forward, left), which the exact mount fit needs because it
estimates the mount yaw itself, and a CPI override for freshly calibrated values.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mousedom.config import MouseConfig
from mousedom.fusion.units import INCH, counts_to_body

__all__ = ["INCH", "body_frame", "mouse_frame", "rotate"]


def rotate(v: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Rotate (..., 2) vectors counter-clockwise by ``angle`` radians."""
    v = np.asarray(v, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def body_frame(
    mouse: MouseConfig,
    dx: np.ndarray | float,
    dy: np.ndarray | float,
    cpi: tuple[float, float] | None = None,
) -> np.ndarray:
    """(..., 2) body-frame metres from REL_X, REL_Y counts; ``cpi`` = (x, y) overrides."""
    if cpi is not None:
        mouse = replace(mouse, cpi_x=float(cpi[0]), cpi_y=float(cpi[1]))
    bx, by = counts_to_body(mouse, dx, dy)
    return np.stack([bx, by], axis=-1)


def mouse_frame(
    mouse: MouseConfig,
    dx: np.ndarray | float,
    dy: np.ndarray | float,
    cpi: tuple[float, float] | None = None,
) -> np.ndarray:
    """(..., 2) metres (forward, left) in the mouse's own frame: the mount yaw undone."""
    return rotate(body_frame(mouse, dx, dy, cpi), -mouse.mount.yaw)
