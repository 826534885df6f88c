"""Faulty drives with exact truth: the rigs, paths and faults of issue 16, for the tests of
the fault-tolerant fusion and for bench/robust.py.

A drive is a minute of the kind of motion a floor robot makes (straights, arcs, turns on the
spot, stops) with accelerations ramped over a fifth of a second, as motor controllers do.
Mice report at their own rates with per-report noise and arrival stamps late by up to a
millisecond (USB).  A fault puts one of ``sim.SimMouse``'s imperfections on one mouse for a
span; ``informed`` runs the plain least squares with exactly that span of that mouse removed
(what a user who knew would do), the reference the robust engine is measured against.

Issue 31 adds what the engine is developed against beyond one faulty mouse: two mice
faulty together, overlapping in time and starting in a straight, an arc or a pivot
(``pair_trial``, ``pair_cases``; ``drive_spans`` tells a drive's stretches apart), and
conditions of healthy rigs that are not faults (``conditions.condition``,
``conditions.condition_trial``): USB
polling gaps, late and long-tailed arrival stamps, a noisier mouse, a CPI off from the one
configured.  A ``Trial`` holds one drive run four ways, each measured at its end (``Run``:
errors, NEES against the final covariance, exclusions): the default engine, fault handling
off, the informed reference, and the default engine on the same drive without the fault or
condition.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mousedom.config import Config, RobustConfig
from mousedom.fusion import sim
from mousedom.fusion.drives import drive, drive_having, spans_of
from mousedom.fusion.drives import drive_spans as drive_spans  # scenarios.drive_spans too

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
    "pentagon": (  # a ring of 0.12 m, the first mouse ahead
        ("front", 0.12, 0.0, 125.0),
        ("fl", 0.0371, 0.1141, 500.0),
        ("rl", -0.0971, 0.0705, 1000.0),
        ("rr", -0.0971, -0.0705, 250.0),
        ("fr", 0.0371, -0.1141, 1000.0),
    ),  # fmt: skip
    "kite": (  # four mice, irregular: one far ahead, the others bunched behind
        ("nose", 0.22, 0.0, 1000.0),
        ("left", 0.02, 0.11, 125.0),
        ("right", -0.01, -0.09, 500.0),
        ("tail", -0.12, 0.02, 250.0),
    ),  # fmt: skip
    "close-pair-plus": (  # two mice 2 cm apart fix the turn poorly: a third far behind
        ("a", 0.10, 0.01, 125.0),
        ("b", 0.10, -0.01, 500.0),
        ("c", -0.20, 0.0, 1000.0),
    ),  # fmt: skip
    "far-one": (  # one mouse far ahead of a close pair
        ("a", 0.6, 0.0, 125.0),
        ("b", -0.05, 0.08, 500.0),
        ("c", -0.05, -0.08, 1000.0),
    ),  # fmt: skip
    "line-along": (  # three in a line along the robot, the middle one at a spin's pivot
        ("f", 0.15, 0.0, 125.0),
        ("c", 0.0, 0.0, 500.0),
        ("b", -0.15, 0.0, 1000.0),
    ),  # fmt: skip
    "offset-ring": (  # a ring of 0.1 m whose centre is 0.32 m off the rig's (a front bumper)
        ("m0", 0.40, 0.10, 125.0),
        ("m1", 0.25, 0.1866, 500.0),
        ("m2", 0.25, 0.0134, 1000.0),
    ),  # fmt: skip
}

FAULTS = ("none", "lift", "lift-noisy", "under-read", "jumps", "saturation")


@dataclass(frozen=True)
class Fault:
    kind: str
    mouse: str
    start: float = 0.0
    end: float = 0.0
    jumps: tuple[tuple[float, float, float], ...] = ()


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
            report_hz=hz,
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


def config(
    rig: sim.Rig,
    robust: bool = True,
    max_speed: dict[str, float] | None = None,
    cpi: dict[str, tuple[float, float]] | None = None,
) -> Config:
    """The config of ``rig`` (``cpi``: what the robot believes instead, see sim.rig_yaml),
    fault handling on or off, with speed limits per mouse."""
    cfg = sim.rig_config(rig, cpi)
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
        spans: list[tuple[str, float, float]] = []
        t = 0.0
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
        period = 1.0 / next(m.report_hz for m in rig.mice if m.name == fault.mouse)
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


# ---------------------------------------------------------------------------- measuring


class Run(NamedTuple):
    """One drive through one engine, measured at its end."""

    position: float  # end position error, metres
    heading: float  # end heading error, radians (absolute, wrapped)
    nees: float  # e^T P^+ e of the end error against the end covariance (nan: P is 0)
    nees_dof: int  # the rank of P used: the NEES's expected value
    windows: int
    exclusions: int  # windows in which a mouse newly became robust.EXCLUDED
    inconsistent: int  # windows found inconsistent without blame


def nees(error: np.ndarray, cov: np.ndarray, rcond: float = 1e-10) -> tuple[float, int]:
    """Normalised estimation error squared e^T P^-1 e, and the degrees of freedom it has.

    P may be singular in parts (a direction nothing was learnt about, or a pose held): the
    inverse is taken on P's eigenvectors whose eigenvalue exceeds ``rcond`` times the
    largest, and e's part along the others is left out; the rank is returned with the
    value (NEES over a rank-k P has expected value k when P is right)."""
    e = np.asarray(error, dtype=float)
    p = np.asarray(cov, dtype=float)
    w, v = np.linalg.eigh((p + p.T) / 2)
    top = float(w.max()) if w.size else 0.0
    keep = w > rcond * top if top > 0 else np.zeros(len(w), dtype=bool)
    if not keep.any():
        return math.nan, 0
    z = v[:, keep].T @ e
    return float(np.sum(z * z / w[keep])), int(keep.sum())


def end_pose_error(result: sim.SimResult, batch) -> np.ndarray:
    """(x, y, theta) of the batch's last window minus the truth there (theta wrapped)."""
    truth = result.truth(np.array([batch.t[-1]]))[0]
    e = np.array([batch.x[-1], batch.y[-1], batch.theta[-1]], dtype=float) - truth
    e[2] = (e[2] + math.pi) % (2 * math.pi) - math.pi
    return e


def exclusions(batch) -> tuple[int, int]:
    """(windows in which a mouse newly became robust.EXCLUDED, windows inconsistent without
    blame): on a healthy drive every exclusion is a false one."""
    from mousedom.fusion import robust

    st = np.asarray(batch.state)
    new = (st[1:] == robust.EXCLUDED) & (st[:-1] != robust.EXCLUDED)
    return int(new.any(axis=1).sum()), int((~np.asarray(batch.consistent)).sum())


def measure(
    result: sim.SimResult, cfg: Config, dead: tuple[tuple[str, float, float], ...] = ()
) -> Run:
    """``run`` the drive through ``cfg`` (``dead`` spans removed) and measure its end."""
    batch, _ = run(result, cfg, dead)
    e = end_pose_error(result, batch)
    value, dof = nees(e, np.asarray(batch.cov)[-1])
    excluded, inconsistent = exclusions(batch)
    return Run(
        math.hypot(e[0], e[1]), abs(float(e[2])), value, dof, len(batch), excluded, inconsistent
    )


@dataclass(frozen=True)
class Trial:
    """One drive with a fault or a condition, run four ways."""

    label: str
    default: Run  # the default engine (robust on) on the drive with the fault or condition
    off: Run  # fault handling off (RobustConfig(enabled=False)) on that drive
    informed: Run  # the reference: what a user who knew would run (see each builder)
    clean: Run  # the default engine on the same drive without the fault or condition
    faults: tuple[Fault, ...] = ()
    seed: int = 0  # the drive's seed


def fault_trial(layout: str, kind: str, seed: int, duration: float) -> Trial:
    """``compare``'s drive (one fault of ``kind``, FAULTS) as a Trial: informed is plain least
    squares with the faulty reports removed by hand; clean the same drive, no fault."""
    traj = drive(duration, seed)
    base = rig(layout)
    fault = fault_for(kind, base, duration, seed)
    result = sim.simulate(apply(base, fault), traj, seed=seed)
    limits = {fault.mouse: SATURATION_SPEED} if kind == "saturation" else None
    plain = config(base, robust=False)
    return Trial(
        f"{layout} {kind}",
        measure(result, config(base, max_speed=limits)),
        measure(result, plain),
        measure(result, plain, informed_dead(fault, base, traj)),
        measure(sim.simulate(base, traj, seed=seed), config(base, max_speed=limits)),
        (fault,),
        seed,
    )


# ---------------------------------------------------------------------------- pair faults

PAIR_KINDS = ("lift", "under-read", "jumps")
PAIR_MOTIONS = ("straight", "arc", "turn")  # what the rig does when the first fault starts


def pair_faults(
    base: sim.Rig,
    kinds: tuple[str, str],
    mice: tuple[str, str],
    during: str,
    duration: float,
    seed: int,
) -> tuple[Fault, Fault]:
    """Two faults on two mice of ``base``, overlapping in time: the first starts in a
    stretch of ``during`` (DRIVE_KINDS) of ``drive(duration, seed)`` (see drive_having for
    a seed that has one), the second 0.3 to 1 s later.  Kinds: PAIR_KINDS ("lift": 3 s
    silent; "under-read": 5 s at half the counts; "jumps": four seams of 6 to 9 mm over
    3 s)."""
    if mice[0] == mice[1]:
        raise ValueError("a pair fault needs two different mice")
    spans = spans_of(during, duration, seed, 0.8)
    if not spans:
        raise ValueError(f"drive {seed} of {duration:g} s has no {during} stretch to start in")
    rng = np.random.default_rng((2000, seed))
    span = spans[int(rng.integers(len(spans)))]
    start = span.start + float(rng.uniform(0.0, 0.5)) * (span.end - span.start)
    starts = (start, start + float(rng.uniform(0.3, 1.0)))
    out = []
    for kind, mouse, t0 in zip(kinds, mice, starts, strict=True):
        if kind == "lift":
            out.append(Fault(kind, mouse, t0, t0 + 3.0))
        elif kind == "under-read":
            out.append(Fault(kind, mouse, t0, t0 + 5.0))
        elif kind == "jumps":
            cpi = next(m.cpi_x for m in base.mice if m.name == mouse)
            jumps = []
            for t in t0 + np.sort(rng.uniform(0.0, 3.0, 4)):
                size = rng.uniform(0.006, 0.009) / 0.0254 * cpi
                ang = rng.uniform(0, 2 * math.pi)
                jumps.append((float(t), float(size * math.cos(ang)), float(size * math.sin(ang))))
            out.append(Fault(kind, mouse, jumps[0][0] - 0.01, jumps[-1][0] + 0.01, tuple(jumps)))
        else:
            raise ValueError(f"unknown pair fault {kind!r}; choose of {', '.join(PAIR_KINDS)}")
    return out[0], out[1]


def pair_cases(layout: str) -> list[tuple[tuple[str, str], tuple[str, str]]]:
    """Every (kinds, mice) of two faulty mice on ``layout``: each unordered pair of mice,
    each ordered pair of PAIR_KINDS (the first kind on the first mouse)."""
    names = [name for name, *_ in LAYOUTS[layout]]
    return [
        ((k1, k2), (names[i], names[j]))
        for i in range(len(names))
        for j in range(i + 1, len(names))
        for k1 in PAIR_KINDS
        for k2 in PAIR_KINDS
    ]


def pair_trial(
    layout: str,
    kinds: tuple[str, str],
    mice: tuple[str, str],
    during: str,
    seed: int,
    duration: float,
) -> Trial:
    """Two mice of ``layout`` faulty together (``pair_faults``) on the first drive from
    ``seed`` on that has a ``during`` stretch (``drive_having``).  informed: plain least
    squares with both faulty spans removed by hand; clean: the same drive, no fault."""
    s = drive_having(during, duration, seed)
    traj = drive(duration, s)
    base = rig(layout)
    faults = pair_faults(base, kinds, mice, during, duration, s)
    faulty = base
    for f in faults:
        faulty = apply(faulty, f)
    result = sim.simulate(faulty, traj, seed=s)
    plain = config(base, robust=False)
    dead = tuple(d for f in faults for d in informed_dead(f, base, traj))
    return Trial(
        f"{layout} {kinds[0]}@{mice[0]}+{kinds[1]}@{mice[1]} in {during}",
        measure(result, config(base)),
        measure(result, plain),
        measure(result, plain, dead),
        measure(sim.simulate(base, traj, seed=s), config(base)),
        faults,
        s,
    )
