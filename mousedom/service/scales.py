"""Each mouse's learnt scale as the daemon reports it: SOURCE fields and the log.

The fusion learns each mouse's scale relative to the others (``fusion.scalelearn``, three or
more mice with fault handling on) and renews it twice a second of windows.  The daemon shows
it in every SOURCE message (``scale_fields``: hence also /diagnostics, ``mousedom watch``) and
logs the learner's warnings (a mouse 10 % or more off: a CPI typo, the wrong mouse's CPI)
through ``ScaleLog``, which keeps the journal readable:

- a mouse's warning is logged (WARNING) when it first appears;
- while it persists it is logged again every ``REPEAT_S`` (10 minutes), not at every renewal
  (twice a second would flood the journal);
- it is over when the learner has not warned of that mouse for ``CLEAR_S`` (10 s): logged
  once (INFO) with the scale it has now, so that a mouse whose scale hovers at the threshold
  is not logged in and out at every renewal.

Everything here is plain data in, text out: tests drive it with a stand-in learner and
their own clock.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)

REPEAT_S = 600.0  # a warning that persists is logged again this often
CLEAR_S = 10.0  # a warning absent this long is over (and said so once)


def _token(i: int) -> str:
    # Stands for mouse i's name in the learner's warning lines: a string no name holds,
    # so that each line is told to its mouse however the names read.
    return f"\x00{i}\x00"


def warning_texts(learner: Any, names: Sequence[str]) -> dict[str, str]:
    """The learner's warnings (``ScaleLearner.warnings``, its own wording and threshold)
    by mouse name."""
    if learner is None:
        return {}
    tokens = [_token(i) for i in range(len(names))]
    out = {}
    for line in learner.warnings(tokens):
        for i, token in enumerate(tokens):
            if token in line:
                out[names[i]] = line.replace(token, names[i])
                break
    return out


def scale_fields(learner: Any, names: Sequence[str], applying: bool) -> list[dict[str, Any]]:
    """Per mouse (config order) the SOURCE keys of its learnt scale (docs/protocol.md):
    ``scale`` (the factor its counts need to agree with the others; both axes are one,
    but for a mouse given a scale per axis: its axis further from 1),
    ``scale_spread`` (its standard deviation), ``scale_applied`` (whether the fusion
    multiplies the mouse's counts by it, within robust.scale_limit) and ``scale_warning``
    (the learner's warning, or None).  ``scale`` and ``scale_spread`` are None where
    nothing is learnt: fewer than three mice, fault handling off, or too little motion
    yet."""
    none: dict[str, Any] = {
        "scale": None,
        "scale_spread": None,
        "scale_applied": False,
        "scale_warning": None,
    }
    if learner is None:
        return [dict(none) for _ in names]
    warnings = warning_texts(learner, names)
    out = []
    for i, name in enumerate(names):
        a = learner.reported_axis(i)  # (a mouse given a scale per axis: its axis off)
        g, s = float(learner.estimate[i, a]), float(learner.spread[i, a])
        if not (math.isfinite(g) and math.isfinite(s)):
            out.append(dict(none))
            continue
        out.append({
            "scale": round(g, 6),
            "scale_spread": round(s, 6),
            # applied where either axis is
            "scale_applied": bool(applying and (learner.scale[i] != 1.0).any()),
            "scale_warning": warnings.get(name),
        })  # fmt: skip
    return out


@dataclass
class _Warned:
    text: str  # the latest warning
    since: float  # when it was first logged
    logged: float  # when it was last logged
    seen: float  # the last renewal that warned of it


class ScaleLog:
    """Logs the learner's warnings when the set of warned mice changes, and again every
    ``REPEAT_S`` while one persists (the module docstring)."""

    def __init__(self, repeat_s: float = REPEAT_S, clear_s: float = CLEAR_S) -> None:
        self.repeat_s, self.clear_s = repeat_s, clear_s
        self.learner: Any = None  # the learner and version last read
        self.version = -1
        self.changes = 0  # the learner's changes of scale logged
        self.warned: dict[str, _Warned] = {}

    def due(self, learner: Any) -> bool:
        """Whether ``learner`` has renewed since it was last read (or is another one: the
        config was reloaded).  Cheap: the daemon asks after every poll."""
        return learner is not None and (
            learner is not self.learner or learner.version != self.version
        )

    def renewed(self, learner: Any, names: Sequence[str], now: float) -> None:
        """Read a renewal of ``learner`` (mice ``names``) at daemon time ``now``; log."""
        if learner is not self.learner:
            self.changes = 0
        self.learner, self.version = learner, learner.version
        if learner.changes != self.changes:
            self.changes = learner.changes
            for line in learner.change_lines(names):
                log.info(
                    "%s (another floor, its lens?): the scales are learnt again from the "
                    "change on", line,
                )  # fmt: skip
        texts = warning_texts(learner, names)
        for name, text in texts.items():
            w = self.warned.get(name)
            if w is None:
                log.warning("%s", text)
                self.warned[name] = _Warned(text, now, now, now)
                continue
            w.text, w.seen = text, now
            if now - w.logged >= self.repeat_s:
                minutes = (now - w.since) / 60.0
                log.warning("%s (still so, for %.0f minutes)", text, minutes)
                w.logged = now
        for name in list(self.warned):
            if name in texts:
                continue
            if name not in names:  # no longer configured (a reload): nothing to say
                del self.warned[name]
            elif now - self.warned[name].seen >= self.clear_s:
                i = list(names).index(name)
                g, s = float(learner.estimate[i, 0]), float(learner.spread[i, 0])
                if math.isfinite(s):
                    log.info(
                        "mouse %s agrees with the others again (learnt scale %.3f +- %.3f)",
                        name, g, s,
                    )  # fmt: skip
                else:
                    log.info("mouse %s: no scale warning any more (its scale is not known "
                             "now: too little motion)", name)  # fmt: skip
                del self.warned[name]
