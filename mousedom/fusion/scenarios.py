"""Faulty drives with exact truth: the rigs, paths and faults of issue 16, for the tests of
the fault-tolerant fusion and for bench/robust.py.

A drive is a minute of the kind of motion a floor robot makes (straights, arcs, turns on the
spot, stops) with accelerations ramped over a fifth of a second, as motor controllers do.
Mice report at their own rates with per-report noise and arrival stamps late by up to a
millisecond (USB).  A fault puts one of ``sim.SimMouse``'s imperfections on one mouse for a
span; ``informed`` runs the plain least squares with exactly that span of that mouse removed
(what a user who knew would do), the reference the robust engine is measured against.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from mousedom.config import Config, RobustConfig
from mousedom.fusion import sim

LAYOUTS = {
    # name: ((mouse, x, y, report_hz), ...)
    "triangle": (
        ("front", 0.12, 0.0, 125.0),
        ("left", -0.06, 0.10, 500.0),
        ("right", -0.06, -0.10, 1000.0),
    ),  # fmt: skip
    "square": (
        ("fl", 0.1, 0.08, 125.0),
        ("fr", 0.1, -0.08, 500.0),
        ("rl", -0.1, 0.08, 1000.0),
        ("rr", -0.1, -0.08, 250.0),
    ),  # fmt: skip
    "wide": (
        ("a", 0.25, 0.0, 1000.0),
        ("b", -0.05, 0.18, 1000.0),
        ("c", -0.08, -0.15, 125.0),
    ),  # fmt: skip
    "pair": (("left", 0.0, 0.1, 500.0), ("right", 0.0, -0.1, 500.0)),
}

FAULTS = ("none", "lift", "lift-noisy", "under-read", "jumps", "saturation")


@dataclass(frozen=True)
class Fault:
    kind: str
    mouse: str
    start: float = 0.0
    end: float = 0.0
    jumps: tuple[tuple[float, float, float], ...] = ()


def _ramp(v0: tuple, v1: tuple, duration: float = 0.2, steps: int = 10) -> list[sim.Segment]:
    out = []
    for k in range(steps):
        f = (k + 0.5) / steps
        vx, vy, w = (a + f * (b - a) for a, b in zip(v0, v1, strict=True))
        out.append(sim.Segment(duration / steps, vx, vy, w))
    return out


def drive(duration: float = 60.0, seed: int = 0, holonomic: bool = False) -> list[sim.Segment]:
    """About ``duration`` seconds of floor-robot motion with ramped speed changes."""
    rng = np.random.default_rng(seed)
    segs: list[sim.Segment] = [sim.Segment(0.5)]
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
        segs += _ramp(v, target)
        segs.append(sim.Segment(hold, *target))
        v = target
        t += 0.2 + hold
    segs += _ramp(v, (0.0, 0.0, 0.0))
    segs.append(sim.Segment(0.5))
    return segs


def rig(
    layout: str = "triangle", noise: float = 0.3, stamp_delay: float = 0.001, cpi: float = 1000.0
) -> sim.Rig:
    mice = tuple(
        sim.SimMouse(
            name,
            x,
            y,
            cpi_x=cpi,
            cpi_y=cpi,
            rate_hz=hz,
            phase=0.00131 * k,
            noise=noise,
            stamp_delay=stamp_delay,
        )  # fmt: skip
        for k, (name, x, y, hz) in enumerate(LAYOUTS[layout])
    )
    return sim.Rig(mice, model="lsq")


def fault_for(kind: str, rig: sim.Rig, duration: float, seed: int = 0) -> Fault:
    """The issue's fault of ``kind`` on the rig's first mouse (jumps: its last one)."""
    rng = np.random.default_rng(1000 + seed)
    first, last = rig.mice[0].name, rig.mice[-1].name
    mid = duration * float(rng.uniform(0.3, 0.6))
    if kind == "none":
        return Fault(kind, first)
    if kind in ("lift", "lift-noisy"):
        return Fault(kind, first, mid, mid + 3.0)
    if kind == "under-read":
        return Fault(kind, first, mid, mid + 5.0)
    if kind == "saturation":
        return Fault(kind, first, 0.0, duration)
    if kind == "jumps":
        jumps = []
        cpi = rig.mice[-1].cpi_x
        for t in np.sort(rng.uniform(0.15 * duration, 0.85 * duration, 5)):
            size = rng.uniform(0.006, 0.009) / 0.0254 * cpi
            ang = rng.uniform(0, 2 * math.pi)
            jumps.append((float(t), float(size * math.cos(ang)), float(size * math.sin(ang))))
        return Fault(kind, last, jumps[0][0] - 0.01, jumps[-1][0] + 0.01, tuple(jumps))
    raise ValueError(f"unknown fault {kind!r}; choose one of {', '.join(FAULTS)}")


SATURATION_SPEED = 0.3  # m/s: the saturating mouse's limit in the "saturation" fault


def apply(rig: sim.Rig, fault: Fault) -> sim.Rig:
    """The rig with ``fault`` put on its mouse."""
    mice = []
    for m in rig.mice:
        if m.name == fault.mouse and fault.kind != "none":
            if fault.kind == "lift":
                m = dataclasses.replace(m, lost=((fault.start, fault.end),))
            elif fault.kind == "lift-noisy":
                m = dataclasses.replace(m, lost=((fault.start, fault.end),), lift_noise=1.5)
            elif fault.kind == "under-read":
                m = dataclasses.replace(m, scale=((fault.start, fault.end, 0.5),))
            elif fault.kind == "jumps":
                m = dataclasses.replace(m, jumps=fault.jumps)
            elif fault.kind == "saturation":
                m = dataclasses.replace(m, max_speed=SATURATION_SPEED)
        mice.append(m)
    return dataclasses.replace(rig, mice=tuple(mice))


def config(rig: sim.Rig, robust: bool = True, max_speed: dict[str, float] | None = None) -> Config:
    cfg = sim.rig_config(rig)
    mice = tuple(
        dataclasses.replace(m, max_speed=(max_speed or {}).get(m.name, m.max_speed))
        for m in cfg.mice
    )
    return dataclasses.replace(cfg, mice=mice, robust=RobustConfig(enabled=robust))


def end_error(result: sim.SimResult, tracker) -> tuple[float, float]:
    """(position error in metres, heading error in radians) of the tracker's pose at the
    end of the drive."""
    truth = result.truth(np.array([result.motion.starts[-1]]))[0]
    x, y, th = tracker.pose
    dth = (th - truth[2] + math.pi) % (2 * math.pi) - math.pi
    return math.hypot(x - truth[0], y - truth[1]), abs(dth)


def run(result: sim.SimResult, cfg: Config, dead: tuple[tuple[str, float, float], ...] = ()):
    """The drive through a Tracker in one batch; ``dead`` spans (mouse, from, to) of
    reports removed by hand.  Returns (PoseBatch, tracker)."""
    from mousedom.fusion.tracker import Tracker

    tracker = Tracker(cfg, t0=float(result.motion.starts[0]))
    for name, rep in result.reports.items():
        keep = np.ones(len(rep.t), dtype=bool)
        for mouse, a, b in dead:
            if mouse == name:
                keep &= ~((rep.t >= a) & (rep.t < b + 1.0 / cfg.mouse(name).report_hz))
        tracker.push(name, rep.t[keep], rep.dx[keep], rep.dy[keep])
    for mouse, a, b in dead:
        tracker.set_live(mouse, False, a)
        tracker.set_live(mouse, True, b)
    return tracker.finish(), tracker


def informed_dead(
    fault: Fault, rig: sim.Rig, trajectory: list[sim.Segment]
) -> tuple[tuple[str, float, float], ...]:
    """The spans a user who knew the fault would remove."""
    if fault.kind == "none":
        return ()
    if fault.kind == "saturation":  # where the mouse truly moved faster than it tracks
        m = next(m for m in rig.mice if m.name == fault.mouse)
        spans, t = [], 0.0
        for seg in trajectory:
            speed = math.hypot(seg.vx - seg.omega * m.y, seg.vy + seg.omega * m.x)
            if speed > SATURATION_SPEED:
                if spans and abs(spans[-1][2] - t) < 1e-12:
                    spans[-1] = (m.name, spans[-1][1], t + seg.duration)
                else:
                    spans.append((m.name, t, t + seg.duration))
            t += seg.duration
        return tuple(spans)
    if fault.kind == "jumps":
        period = 1.0 / next(m.rate_hz for m in rig.mice if m.name == fault.mouse)
        return tuple((fault.mouse, t - period, t + period) for t, _, _ in fault.jumps)
    return ((fault.mouse, fault.start, fault.end),)


@dataclass
class Comparison:
    """One faulty drive run three ways (see ``compare``)."""

    base: sim.Rig  # the rig as the robot believes it is (no faults)
    fault: Fault
    robust: object  # the robust engine's PoseBatch
    plain: object  # plain least squares' PoseBatch
    errors: list[tuple[float, float]]  # end (position, heading) error: plain, robust, informed


def compare(layout: str, kind: str, seed: int, duration: float) -> Comparison:
    """The drive of ``seed`` with the fault ``kind`` on ``layout``, through plain least
    squares, the robust engine (told the saturating mouse's limit) and the informed
    reference (plain, the faulty reports removed by hand for exactly the fault's span)."""
    traj = drive(duration, seed)
    base = rig(layout)
    fault = fault_for(kind, base, duration, seed)
    result = sim.simulate(apply(base, fault), traj, seed=seed)
    limits = {fault.mouse: SATURATION_SPEED} if kind == "saturation" else None
    plain_b, plain = run(result, config(base, robust=False))
    batch, rob = run(result, config(base, max_speed=limits))
    _, informed = run(result, config(base, robust=False), informed_dead(fault, base, traj))
    errors = [end_error(result, t) for t in (plain, rob, informed)]
    return Comparison(base, fault, batch, plain_b, errors)
