"""From a recording (per-mouse reports and runs) and a config to calibration results.

The glue between the pure algorithms and the command line: it picks the mice, sums
counts per run or window, converts them with the config (whose calibration file is
already applied, so "calibrated CPI" is simply the config's CPI), and turns every reason
the data cannot give an answer into a UserError naming the mouse and run at fault.
No I/O here: files are read by the command, results are printed by ``report``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from mousedom import plausible
from mousedom.calibrate.counts import body_frame, mouse_frame
from mousedom.calibrate.cpi import CpiError, CpiResult, calibrate_cpi
from mousedom.calibrate.distance import DistanceError, DistanceResult, calibrate_distance
from mousedom.calibrate.mounts import MountError, MountFit, exact_mount, kimlee, motion_problem
from mousedom.calibrate.reference import Reference, WheelGeometry, check_coverage, window_twist
from mousedom.calibrate.runs import Run, moving, run_counts, run_windows, runs_window_counts
from mousedom.config import Config
from mousedom.errors import UserError, located
from mousedom.sources.base import Reports

SMALL_RUN = 0.25  # a run with less motion than this fraction of the median is a bump
CPI_TOLERANCE = 0.25  # a CPI this far off the configured one is suspicious
DRAWING_TOLERANCE = 0.1  # a measured distance this far off the config's is suspicious
PAD = 0.2  # seconds of pause added around each run for the reference (clock offsets)


@dataclass
class Session:
    config: Config
    recording: dict[str, Reports]  # the mice being calibrated, config order
    runs: list[Run]
    notes: list[str] = field(default_factory=list)  # what was left out, and why

    @property
    def names(self) -> list[str]:
        return list(self.recording)


def make_session(config: Config, recording: Mapping[str, Reports], runs: Sequence[Run]) -> Session:
    ordered = {n: recording[n] for n in config.names if n in recording}
    return Session(config, ordered, list(runs))


def _keep_real_runs(session: Session, magnitude: np.ndarray, what: str) -> np.ndarray:
    """Mask of runs that are real motion; bumps are left out with a note."""
    if len(magnitude) == 0:
        return np.zeros(0, bool)
    median = float(np.median(magnitude))
    keep = magnitude >= SMALL_RUN * median
    for k in np.flatnonzero(~keep):
        r = session.runs[k]
        session.notes.append(
            f"{what}: left out run {k + 1} at t = {r.t0:.3f} .. {r.t1:.3f} s: its motion is "
            f"{magnitude[k] / median:.0%} of the median run (a bump, not a run)"
        )
    return keep


def _no_motion(session: Session, counts: np.ndarray) -> None:
    """Raise when a mouse shows no motion at all: wrong capture or a mouse off the floor."""
    for j, name in enumerate(session.names):
        if not np.any(counts[:, j, :]):
            if len(moving(session.recording[name])):
                # It moved, but forth and back inside one run: the runs were not split.
                raise UserError(
                    f"mouse {name}: its motion adds up to nothing in every run (runs: "
                    f"{len(session.runs)}): pushes or turns forth and back must be separated "
                    "by pauses longer than --gap"
                )
            raise UserError(
                f"mouse {name}: no motion in any run (is it on the floor? is this its capture?)"
            )


def cpi(session: Session, distance: float, axis: str, min_runs: int = 2) -> dict[str, CpiResult]:
    """Bonarini 4.2 per mouse: CPI along ``axis`` from pushes of ``distance`` metres."""
    counts = run_counts(session.recording, session.runs, session.names)
    if len(session.runs) == 0:
        raise UserError("calibrate cpi: no runs: the mice never moved")
    _no_motion(session, counts)
    out = {}
    for j, name in enumerate(session.names):
        mouse = session.config.mouse(name)
        c = counts[:, j, :]
        keep = _keep_real_runs(session, np.hypot(c[:, 0], c[:, 1]), f"mouse {name}")
        across = mouse.cpi_y if axis == "x" else mouse.cpi_x
        try:
            out[name] = calibrate_cpi(c[keep], distance, axis, across, min_runs=min_runs,
                                      numbers=(np.flatnonzero(keep) + 1).tolist())  # fmt: skip
        except CpiError as e:
            raise UserError(f"mouse {name}: {e}") from None
        problem = plausible.cpi_problem(out[name].cpi)
        if problem:  # bad runs or hostile data: not stored without --force
            out[name].warnings.append(f"cpi {axis}: {problem}")
        # Far from the configured CPI is most often a --distance in the wrong unit.
        before = mouse.cpi_y if axis == "y" else mouse.cpi_x
        off = out[name].cpi / before - 1
        if abs(off) > CPI_TOLERANCE:
            out[name].hints.append(
                f"cpi {out[name].cpi:.1f} is {off:+.0%} off the configured {before:g}: "
                f"is --distance right (metres: {distance:g} m = {distance * 1000:g} mm)?"
            )
    return out


def distance(session: Session, angle: float, min_runs: int = 2) -> DistanceResult:
    """Bonarini (18)-(19) for the session's two mice; ``angle`` in radians."""
    if len(session.names) != 2:
        raise UserError(
            f"calibrate distance takes exactly two mice, got {len(session.names)} "
            f"({', '.join(session.names)}): choose them with --mice A,B"
        )
    a, b = (session.config.mouse(n) for n in session.names)
    counts = run_counts(session.recording, session.runs, session.names)
    if len(session.runs) == 0:
        raise UserError("calibrate distance: no runs: the mice never moved")
    _no_motion(session, counts)
    d1 = body_frame(a, counts[:, 0, 0], counts[:, 0, 1])
    d2 = body_frame(b, counts[:, 1, 0], counts[:, 1, 1])
    # A bump is told by how far the mice moved, not by how differently: a push moves
    # them alike (a difference near 0), and must reach calibrate_distance's error for
    # that, not be left out as a bump.
    moved = np.maximum(np.hypot(*d1.T), np.hypot(*d2.T))
    keep = _keep_real_runs(session, moved, "distance")
    line = np.array([b.mount.x - a.mount.x, b.mount.y - a.mount.y])
    try:
        result = calibrate_distance(d1[keep], d2[keep], angle, line, min_runs=min_runs,
                                    numbers=(np.flatnonzero(keep) + 1).tolist())  # fmt: skip
    except DistanceError as e:
        raise UserError(f"calibrate distance ({a.name}, {b.name}): {e}") from None
    # A distance far from the drawing's is most often a wrong --angle (radians given for
    # degrees, a half turn for a quarter): say so rather than let --write store it quietly.
    nominal = float(np.hypot(*line))
    if nominal > 0 and abs(result.distance / nominal - 1) > DRAWING_TOLERANCE:
        result.hints.append(
            f"the distance {result.distance * 1000:.1f} mm is {result.distance / nominal - 1:+.0%} "
            f"off the configured {nominal * 1000:.1f} mm: is --angle right (in degrees)?"
        )
    return result


def _refuse_unfit(ref: Reference, session: Session, w: np.ndarray, size: float) -> None:
    """A UserError where the reference is in other units, or its motion ``w`` cannot give
    mounts (``motion_problem``)."""
    problem = _units_hint(ref, session) or motion_problem(w, size)
    if problem:
        raise UserError(f"calibrate mounts: {problem}")


def _units_hint(ref: Reference, session: Session) -> str:
    """Where a reference's numbers look like other units than REF.csv's (s, m/s, rad/s),
    what says so ("" where none): refused before any fit.  omega in degrees per second
    fitted every mount 57 times too close to the turns' centre with a residual of 7 um
    and exit 0 (a mouse 150 mm ahead at 2.6 mm), or read as turns about one point; t in
    milliseconds as no motion at all.  No calibration drive turns at 20 rad/s (three
    turns a second) nor moves at 10 m/s, and a reference longer than a hundred times the
    capture is no reference of it."""
    said = []
    if ref.kind == "twist" and len(ref.values):
        top = np.abs(ref.values).max(axis=0)
        # where: a single sample far out (a logger's glitch) is found by its time
        at = ref.t[np.argmax(np.abs(ref.values), axis=0)]
        if top[2] > 20.0:
            said.append(f"its omega reaches {top[2]:g} rad/s: degrees per second? (at t = "
                        f"{at[2]:.3f} s)")  # fmt: skip
        if max(top[0], top[1]) > 10.0:
            k = int(top[1] > top[0])
            said.append(f"its vx, vy reach {top[k]:g} m/s: millimetres per second? (at t = "
                        f"{at[k]:.3f} s)")  # fmt: skip
    spans = [float(r.t[-1] - r.t[0]) for r in session.recording.values() if len(r.t) > 1]
    if len(ref.t) > 1 and spans and float(ref.t[-1] - ref.t[0]) > 100.0 * max(spans):
        said.append(f"its t spans {float(ref.t[-1] - ref.t[0]):g} s where the capture spans "
                    f"{max(spans):.3g} s: milliseconds?")  # fmt: skip
    if not said:
        return ""
    return f"the reference {ref.path or ''}: {'; '.join(said)} (REF.csv is in s, m/s, rad/s)"


def spread_mounts(config: Config, names: Sequence[str], d: float) -> dict[str, tuple[float, float]]:
    """New positions of the two mice: same midpoint and direction, distance ``d`` apart."""
    a, b = (config.mouse(n) for n in names)
    pa, pb = np.array([a.mount.x, a.mount.y]), np.array([b.mount.x, b.mount.y])
    gap = float(np.linalg.norm(pb - pa))
    if not gap > 0:
        raise UserError(
            f"--write: mice {a.name} and {b.name} sit at one point in the config, so the "
            "line to spread them along is unknown: set their mounts roughly, then write again"
        )
    mid, u = (pa + pb) / 2, (pb - pa) / gap
    return {a.name: tuple(mid - u * d / 2), b.name: tuple(mid + u * d / 2)}


PAUSE_MOTION = 0.02  # reference motion in a pause, as a fraction of a run's: a cut run
CLOCK_SLACK = 0.05  # seconds the reference's clock may be off the mice's in that check
PATH_STEP = 0.01  # seconds: the reference's path length is summed over steps this long


def _scaled_steps(
    ref: Reference, t0: float, t1: float, geo: WheelGeometry | None, size: float
) -> np.ndarray:
    """The reference's twist over steps of PATH_STEP across [t0, t1], turns times ``size``
    (as in ``motion_problem``); no rows where the span is empty."""
    if not t1 > t0:
        return np.zeros((0, 3))
    edges = np.linspace(t0, t1, max(2, min(100_000, math.ceil((t1 - t0) / PATH_STEP)) + 1))
    return window_twist(ref, edges, geo) * np.array([1.0, 1.0, size])


def _path_length(steps: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(steps, axis=1)))


def _excursion(steps: np.ndarray) -> float:
    """How far the reference gets from where it was at the span's start: its noise, which
    a path length would add up, mostly cancels."""
    return float(np.max(np.linalg.norm(np.cumsum(steps, axis=0), axis=1), initial=0.0))


def _reference_still_in_pauses(
    session: Session,
    ref: Reference,
    edges: Sequence[np.ndarray],
    geo: WheelGeometry | None,
    gap: float,
    period: float,
    size: float,
) -> None:
    """Raise when the reference moves where every mouse was still: in a pause between two
    runs, or within ``gap`` before the first run or after the last one.

    Runs are cut where the mice were still for longer than ``gap``, so reference motion
    there means the mice did not see it: most often a capture that ends (or begins) in the
    middle of a motion, whose run would be fitted to only part of the reference's motion
    and give wrong mounts with a small residual.  A pause begins one report ``period`` plus
    CLOCK_SLACK after a run's last motion report (and ends as long before the next run's
    first), so that a reference whose clock is a few milliseconds off is not refused.
    """
    runs = session.runs
    paths = [_path_length(_scaled_steps(ref, e[0], e[-1], geo, size)) for e in edges]
    margin = period + CLOCK_SLACK
    # Within ``gap`` of each run only: a noisy reference wanders over a long pause (its
    # excursion grows as the square root of the time), and a cut shows right at the run.
    pauses = [(max(ref.t[0], runs[0].t0 - gap), runs[0].t0 - margin, 0, "begin")]
    for k, (r, n) in enumerate(zip(runs[:-1], runs[1:], strict=True)):
        pauses.append((r.t1 + margin, min(r.t1 + gap, n.t0 - margin), k, ""))
        pauses.append((max(n.t0 - gap, r.t1 + margin), n.t0 - margin, k, ""))
    pauses += [(runs[-1].t1 + margin, min(ref.t[-1], runs[-1].t1 + gap), len(runs) - 1, "end")]
    for a, b, k, cut in pauses:
        nearby = [paths[j] for j in (k, k + 1) if j < len(runs) and (cut == "" or j == k)]
        moved = _excursion(_scaled_steps(ref, a, b, geo, size))
        if not min(nearby) > 0 or not moved > PAUSE_MOTION * min(nearby):
            continue
        where = {
            "begin": f"before run 1 ({runs[0].t0:.3f} s): the captures begin",
            "end": f"after run {k + 1} (to {runs[k].t1:.3f} s): the captures end",
            "": f"between runs {k + 1} and {k + 2}: a mouse missed a motion, or",
        }[cut]
        why = "in the middle of a motion" if cut else "the clocks differ"
        raise UserError(
            located(
                ref.path,
                None,
                f"the reference moves at t = {a:.3f} .. {b:.3f} s, where every mouse was "
                f"still ({moved / min(nearby):.0%} of a run's motion), {where} {why}; the "
                "mounts would be fitted to part of a motion",
            )
        )


@dataclass
class MountsResult:
    method: str
    fits: dict[str, MountFit]  # exact: everything estimated; kimlee: yaw, scale as configured
    windows: int
    rank: int | None = None  # kimlee: rank of S (below 2N: minimum-norm solution)
    warnings: list[str] = field(default_factory=list)


def mounts(
    session: Session,
    ref: Reference,
    method: str = "exact",
    geo: WheelGeometry | None = None,
    window: float = 0.25,
    gap: float = 0.5,
) -> MountsResult:
    """Kim & Lee or exact mount calibration against the reference motion; ``gap``: the
    pause that split the runs (``split_runs``)."""
    if not session.runs:
        raise UserError("calibrate mounts: no runs: the mice never moved")
    mice = [session.config.mouse(n) for n in session.names]
    period = max(1.0 / m.report_hz for m in mice)
    if 0 < window < period:
        # Shorter windows hold less than one report each (and a tiny one would ask for
        # billions of windows): they cannot say more than one window per report.
        slow = max(mice, key=lambda m: 1.0 / m.report_hz)
        raise UserError(
            f"calibrate mounts: --window {window:g} s is shorter than one report period "
            f"({period * 1000:.3g} ms, mouse {slow.name}): give 0 (one window per run) or "
            f"at least {period:g}"
        )
    for r in session.runs:
        check_coverage(ref, r.t0 - period, r.t1, slack=period)
    edges = run_windows(session.runs, window, period)
    # Runs start and end at rest: widen each run's outer edges into the pauses around it
    # (up to PAD, never past halfway to the next run), so that a reference whose clock lags
    # or leads the mice's by some milliseconds still has all of its motion inside.
    starts = np.array([r.t0 for r in session.runs])
    ends = np.array([r.t1 for r in session.runs])
    room = (starts - np.concatenate([[-np.inf], ends[:-1]])) / 2
    after = (np.concatenate([starts[1:], [np.inf]]) - ends) / 2
    for k, e in enumerate(edges):
        e[0] -= max(0.0, min(PAD, room[k] - period))
        e[-1] += max(0.0, min(PAD, after[k]))
    size = max([0.05] + [math.hypot(m.mount.x, m.mount.y) for m in mice])
    units = _units_hint(ref, session)  # before the pauses' check: the likelier cause
    if units:
        raise UserError(f"calibrate mounts: {units}")
    _reference_still_in_pauses(session, ref, edges, geo, gap, period, size)
    w = np.concatenate([window_twist(ref, e, geo) for e in edges])
    counts = np.zeros((len(w), len(mice), 2))
    # A report covers the time since its mouse's previous one within late_report_s (a USB
    # catch-up), as in the fusion; never across a pause that split two runs.
    bridge = min(session.config.late_report_s, gap)
    for j, m in enumerate(mice):
        rep = session.recording[m.name]
        for axis, values in enumerate((rep.dx, rep.dy)):
            counts[:, j, axis] = runs_window_counts(rep.t, values, edges, 1.0 / m.report_hz, bridge)
    _no_motion(session, counts)
    _refuse_unfit(ref, session, w, size)
    if method == "exact":
        fits = {}
        for j, m in enumerate(mice):
            reading = mouse_frame(m, counts[:, j, 0], counts[:, j, 1])
            try:
                fits[m.name] = exact_mount(reading, w)
            except MountError as e:
                said = f" (it says flip: {str(m.flip).lower()})" if "`flip`" in str(e) else ""
                raise UserError(f"mouse {m.name}: {e}{said}") from None
            if not fits[m.name].axes_seen:
                session.notes.append(_axes_unseen(m.name, ref.kind == "wheels"))
        return MountsResult("exact", fits, len(w))
    if method != "kimlee":
        raise ValueError(f"unknown method {method!r}")
    v_s = np.stack(
        [body_frame(m, counts[:, j, 0], counts[:, j, 1]) for j, m in enumerate(mice)], axis=1
    )
    nominal = np.array([[m.mount.x, m.mount.y] for m in mice])
    res = kimlee(v_s, w, nominal)
    nan4 = (math.nan,) * 4
    fits = {
        m.name: MountFit(
            float(res.positions[j, 0]),
            float(res.positions[j, 1]),
            m.mount.yaw,
            1.0,
            nan4,
            math.nan,
            res.rank,
        )
        for j, m in enumerate(mice)
    }
    warnings = []
    if res.rank < res.unknowns:
        warnings.append(
            f"Kim & Lee: S has rank {res.rank} < {res.unknowns} unknowns; the "
            "minimum-norm solution is reported (as in their example)"
        )
    if len(w) < 2 * len(mice) - 2:
        warnings.append(
            f"Kim & Lee (49): {len(w)} measurements, they need at least {2 * len(mice) - 2}"
        )
    return MountsResult("kimlee", fits, len(w), res.rank, warnings)


def _axes_unseen(name: str, wheels: bool) -> str:
    """What to say of a mouse whose two axes' scales the motion cannot tell apart."""
    how = (
        "a differential drive never slides: measure one axis with `calibrate cpi`"
        if wheels
        else "add sideways motion, or measure one axis with `calibrate cpi`"
    )
    return (
        f"mouse {name}: the motion cannot tell its x scale from its y scale (without "
        "sideways motion they, its yaw and its position are one unknown too many): one "
        f"scale is fitted for both, and the CPIs and the position assume their configured "
        f"ratio ({how})"
    )


def implausible_mounts(result: MountsResult, config: Config) -> list[str]:
    """Warnings for the CPIs an exact fit's scales give that no mouse reports
    (``plausible.cpi_problem``): not stored without --force."""
    out: list[str] = []
    if result.method != "exact":
        return out
    for name, fit in result.fits.items():
        m = config.mouse(name)
        per = {"x": (fit.scale_x, m.cpi_x * fit.scale_x), "y": (fit.scale_y, m.cpi_y * fit.scale_y)}
        if per["x"] == per["y"]:
            per = {"x and y": per["x"]}
        for axis, (scale, cpi) in per.items():
            problem = plausible.cpi_problem(cpi)
            if problem:
                out.append(f"mouse {name}: scale {scale:.6g} gives cpi {axis}: {problem}")
    return out
