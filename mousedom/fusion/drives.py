"""Drives: about a minute of the motion a floor robot makes (straights, arcs, turns on the
spot, stops), accelerations ramped over a fifth of a second as motor controllers do; and
the stretches of a drive told apart by kind (for faults that start in one)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mousedom.fusion import sim


def _ramp(v0: tuple, v1: tuple, duration: float = 0.2, steps: int = 10) -> list[sim.Segment]:
    out = []
    for k in range(steps):
        f = (k + 0.5) / steps
        vx, vy, w = (a + f * (b - a) for a, b in zip(v0, v1, strict=True))
        out.append(sim.Segment(duration / steps, vx, vy, w))
    return out


class DriveSpan(NamedTuple):
    """A held stretch of a drive (see drive_spans)."""

    start: float
    end: float
    kind: str  # one of DRIVE_KINDS


DRIVE_KINDS = ("straight", "arc", "turn", "stop")  # turn: a pivot in place


def _drive(duration: float, seed: int, holonomic: bool) -> list[tuple[sim.Segment, str]]:
    """drive()'s segments, each with its kind ("ramp" for the speed changes between)."""
    rng = np.random.default_rng(seed)
    segs: list[tuple[sim.Segment, str]] = [(sim.Segment(0.5), "stop")]
    v = (0.0, 0.0, 0.0)
    t = 0.5
    while t < duration - 1.0:
        kind = rng.choice(["straight", "arc", "turn", "stop"], p=[0.35, 0.35, 0.2, 0.1])
        if kind == "straight":
            target = (rng.uniform(0.15, 0.5), rng.uniform(-0.1, 0.1) if holonomic else 0.0, 0.0)
        elif kind == "arc":
            speed = rng.uniform(0.15, 0.45)
            target = (speed, 0.0, speed / rng.choice([-1, 1]) / rng.uniform(0.3, 1.5))
        elif kind == "turn":
            target = (0.0, 0.0, rng.choice([-1, 1]) * rng.uniform(0.5, 2.0))
        else:
            target = (0.0, 0.0, 0.0)
        hold = float(rng.uniform(1.0, 4.0))
        segs += [(s, "ramp") for s in _ramp(v, target)]
        segs.append((sim.Segment(hold, *target), str(kind)))
        v = target
        t += 0.2 + hold
    segs += [(s, "ramp") for s in _ramp(v, (0.0, 0.0, 0.0))]
    segs.append((sim.Segment(0.5), "stop"))
    return segs


def drive(duration: float = 60.0, seed: int = 0, holonomic: bool = False) -> list[sim.Segment]:
    """About ``duration`` seconds of floor-robot motion with ramped speed changes."""
    return [seg for seg, _ in _drive(duration, seed, holonomic)]


def drive_spans(duration: float = 60.0, seed: int = 0, holonomic: bool = False) -> list[DriveSpan]:
    """The held stretches of ``drive(duration, seed, holonomic)`` in order, with their start
    and end times (as ``sim.Motion`` sums them) and kind: "straight", "arc", "turn" (a pivot
    in place) or "stop".  The ramps between them (0.2 s each) are left out."""
    out, t = [], 0.0
    for seg, kind in _drive(duration, seed, holonomic):
        if kind != "ramp":
            out.append(DriveSpan(t, t + seg.duration, kind))
        t = t + seg.duration
    return out


def drive_having(kind: str, duration: float, seed: int, within: float = 0.8) -> int:
    """The first of seed, seed + 1000, seed + 2000, ... whose drive holds a stretch of
    ``kind`` starting after 10 % and before ``within`` of ``duration`` (a short drive may
    have no pivot at all)."""
    if kind not in DRIVE_KINDS:
        raise ValueError(f"unknown kind {kind!r}; choose one of {', '.join(DRIVE_KINDS)}")
    for s in range(seed, seed + 100_000, 1000):
        if spans_of(kind, duration, s, within):
            return s
    raise ValueError(f"no drive of {duration:g} s has a {kind} stretch")  # pragma: no cover


def spans_of(kind: str, duration: float, seed: int, within: float) -> list[DriveSpan]:
    return [
        sp
        for sp in drive_spans(duration, seed)
        if sp.kind == kind and 0.1 * duration <= sp.start < within * duration
    ]
