"""Exact synthetic calibration sessions: a body twist schedule, mice, and their reports.

The twist is piecewise linear in time (moves ramp up and down, pauses between them), so
its integral is known in closed form.  A mouse at p integrates the body-frame velocity of
its point, (U_x - Θ p_y, U_y + Θ p_x), which is exact for any twist; its counts are that,
turned into the mouse's frame, times its true CPI, with optional noise, quantised so that
no count is lost.  ``mousedom.fusion.sim`` is the general simulator; this one is small and exact
for what calibration needs (the reference twist, per-window truth).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mousedom.calibrate.counts import rotate
from mousedom.fusion.units import INCH
from mousedom.sources.base import Reports


@dataclass(frozen=True)
class SynthMouse:
    """A simulated mouse.  Units as in the rig YAML and ``fusion.sim.SimMouse``: metres, and
    the yaw in degrees (turned to radians where the reports are made)."""

    name: str
    x: float
    y: float
    yaw: float = 0.0  # degrees, body x to the mouse's forward
    cpi_x: float = 1000.0  # true CPI
    cpi_y: float = 1000.0
    flip: bool = False
    report_hz: float = 125.0
    phase: float = 0.0  # of a report period
    rel_noise: float = 0.0  # relative error of each report's motion (std)
    abs_noise: float = 0.0  # counts added to each moving report (std)


class Motion:
    """Body twist (vx, vy, omega), linear between knots, zero before and after."""

    def __init__(self, knots_t: np.ndarray, knots_twist: np.ndarray) -> None:
        self.t = np.asarray(knots_t, dtype=float)
        self.v = np.asarray(knots_twist, dtype=float).reshape(-1, 3)
        steps = 0.5 * (self.v[1:] + self.v[:-1]) * np.diff(self.t)[:, None]
        self.cum = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])

    @property
    def end(self) -> float:
        return float(self.t[-1])

    def twist(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.stack([np.interp(t, self.t, self.v[:, j], 0, 0) for j in range(3)], -1)

    def integral(self, t: np.ndarray) -> np.ndarray:
        """(n, 3) cumulative (U_x, U_y, Θ) from the first knot to each t."""
        t = np.clip(np.asarray(t, dtype=float), self.t[0], self.t[-1])
        j = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2)
        tau = (t - self.t[j])[:, None]
        h = (self.t[j + 1] - self.t[j])[:, None]
        slope = np.where(h > 0, (self.v[j + 1] - self.v[j]) / np.where(h > 0, h, 1), 0)
        return self.cum[j] + self.v[j] * tau + 0.5 * slope * tau**2

    def poses(self, t: np.ndarray, dt: float = 1e-3) -> np.ndarray:
        """(n, 3) world poses (x, y, theta) at t, starting at the origin; SE(2) substeps."""
        t = np.asarray(t, dtype=float)
        grid = np.union1d(np.arange(self.t[0], self.t[-1] + dt, dt), t)
        inc = np.diff(self.integral(grid), axis=0)
        a = inc[:, 2]
        small = np.abs(a) < 1e-9
        a_safe = np.where(small, 1.0, a)
        sin_a = np.where(small, 1 - a**2 / 6, np.sin(a) / a_safe)
        cos_a = np.where(small, a / 2, (1 - np.cos(a)) / a_safe)
        step = np.stack(
            [inc[:, 0] * sin_a - inc[:, 1] * cos_a, inc[:, 0] * cos_a + inc[:, 1] * sin_a], -1
        )
        theta = np.concatenate([[0.0], np.cumsum(a)])
        xy = np.concatenate([np.zeros((1, 2)), np.cumsum(rotate(step, theta[:-1]), 0)])
        k = np.searchsorted(grid, t)
        return np.column_stack([xy[k], theta[k]])


def build_motion(
    moves: Sequence[Sequence[float]], ramp: float = 0.1, pause: float = 1.0, start: float = 0.5
) -> Motion:
    """Moves (U_x, U_y, Θ, seconds): each integrates to exactly (U_x, U_y, Θ).

    Each move ramps up over ``ramp`` s, holds, ramps down, and is followed by ``pause``.
    """
    t, v = [0.0], [np.zeros(3)]
    now = start
    for ux, uy, th, seconds in moves:
        if seconds <= 2 * ramp:
            raise ValueError("a move must last longer than two ramps")
        peak = np.array([ux, uy, th]) / (seconds - ramp)
        for dt_, val in (
            (0.0, 0 * peak),
            (ramp, peak),
            (seconds - ramp, peak),
            (seconds, 0 * peak),
        ):
            t.append(now + dt_)
            v.append(val)
        now += seconds + pause
    t.append(now)
    v.append(np.zeros(3))
    return Motion(np.array(t), np.array(v))


def mouse_reports(mouse: SynthMouse, motion: Motion, seed: int | None = 0) -> Reports:
    """The evdev reports of ``mouse`` during ``motion`` (only reports with motion)."""
    rng = np.random.default_rng(seed)
    period = 1.0 / mouse.report_hz
    grid = np.arange(motion.t[0] + mouse.phase * period, motion.end + period, period)
    u = motion.integral(grid)
    body = np.stack([u[:, 0] - u[:, 2] * mouse.y, u[:, 1] + u[:, 2] * mouse.x], -1)
    own = rotate(body, -math.radians(mouse.yaw)) / INCH  # inches: forward, left
    rel_y = -own[:, 0] * mouse.cpi_y
    rel_x = (own[:, 1] if mouse.flip else -own[:, 1]) * mouse.cpi_x
    out = []
    for cum in (rel_x, rel_y):
        inc = np.diff(cum, prepend=cum[0])
        moving = inc != 0
        noisy = inc * (1 + mouse.rel_noise * rng.standard_normal(len(inc)))
        noisy += moving * mouse.abs_noise * rng.standard_normal(len(inc))
        q = np.floor(np.cumsum(noisy) + 0.5)
        out.append(np.diff(q, prepend=0.0))
    dx, dy = out
    keep = (dx != 0) | (dy != 0)
    return Reports(mouse.name, grid[keep], dx[keep], dy[keep])


def true_window_twist(motion: Motion, edges: np.ndarray) -> np.ndarray:
    """(len(edges) - 1, 3) exact integrated twist per window."""
    return np.diff(motion.integral(np.asarray(edges, dtype=float)), axis=0)


def twist_csv(motion: Motion, sample_hz: float = 100.0, t_offset: float = 0.0) -> str:
    """REF.csv text (t,vx,vy,omega) sampled at ``sample_hz`` plus every knot (exact trapezoid)."""
    t = np.unique(
        np.round(np.union1d(np.arange(motion.t[0], motion.end, 1 / sample_hz), motion.t), 6)
    )
    v = motion.twist(t)
    lines = ["t,vx,vy,omega"]
    lines += [
        f"{a + t_offset:.6f},{b:.9g},{c:.9g},{d:.9g}" for a, (b, c, d) in zip(t, v, strict=True)
    ]
    return "\n".join(lines) + "\n"
