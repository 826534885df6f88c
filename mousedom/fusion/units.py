"""Counts in, metres in the body frame out.

A mouse reports (REL_X, REL_Y) counts in its own frame: REL_X + means it moved to its
right, REL_Y + that it moved backwards (toward its user).  So in the mouse's frame
forward = -REL_Y and left = -REL_X; a mirrored sensor (``flip``) has left = +REL_X.
Counts become metres with the calibrated CPI of each axis (one inch is 0.0254 m), and the
mount yaw rotates the mouse frame into the body frame (REP-103: x forward, y left).

Everything is one constant 2x2 matrix per mouse, so converting millions of reports is a
single matrix product.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from mousedom.config import MouseConfig

INCH = 0.0254  # metres


def counts_matrix(mouse: MouseConfig) -> np.ndarray:
    """2x2 matrix M with body_metres = M @ (REL_X, REL_Y) for this mouse."""
    sx = INCH / mouse.cpi_x
    sy = INCH / mouse.cpi_y
    left_per_relx = sx if mouse.flip else -sx
    # Mouse frame: [forward, left] = [[0, -sy], [left_per_relx, 0]] @ [REL_X, REL_Y].
    to_mouse = np.array([[0.0, -sy], [left_per_relx, 0.0]])
    c, s = math.cos(mouse.mount.yaw), math.sin(mouse.mount.yaw)
    return np.array([[c, -s], [s, c]]) @ to_mouse


def counts_matrices(mice: Sequence[MouseConfig]) -> np.ndarray:
    """(N, 2, 2) stack of counts_matrix for a rig."""
    return np.stack([counts_matrix(m) for m in mice]) if mice else np.zeros((0, 2, 2))


def counts_to_body(
    mouse: MouseConfig, dx: np.ndarray | float, dy: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame displacement (metres) of the sensor for REL_X/REL_Y counts."""
    m = counts_matrix(mouse)
    dx = np.asarray(dx, dtype=float)
    dy = np.asarray(dy, dtype=float)
    return m[0, 0] * dx + m[0, 1] * dy, m[1, 0] * dx + m[1, 1] * dy


def body_to_counts(
    mouse: MouseConfig, bx: np.ndarray | float, by: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """The inverse: the REL_X/REL_Y counts (unrounded) a body-frame displacement gives."""
    m = np.linalg.inv(counts_matrix(mouse))
    bx = np.asarray(bx, dtype=float)
    by = np.asarray(by, dtype=float)
    return m[0, 0] * bx + m[0, 1] * by, m[1, 0] * bx + m[1, 1] * by


def sigma_metres(mouse: MouseConfig) -> float:
    """The mouse's per-axis noise (config ``sigma``, counts) in metres, one for both axes:
    the root mean square of the two axes' (sigma / cpi each), so that the two variances'
    sum is the true one.  At the mean CPI, a mouse of 400 by 1600 CPI was given 51 um on
    both axes where REL_X errs by 127 um: an end pose's NEES of 9-11 on rigs whose
    covariance comes from the config (one or two mice); now 2.7-3.4 there.  One sigma for
    both axes cannot follow each error's direction, so it is still wrong where the
    directions matter: eight mice of 400 by 1600 CPI facing out from the centre gave a NEES
    of 4.8, of 1600 by 400 0.96 (a 2x2 noise per mouse would reach the solve, the noise
    model and the compiled core).  Equal CPIs: unchanged."""
    sx, sy = INCH / mouse.cpi_x, INCH / mouse.cpi_y
    return mouse.sigma * math.sqrt(0.5 * (sx * sx + sy * sy))
