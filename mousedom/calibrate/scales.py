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
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from mousedom.capture.assignment import assign, parse_capture_arg
from mousedom.capture.replay import Replay
from mousedom.config import Config
from mousedom.errors import UserError
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

    @property
    def implied(self) -> tuple[float, float]:
        """The CPI the others imply: cpi / g on each axis."""
        return (self.cpi[0] / self.scale, self.cpi[1] / self.scale)

    @property
    def change(self) -> bool:
        """Whether the scale is plain enough to correct the CPI (see MIN_CHANGE)."""
        off = abs(self.scale - 1.0)
        return off > PLAIN_SIGMAS * self.spread and off > MIN_CHANGE

    def as_json(self) -> dict:
        cx, cy = self.implied
        return {
            "scale": round(self.scale, 6),
            "spread": round(self.spread, 6),
            "cpi": {"x": self.cpi[0], "y": self.cpi[1]},
            "implied_cpi": {"x": round(cx, 3), "y": round(cy, 3)},
            "change": self.change,
        }


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
) -> ScaleResult:
    """Replay ``captures`` (``--capture`` arguments; the config's ``replay:`` entries for
    mice without one) through the fusion and return each mouse's learnt scale."""
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
    mice = []
    for i, m in enumerate(config.mice):
        g, s = float(learner.estimate[i, 0]), float(learner.spread[i, 0])
        mice.append(MouseScale(m.name, g, s, (m.cpi_x, m.cpi_y)))
    return ScaleResult(
        mice=mice,
        duration=summary.duration,
        windows=summary.windows,
        evidence_s=float(learner.groups) * GROUP_S,
        warnings=list(summary.warnings),
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
    loose = [m for m in result.mice if m.spread > max_spread]
    if loose:
        said = ", ".join(f"{m.name} to +- {100 * m.spread:.2f} %" for m in loose)
        raise UserError(
            f"too little evidence: the scale is known only {said}, and a calibration needs "
            f"+- {100 * max_spread:g} % (--max-spread): {how}"
        )


def report_text(result: ScaleResult, config_path: str) -> list[str]:
    """The readable report: per mouse its scale, spread, how it reads and the CPI (x, y)
    the others imply."""
    rows = []
    for m in result.mice:
        off = 1.0 / m.scale - 1.0  # what it reads beyond the others (g < 1: more)
        reads = "as the others" if round(100 * off, 1) == 0 else (
            f"{100 * abs(off):.1f} % {'more' if off > 0 else 'less'}"
        )  # fmt: skip
        if m.change:
            implied = f"{m.implied[0]:.1f}, {m.implied[1]:.1f}"
        elif abs(m.scale - 1.0) <= PLAIN_SIGMAS * m.spread:
            implied = "unchanged: within spread"
        else:
            implied = f"unchanged: under {100 * MIN_CHANGE:g} %"
        scale = f"{m.scale:.4f} +- {m.spread:.4f}"
        rows.append((m.name, scale, reads, f"{m.cpi[0]:g}, {m.cpi[1]:g}", implied))
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
    lines += [
        "",
        "The scales are relative: the median mouse is taken as right, and a CPI error",
        "common to all the mice cannot be seen (docs/calibration.md); `calibrate cpi`",
        "measures one mouse against a known distance.",
    ]
    return lines
