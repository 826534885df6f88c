"""Counts to metres: in the mouse's own frame, and in the body frame.

evdev convention (DESIGN.md): REL_X + = the mouse moved to its right, REL_Y + = it moved
backwards.  So in the mouse's own frame (x toward its buttons, y to its left)
forward = -REL_Y / cpi_y and left = -REL_X / cpi_x (inches); a mirrored sensor
(``flip``) has REL_X pointing left, so left = +REL_X / cpi_x.  The body frame is the
mouse frame turned by the mount yaw.
"""

from __future__ import annotations

import numpy as np

from mousedom.config import MouseConfig

INCH = 0.0254  # metres


def mouse_frame(
    mouse: MouseConfig,
    dx: np.ndarray | float,
    dy: np.ndarray | float,
    cpi: tuple[float, float] | None = None,
) -> np.ndarray:
    """(..., 2) metres (forward, left) in the mouse's own frame from REL_X, REL_Y counts.

    ``cpi`` = (cpi_x, cpi_y) overrides the configured values (e.g. freshly calibrated).
    """
    cx, cy = cpi if cpi is not None else (mouse.cpi_x, mouse.cpi_y)
    dx = np.asarray(dx, dtype=float)
    dy = np.asarray(dy, dtype=float)
    left = (dx if mouse.flip else -dx) * INCH / cx
    forward = -dy * INCH / cy
    return np.stack([forward, left], axis=-1)


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
    """(..., 2) metres in the body frame: the mouse frame turned by the mount yaw."""
    return rotate(mouse_frame(mouse, dx, dy, cpi), mouse.mount.yaw)
