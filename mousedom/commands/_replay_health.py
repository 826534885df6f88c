"""The mice's health in ``mousedom replay``'s summary: the windows after which the fusion
had each mouse excluded or suspect, why, its learnt scale at the end, and the warning for
a scale that says its CPI is wrong."""

from __future__ import annotations

import math

import numpy as np

from mousedom.capture.summary import Summary
from mousedom.errors import escaped
from mousedom.fusion.scalelearn import WARN

# A learnt scale this far from 1 is a wrong CPI, not a floor: the summary says so (the
# learner's own threshold).
SCALE_WARNING = WARN


def _share(k: int, windows: int) -> str:
    return f"{k} ({100.0 * k / windows:.1f} %)" if windows else str(k)


def _percent(k: int, windows: int) -> str:
    """A share of all windows; a few windows of a long replay are not "0.0 %"."""
    share = 100.0 * k / windows
    return "<0.1 %" if 0 < share < 0.05 else f"{share:.1f} %"


def why_line(kind: str, why: dict[str, int], windows: int) -> str | None:
    """Why a mouse was ``kind`` (excluded, suspect): each reason with its share of all
    windows, the most frequent first, or None when it never was."""
    if not why or not windows:
        return None
    reasons = ", ".join(f"{reason} {_percent(k, windows)}" for reason, k in why.items())
    return f"    {kind}: {reasons}"


def health_lines(s: Summary, cpi: dict[str, tuple[float, float]]) -> list[str]:
    """Per mouse: the windows after which the fusion had it excluded and suspect (and
    their share of all windows), its learnt scale at the end as a deviation from 1, and
    under the row, why it was excluded or suspect (the share of each reason); then the
    scale warnings."""
    # The rows are indented: a line that starts with a mouse's name stays its row above.
    # The reasons are indented further: their own lines, so the table stays narrow.
    lines = [
        f"{'mouse health':<14} {'excluded':>15} {'suspect':>15} {'late':>15}   "
        "learnt scale at the end"
    ]
    for m in s.mice:
        scale = "not learnt"
        if m.scale is not None:
            x, y = (round(100 * (k - 1), 1) + 0.0 for k in m.scale)  # + 0.0: no "-0.0"
            scale = f"x {x:+.1f} %  y {y:+.1f} %"
        share = " ".join(f"{_share(k, s.windows):>15}" for k in (m.excluded, m.suspect, m.late))
        lines.append(f"  {m.name:<12} {share}   {scale}")
        for kind, why in (("excluded", m.excluded_why), ("suspect", m.suspect_why)):
            line = why_line(kind, why, s.windows)
            if line:
                lines.append(line)
    return lines + [f"warning: {w}" for w in scale_warnings(s, cpi)]


def scale_warnings(s: Summary, cpi: dict[str, tuple[float, float]]) -> list[str]:
    """A warning for each mouse whose learnt scale at the end is SCALE_WARNING or more off
    the rig's (what the batches show; the engine flags it too), on the axis that read most
    of its motion (the other, for a mouse facing forward the one that reads the turn, is
    learnt less well while another mouse is far off: fusion/scalelearn.py).  Measured
    against the median of all the mice's scales on that axis: only the scales relative to
    each other are observable, and with three or more mice the median is one of the mice
    that agree."""
    learnt = [m for m in s.mice if m.scale is not None]
    if not learnt:
        return []
    ref = np.median([m.scale for m in learnt], axis=0)
    out = []
    for m in learnt:
        if m.name not in cpi or m.scale is None:
            continue
        axis = 0 if m.stats.path_x >= m.stats.path_y else 1
        w = scale_warning(m.name, "xy"[axis], m.scale[axis] / float(ref[axis]), cpi[m.name][axis])
        if w:
            out.append(w)
    return out


def scale_warning(name: str, axis: str, k: float, cpi: float) -> str | None:
    """The warning for a mouse whose scale on ``axis`` relative to the others' (the factor
    its counts are to be multiplied by to agree with them) makes it read SCALE_WARNING or
    more more or less than they do, else None.  A relative scale k means the mouse gives
    1/k times the counts per metre that the others imply: its CPI is about cpi / k."""
    if abs(1.0 / k - 1.0) < SCALE_WARNING:  # how much more or less it reads: as the
        return None  # learner's own warning (fusion/scalelearn.py) judges it
    return (
        f"mouse {name} reads {100 * abs(1 / k - 1):.0f} % {'more' if k < 1 else 'less'} than "
        f"the other mice (its {axis} axis): check its CPI in the config: {cpi:g} there, the "
        f"others say about {cpi / k:.0f}"
    )


def gyro_line(s: Summary) -> str | None:
    """The summary's line for the gyro: its samples, their rate and its bias at the end
    (deg/s, +- one sigma), or that the config's gyro was in no capture; None for a rig
    replayed without one."""
    if s.gyro_dropped:
        return f"{'gyro':<12} none in the captures: replayed without it (the mice alone)"
    g = s.gyro
    if g is None:
        return None
    bias = "no bias learnt (no window with samples)"
    if g.bias is not None and g.bias_sigma is not None:
        bias = f"bias {math.degrees(g.bias):+.3f} +- {math.degrees(g.bias_sigma):.3f} deg/s"
    if g.stats.saturated:  # those windows' heading is the mice's alone
        bias += f", {g.stats.saturated} saturated (left out)"
    # (the device's name is the capture's: escaped, as the mice's in format_summary)
    return (f"{'gyro':<12} {g.stats.reports} samples, {g.samples_per_s:.1f} Hz, {bias}  "
            f"{escaped(g.file)} ({escaped(g.device)})")  # fmt: skip
