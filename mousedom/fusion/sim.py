"""Simulated rigs and trajectories with exact truth, for tests, demos and benchmarks.

A trajectory is a sequence of segments of constant body twist (v_x, v_y, omega).  Within
a segment a rigidly mounted sensor moves at a constant velocity in the body frame,
(v_x - omega p_y, v_y + omega p_x), hence also in its own frame: its cumulative reading is
piecewise linear in time, and the reading at any report time is exact.  The true pose is
the SE(2) exponential of each segment, composed.

Sensors behave as real ones do: they report at their own rate and phase, only when they
moved; counts are whole and the sub-count remainder carries over to the next report;
noise (optional) perturbs each report's increment; during spans of lost tracking (the
sensor lifted off the floor) motion is not seen at all.

Faults a real floor causes can be put on any mouse (issue 16): ``lost`` spans (lifted:
silent, or reporting only ``lift_noise``), ``scale`` spans (a glossy patch: it under-reads
by a factor), ``jumps`` (a seam: a burst of counts added to one report), ``max_speed`` (it
saturates: the sensor never reads faster than that), and ``stamp_delay`` (reports stamped
on arrival, up to that many seconds after the sensor's sample, as over USB).

Timing that is not a fault (issue 31): ``usb_gaps`` (spans in which the host does not poll
the mouse: no report inside; the counts measured meanwhile arrive summed in the first report
slot at or after the span's end, none lost) and ``stamp_tail`` (an extra, long-tailed
arrival delay: exponential with that mean, on top of ``stamp_delay``).  Both leave the other
mice's readings as they were: the random draws they add come from a stream of their own,
and a gapped mouse draws as many stamp delays as it would have without its gaps.
``usb_gap_spans`` draws gaps as a Poisson process.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from mousedom.config import Config, parse_config
from mousedom.config.rig import default
from mousedom.fusion import simgyro
from mousedom.fusion.simgyro import GyroSamples, SimGyro
from mousedom.fusion.units import INCH

# ---------------------------------------------------------------------------- trajectories


@dataclass(frozen=True)
class Segment:
    """Constant body twist for ``duration`` seconds (m/s, m/s, rad/s)."""

    duration: float
    vx: float = 0.0
    vy: float = 0.0
    omega: float = 0.0


def straight(distance: float, speed: float = 0.2) -> list[Segment]:
    """Drive ``distance`` metres forward (negative: backwards) at ``speed`` m/s."""
    return [Segment(abs(distance) / speed, vx=math.copysign(speed, distance))]


def sideways(distance: float, speed: float = 0.2) -> list[Segment]:
    """Slide left (negative: right): holonomic rigs only."""
    return [Segment(abs(distance) / speed, vy=math.copysign(speed, distance))]


def turn(angle: float, rate: float = 0.5) -> list[Segment]:
    """Turn in place by ``angle`` radians (CCW positive) at ``rate`` rad/s."""
    return [Segment(abs(angle) / rate, omega=math.copysign(rate, angle))]


def arc(radius: float, angle: float, speed: float = 0.2) -> list[Segment]:
    """Drive forward along a circle of ``radius`` (positive: centre on the left)."""
    duration = abs(angle * radius) / speed
    return [Segment(duration, vx=speed, omega=math.copysign(speed / abs(radius), angle))]


def pause(duration: float) -> list[Segment]:
    return [Segment(duration)]


def sequence(*parts: Iterable[Segment]) -> list[Segment]:
    return [s for part in parts for s in part]


def umbmark_square(
    cw: bool = True,
    side: float = 4.0,
    speed: float = 0.3,
    turn_rate: float = 0.5,
    rest: float = 0.5,
) -> list[Segment]:
    """Borenstein & Feng's UMBmark path: four legs of ``side`` with 90 degree turns on the
    spot, clockwise or counter-clockwise, stopping before and after each turn."""
    quarter = -math.pi / 2 if cw else math.pi / 2
    leg = sequence(straight(side, speed), pause(rest), turn(quarter, turn_rate), pause(rest))
    return sequence(pause(rest), leg, leg, leg, leg)


# ---------------------------------------------------------------------------- SE(2) truth


def _exp(vx: float, vy: float, w: float, dt: np.ndarray) -> np.ndarray:
    """Body-frame displacement (n,3) after dt under a constant twist (exact)."""
    a = w * dt
    small = np.abs(a) < 1e-6
    safe = np.where(small, 1.0, a)
    s = np.where(small, 1 - a**2 / 6, np.sin(safe) / safe)
    c = np.where(small, a / 2 - a**3 / 24, (1 - np.cos(safe)) / safe)
    ux, uy = vx * dt, vy * dt
    return np.stack([s * ux - c * uy, c * ux + s * uy, a], axis=-1)


def _compose(pose: np.ndarray, step: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.stack(
        [
            pose[..., 0] + c * step[..., 0] - s * step[..., 1],
            pose[..., 1] + s * step[..., 0] + c * step[..., 1],
            pose[..., 2] + step[..., 2],
        ],
        axis=-1,
    )


@dataclass(frozen=True)
class Motion:
    """A trajectory made absolute: segment start times and the poses there."""

    segments: tuple[Segment, ...]
    starts: np.ndarray  # (k+1,) segment start times, last = end time
    poses: np.ndarray  # (k+1, 3) poses at those times

    @classmethod
    def of(cls, segments: Sequence[Segment], t_start: float = 0.0) -> Motion:
        starts = [t_start]
        poses = [np.zeros(3)]
        for seg in segments:
            step = _exp(seg.vx, seg.vy, seg.omega, np.array([seg.duration]))[0]
            poses.append(_compose(poses[-1], step))
            starts.append(starts[-1] + seg.duration)
        return cls(tuple(segments), np.array(starts), np.array(poses))

    @property
    def duration(self) -> float:
        return float(self.starts[-1] - self.starts[0])

    def pose(self, t: np.ndarray | float) -> np.ndarray:
        """True pose(s) at time(s) t, shape (n,3) (clamped to the trajectory's span)."""
        ts = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), self.starts[0], self.starts[-1])
        k = np.clip(np.searchsorted(self.starts, ts, side="right") - 1, 0, len(self.segments) - 1)
        out = np.empty((len(ts), 3))
        for j in np.unique(k):
            sel = k == j
            seg = self.segments[j]
            step = _exp(seg.vx, seg.vy, seg.omega, ts[sel] - self.starts[j])
            out[sel] = _compose(self.poses[j], step)
        return out


# ---------------------------------------------------------------------------- sensors


@dataclass(frozen=True)
class SimMouse:
    """A simulated sensor: true mount and CPI, timing, and imperfections.  Units as in the rig
    YAML: metres, and the yaw in degrees (turned to radians where counts are made);
    ``report_hz`` is the mouse's report rate, not the output ``Rig.rate_hz``."""

    name: str
    x: float
    y: float
    yaw: float = 0.0  # degrees, body x to the mouse's forward
    cpi_x: float = 450.0
    cpi_y: float = 450.0
    report_hz: float = 125.0  # the mouse's configured report rate
    phase: float = 0.0  # seconds: time of the first report slot
    noise: float = 0.0  # std of added counts per report (only while moving)
    lost: tuple[tuple[float, float], ...] = ()  # spans of lost tracking [from, to)
    flip: bool = False
    quantize: bool = True  # False: exact float counts (for exactness tests)
    lift_noise: float = 0.0  # std of counts per report while lost (a lifted sensor's speckle)
    scale: tuple[tuple[float, float, float], ...] = ()  # (from, to, factor): under-reads
    jumps: tuple[tuple[float, float, float], ...] = ()  # (t, REL_X, REL_Y) counts added
    max_speed: float | None = None  # m/s the sensor can track; faster motion reads as this
    stamp_delay: float = 0.0  # reports stamped up to this many seconds late (uniform)
    usb_gaps: tuple[tuple[float, float], ...] = ()  # spans [from, to) the host does not poll
    stamp_tail: float = 0.0  # mean (s) of an extra exponential arrival delay per report

    def counts_per_body_metre(self) -> np.ndarray:
        """2x2 matrix: body-frame metres of sensor motion -> (REL_X, REL_Y) counts."""
        c, s = math.cos(math.radians(self.yaw)), math.sin(math.radians(self.yaw))
        to_mouse = np.array([[c, s], [-s, c]])  # body -> mouse frame (forward, left)
        kx = self.cpi_x / INCH
        ky = self.cpi_y / INCH
        relx_per_left = kx if self.flip else -kx
        return np.array([[0.0, relx_per_left], [-ky, 0.0]]) @ to_mouse


@dataclass(frozen=True)
class Rig:
    mice: tuple[SimMouse, ...]
    # The output rate and the fusion, defaulting as a rig config that leaves them out.
    rate_hz: float = default(Config, "rate_hz", float)
    model: str = default(Config, "model", str)
    integrator: str = default(Config, "integrator", str)
    gyro: SimGyro | None = None  # a MEMS gyro on board (simgyro.py)


def three_mouse_rig(cpi: float = 450.0, report_hz: float = 125.0, radius: float = 0.15) -> Rig:
    """Three mice on a triangle round the body origin, reporting with different phases."""
    mice = []
    for i, name in enumerate(("front", "left", "right")):
        ang = 2 * math.pi * i / 3
        mice.append(
            SimMouse(
                name=name,
                x=radius * math.cos(ang),
                y=radius * math.sin(ang),
                yaw=0.0,
                cpi_x=cpi,
                cpi_y=cpi,
                report_hz=report_hz,
                phase=i / (3 * report_hz) + 0.00037 * i,
            )
        )
    return Rig(tuple(mice))


def usb_gap_spans(
    rng: np.random.Generator | int | None,
    duration: float,
    rate_per_s: float,
    length_s: float,
    jitter: float = 0.0,
    t_start: float = 0.0,
) -> tuple[tuple[float, float], ...]:
    """Spans [from, to) in which a busy host does not poll a mouse, for ``SimMouse.usb_gaps``:
    gaps start as a Poisson process of ``rate_per_s`` a second over the time polled (the next
    gap starts an exponential wait after the previous one ends), within [t_start, t_start +
    duration); each lasts ``length_s`` times a factor uniform in [1 - jitter, 1 + jitter]."""
    if rate_per_s <= 0 or length_s <= 0:
        return ()
    gen = np.random.default_rng(rng)
    spans: list[tuple[float, float]] = []
    t, end = float(t_start), float(t_start) + float(duration)
    while True:
        t += float(gen.exponential(1.0 / rate_per_s))
        if t >= end:
            return tuple(spans)
        length = length_s * (1.0 + jitter * float(gen.uniform(-1.0, 1.0))) if jitter else length_s
        spans.append((t, t + length))
        t += length


def rig_yaml(rig: Rig, cpi: dict[str, tuple[float, float]] | None = None) -> str:
    """The config a robot would be given for this rig (true values unless ``cpi`` says
    what the robot believes)."""
    lines = [
        f"rate_hz: {float(rig.rate_hz)!r}",
        f"model: {rig.model}",
        f"integrator: {rig.integrator}",
        "mice:",
    ]
    for m in rig.mice:
        cx, cy = (float(v) for v in (cpi or {}).get(m.name, (m.cpi_x, m.cpi_y)))
        # float(): numpy scalars would print as np.float64(...), which is not YAML.
        x, y, yaw, rate = float(m.x), float(m.y), float(m.yaw), float(m.report_hz)
        lines += [
            f"  {m.name}:",
            f"    cpi: {{x: {cx!r}, y: {cy!r}}}",
            f"    mount: {{x: {x!r}, y: {y!r}, yaw: {yaw!r}}}",
            f"    report_hz: {rate!r}",
            f"    flip: {'true' if m.flip else 'false'}",
        ]
    if rig.gyro is not None:  # its true sample rate and noise density (use: the default)
        g = rig.gyro
        lines += ["gyro:", f"  sample_hz: {float(g.sample_hz)!r}", f"  noise: {float(g.density)!r}"]
    return "\n".join(lines) + "\n"


def rig_config(rig: Rig, cpi: dict[str, tuple[float, float]] | None = None) -> Config:
    return parse_config(rig_yaml(rig, cpi), "<sim>", need_sources=False)


# ---------------------------------------------------------------------------- simulation


@dataclass
class SimReports:
    t: np.ndarray
    dx: np.ndarray  # REL_X counts
    dy: np.ndarray  # REL_Y counts


@dataclass
class SimResult:
    rig: Rig
    motion: Motion
    reports: dict[str, SimReports] = field(default_factory=dict)
    gyro: GyroSamples | None = None  # the gyro's samples, if the rig has one

    def truth(self, t: np.ndarray | float) -> np.ndarray:
        return self.motion.pose(t)

    @property
    def duration(self) -> float:
        return self.motion.duration

    def total_reports(self) -> int:
        return sum(len(r.t) for r in self.reports.values())


def _sensor_cumulative(mouse: SimMouse, motion: Motion, t: np.ndarray) -> np.ndarray:
    """Exact cumulative (REL_X, REL_Y) counts, unrounded, of ``mouse`` at times t (n,2)."""
    k_matrix = mouse.counts_per_body_metre()
    # Count rates per segment (constant within a segment) and cumulative at the starts.
    velocity = np.array(
        [(s.vx - s.omega * mouse.y, s.vy + s.omega * mouse.x) for s in motion.segments]
    ).reshape(-1, 2)
    if mouse.max_speed is not None:  # saturation: the sensor reads at most max_speed
        speed = np.hypot(velocity[:, 0], velocity[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            velocity = velocity * np.minimum(1.0, mouse.max_speed / speed)[:, None]
    rates = velocity @ k_matrix.T
    durations = np.diff(motion.starts)
    at_starts = np.vstack([np.zeros(2), np.cumsum(rates * durations[:, None], axis=0)])

    def cumulative(times: np.ndarray) -> np.ndarray:
        times = np.clip(times, motion.starts[0], motion.starts[-1])
        k = np.searchsorted(motion.starts, times, side="right") - 1
        k = np.clip(k, 0, len(motion.segments) - 1)
        return at_starts[k] + rates[k] * (times - motion.starts[k])[:, None]

    c = cumulative(t)
    spans = [(a, b, 0.0) for a, b in mouse.lost] + list(mouse.scale)
    for a, b, factor in spans:  # motion during a lost span is never seen, under-read partly
        c = c - (1.0 - factor) * (cumulative(np.clip(t, a, b)) - cumulative(np.full_like(t, a)))
    return c


def _catch_up(
    slots: np.ndarray, counts: np.ndarray, gaps: Sequence[tuple[float, float]], period: float
) -> tuple[np.ndarray, np.ndarray]:
    """The report slots a host that does not poll in ``gaps`` reads, and their counts: each
    slot inside a gap delivers nothing; its counts arrive summed in the next slot polled
    (past the drive's last slot if a gap covers it: the grid goes on until one is polled)."""

    def missed_at(t: np.ndarray) -> np.ndarray:
        out = np.zeros(len(t), dtype=bool)
        for a, b in gaps:
            out |= (t >= a) & (t < b)
        return out

    missed = missed_at(slots)
    if not missed.any():
        return slots, counts
    if missed[-1]:  # the grid goes on (no motion any more) to the first slot polled
        k = len(slots)
        while missed_at(np.array([slots[0] + period * k]))[0]:
            k += 1
        more = slots[0] + period * np.arange(len(slots), k + 1)
        slots = np.concatenate([slots, more])
        counts = np.vstack([counts, np.zeros((len(more), 2))])
        missed = np.concatenate([missed, missed_at(more)])
    polled = np.flatnonzero(~missed)
    owner = np.searchsorted(polled, np.arange(len(slots)))  # the slot that delivers each
    delivered = np.zeros((len(polled), 2))
    np.add.at(delivered, owner, counts)  # a slot after no gap: 0 + its counts, exactly
    return slots[polled], delivered


def simulate(
    rig: Rig, trajectory: Sequence[Segment], seed: int | None = 0, t_start: float = 0.0
) -> SimResult:
    """Run ``trajectory`` on ``rig``: per-mouse reports (evdev convention) and the truth."""
    rng = np.random.default_rng(seed)
    # Draws of the timing imperfections: a stream of their own (spawning does not move rng).
    extra = rng.spawn(1)[0]
    motion = Motion.of(trajectory, t_start)
    result = SimResult(rig, motion)
    end = motion.starts[-1]
    for mouse in rig.mice:
        period = 1.0 / mouse.report_hz
        first = t_start + (mouse.phase % period)
        slots = first + period * np.arange(int(math.floor((end - first) / period)) + 2)
        slots = slots[slots <= end + period]
        cum = _sensor_cumulative(mouse, motion, slots)
        inc = np.diff(cum, axis=0, prepend=np.zeros((1, 2)))
        moving = np.any(np.abs(inc) > 1e-12, axis=1)
        if mouse.noise > 0:
            inc = inc + moving[:, None] * rng.normal(0.0, mouse.noise, inc.shape)
        if mouse.lift_noise > 0:
            lifted = np.zeros(len(slots), dtype=bool)
            for a, b in mouse.lost:
                lifted |= (slots >= a) & (slots < b)
            inc = inc + lifted[:, None] * rng.normal(0.0, mouse.lift_noise, inc.shape)
        for tj, jx, jy in mouse.jumps:
            k = int(np.searchsorted(slots, tj))
            if k < len(slots):
                inc[k] += (jx, jy)
        seen = np.cumsum(inc, axis=0)
        if mouse.quantize:
            # The sensor reports whole counts and keeps the remainder for later.
            whole = np.floor(seen + 1e-9)
            counts = np.diff(whole, axis=0, prepend=np.zeros((1, 2)))
        else:
            counts = inc
        draws = int(np.any(counts != 0, axis=1).sum())  # reports were the host never late
        if mouse.usb_gaps:
            slots, counts = _catch_up(slots, counts, mouse.usb_gaps, period)
        keep = np.any(counts != 0, axis=1)
        stamps = slots[keep]
        if mouse.stamp_delay > 0 or mouse.stamp_tail > 0:
            # Arrival stamps: late by a random delay, never reordered.
            delay: float | np.ndarray = 0.0
            if mouse.stamp_delay > 0:
                delay = rng.uniform(0.0, mouse.stamp_delay, draws)[: len(stamps)]
            if mouse.stamp_tail > 0:
                delay = delay + extra.exponential(mouse.stamp_tail, draws)[: len(stamps)]
            stamps = np.maximum.accumulate(stamps + delay)
        result.reports[mouse.name] = SimReports(t=stamps, dx=counts[keep, 0], dy=counts[keep, 1])
    if rig.gyro is not None:
        result.gyro = _gyro_samples(rig.gyro, motion, rng.spawn(1)[0])
    return result


def _gyro_samples(gyro: SimGyro, motion: Motion, rng: np.random.Generator) -> GyroSamples:
    """The gyro's samples over the drive: from its phase, one a period until the end (and
    one past it, as a mouse's report slots), each the average rate over its period."""
    period = 1.0 / gyro.sample_hz
    first = motion.starts[0] + period + (gyro.phase % period)
    end = motion.starts[-1]
    times = first + period * np.arange(max(0, int(math.floor((end - first) / period)) + 2))
    before, after = motion.pose(times - period)[:, 2], motion.pose(times)[:, 2]
    return simgyro.sample(gyro, np.stack([before, after], axis=1), times, rng)


def run_tracker(result: SimResult, config: Config | None = None, **tracker_kw):
    """Feed a simulation through a Tracker in one batch; returns the PoseBatch."""
    from mousedom.fusion.tracker import Tracker

    cfg = config or rig_config(result.rig)
    tracker = Tracker(cfg, t0=float(result.motion.starts[0]), **tracker_kw)
    for name, rep in result.reports.items():
        tracker.push(name, rep.t, rep.dx, rep.dy)
    if result.gyro is not None and cfg.gyro is not None:
        g = result.gyro
        tracker.push_gyro(g.t, g.rate, g.saturated if g.saturated.any() else None)
    return tracker.finish(), tracker


def run_tracker_live(result: SimResult, tracker, poll: Callable | None = None) -> list:
    """Feed a simulation as a live daemon would: every report in time order, on its own,
    as Python lists of an int count (what evdev gives), polling after each (``poll``:
    how, given the tracker; ``tracker.poll()`` by default); then finish.  Returns the
    tracker's PoseBatches in order (the one-window path's output)."""
    merged = sorted(
        (t, name, dx, dy)
        for name, r in result.reports.items()
        for t, dx, dy in zip(r.t.tolist(), r.dx.tolist(), r.dy.tolist(), strict=True)
    )
    g = result.gyro
    if g is not None and tracker.config.gyro is not None:  # the gyro's samples among them
        merged = sorted(merged + [(t, "", rate, float(sat)) for t, rate, sat in
                                  zip(g.t.tolist(), g.rate.tolist(), g.saturated.tolist(),
                                      strict=True)])  # fmt: skip
    out = []
    for t, name, dx, dy in merged:
        if not name:  # a gyro sample: (stamp, rate, saturated)
            tracker.push_gyro([t], [dx], [bool(dy)])
        else:
            tracker.push(name, [t], [int(dx) if float(dx).is_integer() else dx],
                         [int(dy) if float(dy).is_integer() else dy])  # fmt: skip
        out.append(tracker.poll() if poll is None else poll(tracker))
    out.append(tracker.finish())
    return out
