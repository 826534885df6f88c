"""The fusion engine: asynchronous reports in, poses at the output rate out.

Time is cut into windows of length T = 1/rate_hz on a grid starting at ``t0``.  A report
stamped t covers the motion since its mouse's previous report, but never more than one
report period P back: it covers [max(t_prev, t - P), t].  Each mouse's counts therefore
form a cumulative count function F(t) that is flat between reports and rises linearly
over each report's span.  A window's counts are F(end) - F(start): a report that straddles
a window edge is split in proportion to time (which removes the heading jitter of naive
bucketing), and the totals telescope, so every count lands in exactly one window or is
split into parts that sum to it.

A window closes once its end is behind every live mouse's frontier: the time up to which
that mouse's motion is final.  That is its last report time, or, once the caller declares
that all reports stamped up to tau have been pushed (``complete_until``), tau - P (a later
report can still reach P back).  A silent mouse therefore does not hold the output back:
the daemon calls ``complete_until(now - margin)`` on every tick.

The tracker does no I/O and has no clock: time is data, so replay (millions of windows at
once) and the daemon (a few at a time) run exactly the same code.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, cast

import numpy as np

from mousedom import core
from mousedom.config import Config
from mousedom.fusion import noiserate, robust, scalelearn
from mousedom.fusion.choices import GYRO
from mousedom.fusion.countfunction import CountFunction
from mousedom.fusion.evidence import SensorEvidence
from mousedom.fusion.geometry import rank_problem
from mousedom.fusion.posebatch import PoseBatch
from mousedom.fusion.tracker_batch import ArrayPath
from mousedom.fusion.tracker_learn import Learners, Renewal
from mousedom.fusion.tracker_one import OneWindowPath
from mousedom.fusion.tracker_state import Carried, PathSetup, WindowGrid
from mousedom.fusion.units import counts_matrices, sigma_metres

if TYPE_CHECKING:
    from mousedom.fusion.tracker_gyro import GyroClock


def _counts_array(c) -> np.ndarray:
    """Counts as an array: signed integers as they are (CountFunction.ingest sums them as
    int64), anything else as float64."""
    a = np.asarray(c)
    if a.dtype.kind == "i":
        return a
    return np.asarray(c, dtype=np.float64)


def fusion_terms(config: Config) -> tuple:
    """What a Tracker is built from: its reads of ``config``, the sensors' sources left
    out (a mouse's evdev node, serial port or capture).  Two configs with equal terms build
    the same tracker (``Tracker.go_on``)."""
    mice = tuple(
        dataclasses.replace(m, evdev=None, serial=None, replay=None, replay_device=None)
        for m in config.mice
    )
    gyro = None if config.gyro is None else config.gyro.own()
    return (config.model, config.integrator, config.rate_hz, config.late_report_s, mice,
            config.robust, gyro)  # fmt: skip


class Tracker:
    """Fuses the reports of a rig's mice into poses.  See the module docstring.

    Composed of parts: a ``CountFunction`` per mouse (its reports, knots and liveness),
    the two solving paths (``ArrayPath``, ``OneWindowPath``) over one ``Carried`` pose, the
    fault screen (``robust.Screen``) and the ``Learners``.  The tracker keeps the window
    grid and decides which path closes which windows."""

    def __init__(
        self,
        config: Config,
        *,
        t0: float | None = None,
        model: str | None = None,
        integrator: str | None = None,
    ) -> None:
        self.config = config
        self.model = model or config.model
        if model and model != config.model:  # the config was checked at load; an override not
            problem = rank_problem(model, [(m.mount.x, m.mount.y) for m in config.mice],
                                   config.names)  # fmt: skip
            if problem:
                raise ValueError(f"model {model}: {problem}")
        self.integrator = integrator or config.integrator
        self.period = 1.0 / config.rate_hz
        self._grid = WindowGrid(self.period, t0)
        self.n_mice = len(config.mice)
        self._mice = [CountFunction(1.0 / m.report_hz, config.late_report_s)
                      for m in config.mice]  # fmt: skip
        self._names = {m.name: i for i, m in enumerate(config.mice)}
        # (N,2,2) counts -> body metres: the config's, or with the learnt scales applied;
        # the tracker's (and tests') record of it, handed to the paths by _rebind
        self._to_body = counts_matrices(config.mice)
        positions = np.array([[m.mount.x, m.mount.y] for m in config.mice])
        sigma = np.array([sigma_metres(m) for m in config.mice])
        # A gyro (config.gyro): its samples' integral is a count function as a mouse's
        # counts are, closed with the same edges; it is sensor N in _clocks (after the
        # mice), named "gyro" in complete_each / set_live.
        self._gyro: GyroClock | None = None
        gyro_fusion = None
        if config.gyro is not None:  # (late: a rig without one loads none of it)
            from mousedom.fusion.tracker_gyro import gyro_parts

            self._gyro, gyro_fusion = gyro_parts(config, self.model, positions, sigma)
            self._names[GYRO] = self.n_mice
        # every count function whose frontier holds the windows back
        self._clocks = self._mice + ([self._gyro] if self._gyro is not None else [])
        self._complete_all = -math.inf
        self._counts_out = [[0.0, 0.0] for _ in range(self.n_mice)]  # see counts_out
        self.screen: robust.Screen | None = None
        if config.robust.enabled and self.n_mice:
            self.screen = robust.Screen(
                self.model, positions, sigma,
                np.array([1.0 / m.report_hz for m in config.mice]), self.period,
                config.robust,
                np.array([m.max_speed or math.inf for m in config.mice]),
            )  # fmt: skip
        setup = PathSetup(self.model, self.integrator, positions, sigma, self.period,
                          self.screen, gyro_fusion)  # fmt: skip
        self._carried = Carried.origin()
        self._batch = ArrayPath(setup, self._carried)
        self._one = OneWindowPath(setup, self._carried)
        # Online scale calibration and noise (Learners): with the fault screen, where a
        # mouse's reading is redundant. The scales need three or more mice (two others to
        # predict one), and are reported, and folded into _to_body where the config says
        # so (robust.learn_scale); the noise needs two (noiserate: one factor of sigma^2
        # on two lsq mice), and no model of bonarini's (no linear estimator).
        self._learners: Learners | None = None
        if self.screen is not None and (
            self.n_mice >= 3 or (self.n_mice == 2 and self.model != "bonarini")
        ):
            self._learners = Learners(
                setup, self._to_body, np.array([m.sigma for m in config.mice]), config.robust
            )
        self._rebind()
        self.evidence = SensorEvidence(
            [1.0 / m.report_hz for m in config.mice], [m.min_squal for m in config.mice]
        )

    @property
    def scales(self) -> scalelearn.ScaleLearner | None:
        """The online scale learner (None: not learnt, see __init__; two mice have the
        learners for the noise, and nothing of scales to report)."""
        learners = self._learners
        return None if learners is None or not learners.scales.active else learners.scales

    @property
    def noise_rate(self) -> noiserate.NoiseRate | None:
        """The covariance's noise learner (None: not learnt)."""
        return None if self._learners is None else self._learners.noise_rate

    def _rebind(self) -> None:
        """Hand both paths what the learners renew: the counts matrices, the noise model
        (None: the config's sigma) and the scales reported.  The paths hold these from
        one rebind to the next; they never read them off the tracker."""
        learners, scales = self._learners, self.scales
        noise = None if learners is None else learners.noise
        scale = None if scales is None else scales.estimate
        self._batch.rebind(self._to_body, noise, scale)
        self._one.rebind(self._to_body, noise, scale)

    def settle(self) -> None:
        """Learn from the blocks that ``poll(defer_learning=True)`` filled, if it did.

        A learners' block end (every 0.5 s) costs 1.5-2 ms, ten times a window, and the
        screen's noise model's (every second) 0.4 ms: in the window that ends the block it
        stood between the last report and the POSE, and set the p99 of the daemon's
        latency.  What it learns is for the windows after that one, so the daemon publishes
        first and settles then.  Every method that sets the pose or closes windows settles
        first, so the results are those of learning at once.  Reads (``pose``,
        ``pose_cov``, the learners' ``scales``, ``noise_rate``, ``screen``) do not, and
        may come from another thread (the metrics'): between the two they give the
        published window's state, without what the learning gives back or renews.
        """
        if self.screen is not None:  # (first, as when it learns within the window)
            self.screen.settle()
        learners = self._learners
        if learners is not None and learners.due:
            renewal = learners.end_block()
            if renewal is not None:
                self._renew(renewal)

    @property
    def learning_due(self) -> bool:
        """A block ``poll(defer_learning=True)`` ended that ``settle`` has not learnt from."""
        learners = self._learners
        return (self.screen is not None and self.screen.block_due) or (
            learners is not None and learners.due
        )

    def _renew(self, renewal: Renewal) -> None:
        """A learner's block end (``Learners.add``): new scales applied, if any, with the
        pose moved by what they would have given meanwhile; then the paths rebound."""
        if renewal.to_body is not None:
            self._to_body = renewal.to_body
            self._carried.give_back(renewal.turn, renewal.walk)
        if renewal.cov_add is not None:
            self._carried.cov = (np.array(self._carried.cov) + renewal.cov_add).tolist()
        if self.screen is not None:
            if renewal.faults:
                self.screen.exclude_faulty(renewal.faults)
            self.screen.hold_beyond(renewal.beyond)
        self._rebind()

    # ------------------------------------------------------------------ inputs

    def _index(self, mouse: int | str) -> int:
        return self._names[mouse] if isinstance(mouse, str) else int(mouse)

    def _start(self, t: float) -> None:
        self._grid.start(t)

    @property
    def t0(self) -> float | None:
        """The window grid's start (None until the first report or completion)."""
        return self._grid.t0

    @property
    def frontier_time(self) -> float:
        """End of the last closed window (the start of the grid before any)."""
        return self._grid.frontier

    def push(self, mouse: int | str, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
        """Add one mouse's reports (stamps non-decreasing; counts in evdev convention).

        Reports are only queued here and turned into knots when windows close, once per
        mouse per poll: a live source pushes a few reports at a time, and numpy's cost per
        call, not per element, would otherwise dominate the daemon's CPU use.
        """
        i = self._index(mouse)
        if type(t) is list and type(dx) is list and type(dy) is list:
            # A live read's few reports as Python numbers (float times, int counts from
            # evdev): queued as copies, no numpy at all.  Ints add up exactly as the
            # array path's float64 do (counts are far below 2**53).
            if not len(t) == len(dx) == len(dy):
                raise ValueError(f"push: t, dx, dy must be of one length, got "
                                 f"{len(t)}, {len(dx)}, {len(dy)}")  # fmt: skip
            if t and len(t) <= self._INGEST_SMALL * self._LIST_SCALE:
                self._queue_small(self._mice[i], t[:], dx[:], dy[:])
                return
        t = np.asarray(t, dtype=np.float64)
        dx, dy = _counts_array(dx), _counts_array(dy)
        if not (t.ndim == 1 and t.shape == dx.shape == dy.shape):
            raise ValueError(f"push: t, dx, dy must be 1-D of one length, got "
                             f"{t.shape}, {dx.shape}, {dy.shape}")  # fmt: skip
        if t.size == 0:
            return
        m = self._mice[i]
        if t.size <= self._INGEST_SMALL:
            # A live read's few reports: queued as floats, which ingest_small wants.
            self._queue_small(m, t.tolist(), dx.tolist(), dy.tolist())
            return
        # One sum each is NaN or inf if any element is: cheaper than isfinite per element
        # (integer counts are finite: only float ones are summed).
        total = t.sum()
        for c in (dx, dy):
            if c.dtype.kind != "i":
                total += c.sum()
        if not math.isfinite(total):
            raise ValueError("push: times and counts must be finite numbers")
        self._start(t[0])
        m.queue(t, dx, dy, float(t.max()))

    def push_quality(
        self, mouse: int | str, t: list, squal: list, overflow: list, lost_from: list | None = None
    ) -> None:
        """The sensor's own word on reports pushed (or about to be): SQUAL (None where
        unknown), whether counts were lost (an overflow, or packets that never arrived),
        and for the latter the time since which (``fusion.evidence``)."""
        if self.screen is not None:
            self.evidence.push(self._index(mouse), t, squal, overflow, lost_from)

    def push_gyro(
        self,
        t: np.ndarray | list,
        rate: np.ndarray | list,
        saturated: np.ndarray | list | None = None,
    ) -> None:
        """The gyro's samples: stamps and yaw rates (rad/s, CCW positive), each the mean
        rate since the sample before, and which of them were read at the converter's limit
        (``saturated``, None: none; those windows take no gyro turn: tracker_gyro.GyroClock)."""
        if self._gyro is None:
            raise ValueError("push_gyro: the config has no gyro")
        first = self._gyro.push(t, rate, saturated)
        if first is not None:
            self._start(first)

    def _queue_small(self, m: CountFunction, t: list, dx: list, dy: list) -> None:
        # One sum each is NaN or inf if any element is: cheaper than a test per element.
        try:
            finite = math.isfinite(sum(t) + sum(dx) + sum(dy))
        except TypeError:
            finite = False  # not real numbers (str, None, complex...)
        if not finite:
            raise ValueError("push: times and counts must be finite numbers")
        self._start(t[0])
        m.queue(t, dx, dy, max(t))

    def _ingest(self, m: CountFunction, edge: float | None = None) -> None:
        """Turn a mouse's queued reports into knots (floats for a few, arrays for many);
        ``edge``: the closed frontier, if the caller has it."""
        pending = m.pending
        if not pending:
            return
        if edge is None:
            edge = self.frontier_time
        # one read's reports (the daemon's case) without summing over the queue
        queued = len(pending[0][0]) if len(pending) == 1 else m.queued()
        small = self._INGEST_SMALL * (self._LIST_SCALE if type(pending[0][0]) is list else 1)
        if queued <= small and len(m.knots[0]) <= self._KNOTS_SMALL:
            m.ingest_small(edge)
        else:
            m.ingest(edge)

    # Up to this many queued reports (and knots already held), reports become knots on
    # Python floats and lists (the daemon's few reports per window); tests set it to 0 to
    # compare with the array path.
    _INGEST_SMALL = 64
    _KNOTS_SMALL = 256
    # A live read's reports come as lists.  The compiled core's loops over them cost next
    # to nothing per report, where numpy's cost per call is tens of microseconds: with it,
    # lists stay on the list path up to this many times _INGEST_SMALL (a read of 80
    # reports: a mouse at 8 kHz, 100 windows a second).  Arrays (replay's chunks) keep
    # the array path, whose cost per report is far lower for thousands.
    _LIST_SCALE = 1 if core.native is None else 16

    def complete_until(self, t: float, mouse: int | str | None = None) -> None:
        """Declare that every report stamped <= t has been pushed (one mouse, or all)."""
        self._start(t)
        if mouse is None:
            self._complete_all = max(self._complete_all, t)
            for m in self._clocks:
                m.complete_to(t)
        else:
            self.complete_each([(self._index(mouse), t)])

    def complete_each(self, until: list[tuple[int, float]]) -> None:
        """For each (mouse index i, t): every report of mouse i stamped <= t has been
        pushed.  One call for all the live mice: the daemon's, every window."""
        clocks = self._clocks
        for i, t in until:
            self._start(t)
            clocks[i].complete_to(t)
            self._complete_all = max(self._complete_all, t)

    def set_live(self, mouse: int | str, live: bool, t: float) -> None:
        """A sensor vanished (live=False) or came back at time t.

        Windows that overlap a dead span do not use that mouse; the model goes on with
        the others while it has rank, and reports ok=False otherwise.  Back at or before
        the closed frontier (every window up to then could close), it is not used in the
        first window still open either (``CountFunction.declare_live``).
        """
        grid = self._grid
        first_end = -math.inf if grid.t0 is None else grid.edge(grid.closed + 1)
        self._clocks[self._index(mouse)].declare_live(live, t, first_end)

    def carry(self, old: Tracker, kept: Sequence[tuple[int, int]]) -> None:
        """Go on with the windows ``old`` left open (a reload; ``old`` is not used after):
        this tracker's grid starts at ``old``'s closed frontier, and a window closes here
        once final, as it would have there.  Closing them at the reload instead would close
        them before the slower mice's reports for them came (a report reaches a period
        back), and those counts would land in a later window.

        The pose goes on as it was, with its covariance (and the point that covariance is
        taken at): a reload changes how the rig is read from now on, not what is known of
        where it is (a ``reset`` to the same pose would zero the uncertainty).

        ``kept``: (index here, index in ``old``) of each sensor on an unchanged device.  It
        keeps its count function (its reports, what they owe the open windows, how far
        they are complete, its liveness and counters), its counts closed so far and its
        reports' evidence.  Any other was not read before: it is not live from the grid's
        start until declared live (``set_live``), or the windows before it opens would
        take it as standing still."""
        t0 = old.frontier_time
        if self.t0 != t0 or self._grid.closed:
            raise ValueError(f"carry: the grid must start at the old frontier {t0}, not {self.t0}")
        old.settle()  # (the pose with what the old windows' learning gave back)
        self._carried.take(old._carried)
        clocks = list(self._clocks)
        carried = set()
        for i, j in kept:
            clocks[i] = old._clocks[j].timed_as(clocks[i])
            carried.add(i)
            if i < self.n_mice:
                self._counts_out[i] = list(old._counts_out[j])
                self.evidence.spans[i] = old.evidence.spans[j]
        for i, m in enumerate(clocks):
            if i not in carried:
                m.declare_live(False, t0)
        self._clocks, self._mice = clocks, clocks[: self.n_mice]
        if self._gyro is not None:
            self._gyro = cast("GyroClock", clocks[self.n_mice])
        # how far any sensor's reports are complete: a time, whoever's (finish reads it)
        self._complete_all = max(self._complete_all, old._complete_all)

    def go_on(self, config: Config, kept: Sequence[tuple[int, int]]) -> bool:
        """A reload whose ``config`` builds this very tracker: go on as this one (True), with
        what its parts learnt (the scales, applied or not, the noise, each mouse's health,
        the gyro's bias), the reload's config its config from now on.  Where the fusion's
        terms changed (``fusion_terms``), or a sensor was not kept (``carry``'s ``kept``:
        its device changed), False: the caller builds a new tracker and carries the pose
        into it (``carry``), and the learning starts again.

        A new tracker learnt again every reload: a mouse whose CPI is 3 % off read 3 %
        off until its scale was plain again (a second or two of motion: up to 0.19 degrees of
        heading and 1.2 mm each time on a triangle, tests/test_reload_keeps_counts.py), a
        mouse held out for a fault was used again at once, and the noise tolerances the
        screen had learnt went back to the config's."""
        if (
            fusion_terms(config) != fusion_terms(self.config)
            or (self.model, self.integrator) != (config.model, config.integrator)
            or sorted(kept) != [(i, i) for i in range(len(self._clocks))]
        ):
            return False
        self.settle()
        self.config = config
        return True

    def is_live(self, mouse: int | str) -> bool:
        return self._clocks[self._index(mouse)].live

    # ------------------------------------------------------------------ pose commands

    @property
    def pose(self) -> tuple[float, float, float]:
        # (a read, so it does no work: the metrics thread reads it too; between
        # poll(defer_learning=True) and settle() it is the published window's pose)
        x, y, theta = self._carried.pose
        return x, y, theta

    @property
    def pose_cov(self) -> np.ndarray:
        return np.array(self._carried.cov)

    def reset(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> None:
        """Start the odometry frame again at the given pose, with zero uncertainty."""
        self.settle()
        self._carried.reset(x, y, theta)
        self._rebase(heading=True)

    def fix(
        self, x: float | None = None, y: float | None = None, theta: float | None = None
    ) -> None:
        """Absolute fix of some coordinates only (McGill's grid-line correction).

        The fixed coordinates take the given values and lose their uncertainty; the
        others, and their correlations with each other, are kept.
        """
        self.settle()
        self._carried.fix(x, y, theta)
        self._rebase(heading=theta is not None)

    def _rebase(self, heading: bool) -> None:
        """After the pose was set from outside (Learners.rebase; the gyro's heading error,
        if the heading was set)."""
        if self._learners is not None:
            self._learners.rebase()
        gyro = self._one.gyro
        if heading and gyro is not None:
            gyro.heading_set()

    # ------------------------------------------------------------------ outputs

    @property
    def counts_out(self) -> np.ndarray:
        """(N, 2) counts already in closed windows (REL_X, REL_Y per mouse)."""
        return np.array(self._counts_out, dtype=np.float64).reshape(self.n_mice, 2)

    @property
    def counts_in(self) -> np.ndarray:
        for m in self._mice:
            self._ingest(m)
        return np.array([m.counts_in for m in self._mice]).reshape(self.n_mice, 2)

    def stats(self) -> dict[str, dict[str, int]]:
        for m in self._mice:
            self._ingest(m)
        return {  # the mice's (the gyro's name is among the sensors', after them)
            name: {"late": self._mice[i].late, "backwards": self._mice[i].backwards}
            for name, i in self._names.items()
            if i < self.n_mice
        }

    def poll(self, defer_learning: bool = False, one_by_one: bool = False) -> PoseBatch:
        """Close every window that no future report can change.  ``defer_learning``:
        where one window closes (the daemon's case), the blocks it ends (the learners',
        the screen's noise model's) are learnt at ``settle()``, not here: the daemon
        publishes the window first.  Several windows (after a stall) learn as they go.
        ``one_by_one``: up to ``_SMALL`` windows close one after the other on floats (the
        daemon's few windows a poll), not as one array: the same poses but for their
        last bits, at a fraction of the array path's fixed cost.  Replay and the other
        batch users keep the array path, and so their output to the bit."""
        if self.t0 is None:
            return PoseBatch.empty(self.n_mice)
        # The earliest frontier of the live mice (a mouse that is not live waits for
        # nothing); a loop, not min() of a generator: this runs every window.
        target = math.inf if self._mice else self._complete_all
        edge = None
        for m in self._clocks:
            if m.pending and m.live:
                # the frontier is read off the knots (a report may join the last span)
                if edge is None:
                    edge = self.frontier_time
                self._ingest(m, edge)
            f = m.frontier() if m.live else self._complete_all
            if f < target:
                target = f
        if not math.isfinite(target):
            return PoseBatch.empty(self.n_mice)
        return self._close_until(self._grid.ending_by(target), defer_learning, one_by_one)

    def skip_quiet(self, until: float) -> tuple[float, float] | None:
        """Close the windows up to the last edge at or before ``until`` without solving
        them, when they are known to be empty: every mouse has all its counts closed, and
        the caller knows that no report will cover any time before ``until`` (the next
        report's own span, one period before its stamp, included).  Returns the skipped
        span (start, end), or None when nothing can be skipped.

        Replay uses this for a gap in time (a corrupted stamp, a recording paused for a
        day), so that its cost follows the reports, not the time span.  The pose and its
        covariance are held across the gap, as a windowed run of empty windows would hold
        the pose (its covariance would grow a little per window)."""
        if self.t0 is None:
            return None
        self.settle()
        k = self._grid.ending_by(until)
        if k <= self._grid.closed + 1:
            return None
        start = self.frontier_time
        for m in self._clocks:
            if m.pending:
                self._ingest(m)
            if not m.settled(start):
                return None  # counts still to close, or reports ahead of the frontier
        self._grid.closed = k
        end = self.frontier_time
        for m in self._clocks:
            m.skip_to(end)
        if self._one.gyro is not None:  # no window after the gap is the one before's neighbour
            self._one.gyro.spread.gap()
        return start, end

    def finish(self) -> PoseBatch:
        """End of a finite input: close every window up to the last report."""
        if self.t0 is None:
            return PoseBatch.empty(self.n_mice)
        last = max([m.last_t for m in self._clocks] + [self._complete_all])
        if last == -math.inf:
            return PoseBatch.empty(self.n_mice)
        k = self._grid.ending_by(last)
        if self._grid.edge(k) < last:
            k += 1  # the window that holds the last stamp
        out = [self._close_until(k)]
        while self._pending():
            # Counts that jump exactly on the last edge (or were moved onto the closed
            # frontier) still need one more window.
            out.append(self._close_until(self._grid.closed + 1))
        return PoseBatch.concat(out, self.n_mice)

    def _pending(self) -> bool:
        for m in self._clocks:
            self._ingest(m)
        return any(m.level().any() for m in self._clocks)

    def _close_until(
        self, k_new: int, defer_learning: bool = False, one_by_one: bool = False
    ) -> PoseBatch:
        self.settle()
        k_old = self._grid.closed
        if k_new <= k_old:
            return PoseBatch.empty(self.n_mice)
        edge = self.frontier_time
        small = k_new - k_old <= (self._SMALL if one_by_one else 1) and self.n_mice > 0
        for m in self._clocks:
            if m.pending:
                self._ingest(m, edge)
            if m.n_knots() > self._KNOTS_SMALL:
                small = False
        if small and (k_new - k_old == 1 or self.model != "bonarini"):
            if k_new - k_old == 1:
                return self._close_one(defer_learning)
            # A few windows at once (a second wake, a report rate that pairs windows up):
            # one by one, each learning at its block end as the array path does, the
            # last as the caller asks.  Warm after the first, each costs a fraction of
            # the array path's fixed cost (~0.7 ms a call); not bonarini's, whose one
            # window is that array path already.
            rows = [row for _ in range(k_new - k_old - 1) for row in self._close_one(False).rows()]
            rows += self._close_one(defer_learning).rows()
            return PoseBatch.from_rows(rows)
        n = k_new - k_old
        edges = self._grid.start_time() + self.period * np.arange(k_old, k_new + 1)
        counts = np.zeros((n, self.n_mice, 2))
        mask = np.ones((n, self.n_mice), dtype=bool)
        spans = np.zeros((n, self.n_mice))
        for i, m in enumerate(self._mice):
            m.close(edges, out=counts[:, i], spans=spans[:, i])
            m.close_live(edges, out=mask[:, i])
        long = spans if spans.any() else None  # windows cutting a long span (USB catch-up)
        self._grid.closed = k_new
        for acc, (cx, cy) in zip(self._counts_out, counts.sum(axis=0).tolist(), strict=True):
            acc[0] += cx
            acc[1] += cy
        evidence = self.evidence.windows(edges)
        turns = None if self._gyro is None else self._gyro.turns(edges)
        learners = self._learners
        if learners is None:
            return self._batch.solve(edges[1:], counts, mask, evidence, turns, long)
        # The learnt scales change at block ends: each block's windows with its own.
        out, a = [], 0
        while a < n:
            b = min(n, a + learners.until_block_end())
            ev = None if evidence is None else (evidence[0][a:b], evidence[1][a:b])
            start = self._carried.pose[:2]
            tb = None if turns is None else turns[a:b]
            lb = None if long is None else long[a:b]
            part = self._batch.solve(edges[a + 1 : b + 1], counts[a:b], mask[a:b], ev, tb, lb)
            renewal = learners.add(counts[a:b], part, mask[a:b], start, self._taken())
            if renewal is not None:
                self._renew(renewal)
            out.append(part)
            a = b
        return PoseBatch.concat(out, self.n_mice)

    def _close_one(self, defer_learning: bool) -> PoseBatch:
        """_close_until for the next window on Python floats: the daemon's case."""
        k = self._grid.closed
        start, end = self._grid.edge(k), self._grid.edge(k + 1)
        counts, live_list = [], []
        long = False
        for m, acc in zip(self._mice, self._counts_out, strict=True):
            cx, cy = m.close_one(end)
            counts.append((cx, cy))
            if m.window_span:
                long = True
            acc[0] += cx  # floats, not an array: numpy's += of a list cost 3 us a window
            acc[1] += cy
            live_list.append(not m.dead or m.live_in(start, end))
        live = tuple(live_list)
        gyro = self._gyro
        turn = None if gyro is None else gyro.turn_one(start, end)
        self._grid.closed = k + 1
        evidence = self.evidence.window(start, end) if self.evidence else None
        before = self._carried.pose[:2]
        spans = [m.window_span for m in self._mice] if long else None
        if self.model == "bonarini":  # numerical linearisation: the array path
            ev = None if evidence is None else (np.array([evidence[0]]), np.array([evidence[1]]))
            tb = None if gyro is None else np.array([math.nan if turn is None else turn])
            sb = None if spans is None else np.array([spans])
            batch = self._batch.solve(np.array([end]), np.array([counts]), np.array([live]),
                                      ev, tb, sb)  # fmt: skip
        else:
            batch = self._one.solve(end, counts, live, evidence, turn, spans, defer_learning)
        learners = self._learners
        if learners is not None:
            learners.add_row(counts, batch.rows()[0], live, before, self._taken())
        if not defer_learning:
            self.settle()
        return batch

    def _taken(self) -> list[tuple[int, int, int]]:
        """The screen's take-backs since the windows last handed to the learners
        (``Screen.hand_taken``): theirs not to give back again."""
        return [] if self.screen is None else self.screen.hand_taken()

    # Up to this many windows per poll(one_by_one=True), _close_one (floats, no
    # validation) is used, one window after the other (otherwise one window); tests set
    # it to 0 to compare it with the array path.  The array path's fixed cost is about
    # that of 15 windows on floats (4 mice, warm; docs/performance.md), and a poll of
    # more windows is a stall's catch-up.
    _SMALL = 8
