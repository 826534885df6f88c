"""Readable reports and JSON documents of calibration results (strings only, no I/O)."""

from __future__ import annotations

import math

import numpy as np

from mousedom.calibrate.cpi import CpiResult
from mousedom.calibrate.distance import DistanceResult
from mousedom.calibrate.mounts import MountFit
from mousedom.calibrate.session import MountsResult
from mousedom.calibrate.umbmark import UmbResult
from mousedom.config import Config


def _per_run(values: list[str], numbers: list[int]) -> str:
    """Each run's figure; with its number in the session where runs were left out (a
    bump), so that the list and the warnings number the runs alike."""
    if not numbers or numbers == list(range(1, len(values) + 1)):
        return ", ".join(values)
    return ", ".join(f"run {k}: {v}" for k, v in zip(numbers, values, strict=True))


def cpi_text(results: dict[str, CpiResult], config: Config, distance: float) -> list[str]:
    lines = []
    for name, r in results.items():
        m = config.mouse(name)
        before = m.cpi_y if r.axis == "y" else m.cpi_x
        lines.append(
            f"{name}: cpi {r.axis} = {r.cpi:.2f} +- {r.stderr:.2f} from {r.runs} pushes of "
            f"{distance * 1000:g} mm (configured {before:g}, {r.cpi / before - 1:+.2%})"
        )
        per = _per_run([f"{c:.1f}" for c in r.per_run], r.numbers)
        lines.append(f"  per run: {per}")
        if np.max(r.skew_deg) >= 1.0:
            lines.append(
                f"  pushes were up to {np.max(r.skew_deg):.1f} deg off the mouse's "
                "axis (corrected with the counts across it)"
            )
    return lines


def distance_text(r: DistanceResult, names: list[str], angle_deg: float) -> list[str]:
    per = _per_run([f"{d * 1000:.2f}" for d in r.per_run], r.numbers)
    return [
        f"distance {names[0]} - {names[1]}: {r.distance * 1000:.2f} +- {r.stderr * 1000:.2f} mm "
        f"from {r.runs} turns of {angle_deg:g} deg",
        f"  per run (mm): {per}",
    ]


def mounts_json(r: MountsResult) -> dict:
    return {name: fit.as_json() for name, fit in r.fits.items()}


def mounts_text(r: MountsResult, config: Config) -> list[str]:
    head = {
        "exact": "exact fit (position, yaw and CPI scale per mouse)",
        "kimlee": "Kim & Lee linearised (positions only; yaw and CPI as configured)",
    }
    lines = [f"mounts, {head[r.method]}, {r.windows} windows:"]
    for name, f in r.fits.items():
        m = config.mouse(name).mount
        moved = math.hypot(f.x - m.x, f.y - m.y)
        scale = (f"scale x {f.scale_x:.4f}, y {f.scale_y:.4f}" if f.per_axis
                 else f"scale {f.scale:.4f}")  # fmt: skip
        text = (
            f"  {name}: x {f.x * 1000:.2f} mm, y {f.y * 1000:.2f} mm, yaw "
            f"{math.degrees(f.yaw):.2f} deg, {scale}  (configured x "
            f"{m.x * 1000:.2f}, y {m.y * 1000:.2f}, yaw {math.degrees(m.yaw):.2f}; moved "
            f"{moved * 1000:.2f} mm)"
        )
        lines.append(text)
        if r.method == "exact":
            sx, sy, syaw, ss = f.stderr
            if f.scales_stderr is not None:
                scale = f"scale x {f.scales_stderr[0]:.4f}, y {f.scales_stderr[1]:.4f}"
            else:
                scale = f"scale {ss:.4f}"
            lines.append(
                f"    stderr: x {sx * 1000:.2f} mm, y {sy * 1000:.2f} mm, yaw "
                f"{math.degrees(syaw):.3f} deg, {scale}; residual "
                f"{f.rms * 1000:.3f} mm rms"
            )
            lines.append(f"    {_axes_said(f)}")
    return lines


def _axes_said(f: MountFit) -> str:
    """How the fit's two count axes compare (mounts.AXES_SIGMAS)."""
    if not f.axes_seen:
        return "scale x - y: not told apart by this motion: one scale for both axes"
    diff = f"scale x - y {f.axes_diff:+.4f} +- {f.axes_diff_stderr:.4f}"
    return f"{diff}: fitted per axis" if f.per_axis else f"{diff}: one scale for both axes"


def umbmark_text(r: UmbResult) -> list[str]:
    lines = []
    for d, c in (("cw", r.cw), ("ccw", r.ccw)):
        lines.append(
            f"{d:>3}: {c.runs} runs, centre of gravity x {c.x * 1000:+.1f} mm, "
            f"y {c.y * 1000:+.1f} mm, r = {c.r * 1000:.1f} mm"
        )
    lines.append(f"E_max,syst = {r.e_max_syst * 1000:.1f} mm")
    return lines
