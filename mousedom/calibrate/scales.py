"""Each mouse's CPI from the others: the online scale, learnt over captures.

With three or more mice the fusion learns each mouse's scale relative to the others
(fusion/scalelearn.py): g, the factor its counts need to agree with them.  Counts are
metres * cpi / 0.0254, so a mouse that needs g times its counts gives 1/g times the counts
per metre its configured CPI says: its CPI is cpi / g.  ``learn`` replays the captures
through the same engine as ``mousedom replay`` (fault screen and scale learning on,
whatever the config says: the learner needs the screen to choose its evidence, and the
scales applied keep a far-off mouse in the fit) and reads the learner at the end;
``check`` refuses what too little motion cannot tell.

What it cannot see: a CPI error common to all the mice (the median mouse is taken as
right; docs/calibration.md, "Online scale").

A mouse's two count axes may be off by different amounts (the config has ``cpi: {x,
y}``).  One scale for both then reads as about their mean, and a mouse 3 % off on one axis
looked as if it agreed with the others.  So the learner also keeps its evidence per count
axis (``ScaleLearner.axis_gram``, ``scalefit.fit_axes``), and a mouse whose two axes'
scales differ plainly (beyond PLAIN_SIGMAS standard deviations of the difference and
MIN_CHANGE, the rule by which a CPI is corrected) is given a scale per axis; where they
agree, the one scale stands; where the drive does not tell the two apart (the
difference's spread beyond ``max_spread``), the one scale stands and the report says so.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from mousedom.capture.assignment import assign, parse_capture_arg
from mousedom.capture.replay import Replay
from mousedom.config import Config
from mousedom.errors import UserError
from mousedom.fusion.scalefit import fit_axes, reads
from mousedom.fusion.scalelearn import GROUP_S, HALF_LIFE_S

MIN_MICE = 3  # two mice cannot tell which of them is off
MAX_SPREAD = 0.005  # a scale known less well than this (a standard deviation) is refused
# A mouse's CPI is corrected where its scale is plain: beyond three standard deviations and
# half a per cent from 1 (the rule by which the fusion applies a scale: below that the
# estimate's own bias, from timing and rounding, is as large as what it would correct).
PLAIN_SIGMAS = 3.0
MIN_CHANGE = 0.005


@dataclass(frozen=True)
class MouseScale:
    name: str
    scale: float  # g: the factor its counts need to agree with the others
    spread: float  # its standard deviation
    cpi: tuple[float, float]  # as configured (the calibration file applied), x and y
    # per count axis (x, y) where the two differ plainly (``learn``), and their spreads;
    # None: one scale for both
    axes: tuple[float, float] | None = None
    axes_spread: tuple[float, float] | None = None
    # g_x - g_y learnt per axis and its spread (inf: the drive cannot tell them apart)
    axes_diff: float = math.nan
    axes_diff_spread: float = math.inf

    @property
    def per_axis(self) -> bool:
        return self.axes is not None

    @property
    def scales(self) -> tuple[float, float]:
        """The scale of each count axis (x, y): the one scale twice unless per axis."""
        return self.axes if self.axes is not None else (self.scale, self.scale)

    @property
    def spreads(self) -> tuple[float, float]:
        return self.axes_spread if self.axes_spread is not None else (self.spread, self.spread)

    @property
    def axes_seen(self) -> bool:
        """Whether the drive told the two axes' scales apart (or learnt them apart)."""
        return self.per_axis or math.isfinite(self.axes_diff_spread)

    @property
    def implied(self) -> tuple[float, float]:
        """The CPI the others imply: cpi / g on each axis."""
        gx, gy = self.scales
        return (self.cpi[0] / gx, self.cpi[1] / gy)

    @property
    def changes(self) -> tuple[bool, bool]:
        """Per axis, whether its scale is plain enough to correct the CPI (MIN_CHANGE)."""
        return tuple(  # type: ignore[return-value]
            abs(g - 1.0) > PLAIN_SIGMAS * sd and abs(g - 1.0) > MIN_CHANGE
            for g, sd in zip(self.scales, self.spreads, strict=True)
        )

    @property
    def change(self) -> bool:
        """Whether any axis's CPI is corrected."""
        return any(self.changes)

    @property
    def written(self) -> tuple[float, float]:
        """The CPI (x, y) ``--write`` stores: the implied one on each axis that changes."""
        return tuple(  # type: ignore[return-value]
            round(new, 3) if change else old
            for new, old, change in zip(self.implied, self.cpi, self.changes, strict=True)
        )

    def as_json(self) -> dict:
        cx, cy = self.implied
        (gx, gy), (sx, sy) = self.scales, self.spreads
        return {
            "scale": round(self.scale, 6),
            "spread": round(self.spread, 6),
            "per_axis": self.per_axis,
            "scale_x": round(gx, 6),
            "scale_y": round(gy, 6),
            "spread_x": round(sx, 6),
            "spread_y": round(sy, 6),
            "cpi": {"x": self.cpi[0], "y": self.cpi[1]},
            "implied_cpi": {"x": round(cx, 3), "y": round(cy, 3)},
            "change": self.change,
        }


def _per_axis(m: MouseScale, fitted: tuple | None, i: int, max_spread: float) -> MouseScale:
    """Mouse i's scale per axis from ``scalefit.fit_axes``' result, where its axes
    differ plainly; else the one scale, with the difference as learnt (its spread
    infinite where the drive cannot tell the axes apart: beyond ``max_spread``, the
    bar any scale must pass)."""
    if fitted is None:
        return m
    g, spread, diff, diff_spread = (np.asarray(v) for v in fitted)
    d, sd = float(diff[i]), float(diff_spread[i])
    if sd <= max_spread and abs(d) > PLAIN_SIGMAS * sd and abs(d) > MIN_CHANGE:
        gx, gy = (float(v) for v in g[i])
        return dataclasses.replace(
            m,
            axes=(gx, gy),
            axes_diff=d,
            axes_diff_spread=sd,
            axes_spread=(float(spread[i, 0]), float(spread[i, 1])),
        )
    return dataclasses.replace(m, axes_diff=d, axes_diff_spread=sd if sd <= max_spread
                               else math.inf)  # fmt: skip


@dataclass
class ScaleResult:
    mice: list[MouseScale]
    duration: float  # seconds of captures replayed
    windows: int
    evidence_s: float  # motion with every mouse tracking the scales come from (forgetting)
    warnings: list[str] = field(default_factory=list)  # the replay's (time bases, late reports)

    def as_json(self) -> dict:
        return {m.name: m.as_json() for m in self.mice}


def learn(
    config: Config,
    captures: list[str],
    progress: Callable[[float], None] | None = None,
    max_spread: float = MAX_SPREAD,
) -> ScaleResult:
    """Replay ``captures`` (``--capture`` arguments; the config's ``replay:`` entries for
    mice without one) through the fusion and return each mouse's learnt scale, per axis
    where its two axes differ plainly (module docstring; ``max_spread``: the largest
    spread of the difference that tells them apart)."""
    if len(config.mice) < MIN_MICE:
        raise UserError(
            f"{config.path or 'the config'}: calibrate scales needs three or more mice (it "
            f"has {len(config.mice)}): only then can each mouse's reading be checked against "
            "what the others say; with fewer use `calibrate cpi`"
        )
    robust = dataclasses.replace(config.robust, enabled=True, learn_scale=True)
    config = dataclasses.replace(config, robust=robust)
    specs = [parse_capture_arg(a) for a in captures]
    if not specs and not any(m.replay for m in config.mice):
        raise UserError(
            f"{config.path or 'the config'}: nothing to learn from: give --capture NAME=FILE "
            "for every mouse (a drive recorded with `mousedom record` or `mousedom run --record`)"
        )
    replay = Replay(config, assign(config, specs))
    summary = replay.run(lambda batch: None, progress=progress)
    if not summary.windows:  # one error, not replay's "no pose to write" before it
        raise UserError(
            "the captures hold no motion: nothing to learn the scales from (a drive recorded "
            "with `mousedom record` or `mousedom run --record`, every mouse on the floor)"
        )
    learner = replay.tracker.scales
    assert learner is not None  # learn_scale is on (above): the tracker has its learner
    evidence = (learner.axis_gram, learner.axis_segments, learner.groups, learner.n,
                len(learner.cols))  # fmt: skip
    fitted = fit_axes(*evidence)
    mice = []
    # a mouse the screen kept out (a CPI typo) has its one scale from the windows it was
    # left out of, and no per-axis evidence
    held = [learner.held_out_scale(i) is not None for i in range(len(config.mice))]
    for i, m in enumerate(config.mice):
        g, s = float(learner.one[i]), float(learner.one_spread[i])
        if held[i]:  # (reported from the windows it was left out of: _report_held_out)
            g, s = float(learner.estimate[i, 0]), float(learner.spread[i, 0])
        one = MouseScale(m.name, g, s, (m.cpi_x, m.cpi_y))
        mice.append(one if held[i] else _per_axis(one, fitted, i, max_spread))
    split = np.array([m.per_axis for m in mice])
    mixed = fit_axes(*evidence, split=split) if split.any() else None
    if mixed is not None:
        # The others' one scale again, with the mice off on one axis given a scale per
        # axis: one scale per mouse bends the others' by the one it cannot fit.
        g2, spread2 = mixed[0], mixed[1]
        for i, mouse in enumerate(mice):
            if held[i] or not np.all(np.isfinite(spread2[i])):
                continue
            gx, gy, sx, sy = (float(v) for v in (*g2[i], *spread2[i]))
            if mouse.per_axis:
                mice[i] = dataclasses.replace(mouse, axes=(gx, gy), axes_spread=(sx, sy))
            else:
                mice[i] = dataclasses.replace(mouse, scale=gx, spread=sx)
    warnings = list(summary.warnings)
    if learner.changes:
        # (scalelearn's change of scale: the evidence before the last change was dropped)
        last = ", ".join(learner.change_lines(config.names))
        times = "once" if learner.changes == 1 else f"{learner.changes} times; the last"
        warnings.append(
            f"a mouse's scale changed during the captures ({times}: {last}): the scales are "
            f"those after it, from {learner.groups * GROUP_S:.1f} s of motion (calibrate "
            "from a drive on one floor throughout)"
        )
    return ScaleResult(
        mice=mice,
        duration=summary.duration,
        windows=summary.windows,
        evidence_s=float(learner.groups) * GROUP_S,
        warnings=warnings,
    )


def check(result: ScaleResult, max_spread: float = MAX_SPREAD) -> None:
    """Refuse scales too little motion has told: a UserError naming the mice."""
    how = (
        "drive longer with every mouse on the floor, turning as well as driving straight "
        f"(the scales come from {result.evidence_s:.1f} s of motion in which every mouse "
        f"tracked; motion older than {HALF_LIFE_S / 60:.0f} minutes counts half)"
    )
    if not all(math.isfinite(m.spread) for m in result.mice):
        unknown = [m.name for m in result.mice if not math.isfinite(m.spread)]
        raise UserError(
            f"too little motion to learn the scale of mouse {', '.join(unknown)}: {how}"
        )

    # a mouse fitted per axis is held to the bound on each axis's spread, not its one scale's
    def spread(m: MouseScale) -> float:
        return max(m.axes_spread) if m.axes_spread is not None else m.spread

    loose = [m for m in result.mice if not spread(m) <= max_spread]
    if loose:
        said = ", ".join(f"{m.name} to +- {100 * spread(m):.2f} %" for m in loose)
        raise UserError(
            f"too little evidence: the scale is known only {said}, and a calibration needs "
            f"+- {100 * max_spread:g} % (--max-spread): {how}"
        )


def _reads(g: float) -> str:
    if round(100 * (1.0 / g - 1.0), 1) == 0:
        return "as the others"
    return reads(g, 1)


def _implied(m: MouseScale) -> str:
    """The last column: the CPI the others imply where it changes, or why not."""
    if not m.per_axis:
        if m.change:
            return f"{m.implied[0]:.1f}, {m.implied[1]:.1f}"
        if abs(m.scale - 1.0) <= PLAIN_SIGMAS * m.spread:
            return "unchanged: within spread"
        return f"unchanged: under {100 * MIN_CHANGE:g} %"
    said = [f"{new:.1f}" if change else f"{old:g}"
            for new, old, change in zip(m.implied, m.cpi, m.changes, strict=True)]  # fmt: skip
    kept = [a for a, change in zip("xy", m.changes, strict=True) if not change]
    return ", ".join(said) + (f" ({kept[0]} unchanged)" if kept else "")


def report_text(result: ScaleResult, config_path: str) -> list[str]:
    """The readable report: per mouse its scale, spread, how it reads and the CPI (x, y)
    the others imply; per axis where its axes differ, and a line for each mouse whose axes
    the drive cannot tell apart."""
    rows = []
    for m in result.mice:
        if m.per_axis:
            (gx, gy), (sx, sy) = m.scales, m.spreads
            scale = f"x {gx:.4f} +- {sx:.4f}, y {gy:.4f} +- {sy:.4f}"
            reads = f"x {_reads(gx)}, y {_reads(gy)}"
        else:
            scale, reads = f"{m.scale:.4f} +- {m.spread:.4f}", _reads(m.scale)
        rows.append((m.name, scale, reads, f"{m.cpi[0]:g}, {m.cpi[1]:g}", _implied(m)))
    head = ("mouse", "learnt scale", "reads", "cpi x, y", "the others imply")
    widths = [max(len(r[k]) for r in [head, *rows]) for k in range(4)]
    lines = [
        f"calibrate scales: {len(result.mice)} mice ({config_path}), {result.duration:.1f} s "
        f"of captures, {result.windows} windows;",
        f"learnt from {result.evidence_s:.1f} s of motion with every mouse tracking",
        "",
    ]
    for r in [head, *rows]:
        lines.append("  ".join(f"{v:<{w}}" for v, w in zip(r, widths, strict=False)) + "  " + r[4])
    notes = [
        f"{m.name}: its x and y scales differ by {100 * m.axes_diff:+.1f} % +- "
        f"{100 * m.axes_diff_spread:.1f} %: learnt per axis"
        for m in result.mice
        if m.per_axis
    ]
    unseen = [m.name for m in result.mice if not m.axes_seen]
    if unseen:
        notes += [
            f"{', '.join(unseen)}: the drive does not tell the x scale from the y scale: one",
            "scale for both axes (drive sideways as well; `calibrate cpi` measures one axis)",
        ]
    lines += ["", *notes] if notes else []
    lines += [
        "",
        "The scales are relative: the median mouse is taken as right, and a CPI error",
        "common to all the mice cannot be seen (docs/calibration.md); `calibrate cpi`",
        "measures one mouse against a known distance.",
    ]
    return lines
