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

import math

import numpy as np

from mousedom.config import Config
from mousedom.fusion import integrate, models, noiserate, robust, scalelearn, screenbatch
from mousedom.fusion.countfunction import CountFunction
from mousedom.fusion.covariance import CovarianceState, propagate, world_step_noise
from mousedom.fusion.evidence import SensorEvidence
from mousedom.fusion.geometry import rank_problem
from mousedom.fusion.posebatch import PoseBatch
from mousedom.fusion.tracker_one import OneWindowPath
from mousedom.fusion.units import counts_matrices, sigma_metres


def _counts_array(c) -> np.ndarray:
    """Counts as an array: signed integers as they are (CountFunction.ingest sums them as
    int64), anything else as float64."""
    a = np.asarray(c)
    if a.dtype.kind == "i":
        return a
    return np.asarray(c, dtype=np.float64)


class Tracker(OneWindowPath):
    """Fuses the reports of a rig's mice into poses.  See the module docstring."""

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
        self.t0 = t0
        self.n_mice = len(config.mice)
        self._mice = [CountFunction(1.0 / m.report_hz, config.late_report_s)
                      for m in config.mice]  # fmt: skip
        self._names = {m.name: i for i, m in enumerate(config.mice)}
        self._to_body = counts_matrices(config.mice)  # (N,2,2)
        self._to_body_rows = self._to_body.tolist()  # the same, for the one-window path
        self._positions = np.array([[m.mount.x, m.mount.y] for m in config.mice])
        self._sigma = np.array([sigma_metres(m) for m in config.mice])
        # below these a reading is no count (models.STILL): in metres, and in counts
        self._still = (models.STILL * self._sigma).tolist()
        self._still_counts = models.STILL * np.array([m.sigma for m in config.mice])
        self._still_counts_list = self._still_counts.tolist()  # the one-window path's
        self._rate = 1.0 / self.period
        self._linear_cache: dict = {}  # live mice -> tracker_one.LinearPlan
        self._closed = 0  # number of windows closed so far
        self._complete_all = -math.inf
        # The carried state as Python floats (the one-window path's currency; the array
        # path converts on entry and exit): pose, its covariance and where that is taken.
        self._pose = [0.0, 0.0, 0.0]
        self._cov = [[0.0] * 3 for _ in range(3)]
        self._cov_at = [0.0, 0.0]
        self._counts_out = [[0.0, 0.0] for _ in range(self.n_mice)]  # see counts_out
        self.screen = None
        if config.robust.enabled and self.n_mice:
            self.screen = robust.Screen(
                self.model, self._positions, self._sigma,
                np.array([1.0 / m.report_hz for m in config.mice]), self.period,
                config.robust,
                np.array([m.max_speed or math.inf for m in config.mice]),
            )  # fmt: skip
        self._steady_rows = {}  # live pattern -> (state, reason) of the common case
        # Online scale calibration (fusion.scalelearn): with the fault screen, on three or
        # more mice; its estimates are reported, and folded into _to_body where the config
        # says so (robust.learn_scale).
        self.scales = None
        self._scale_row: list | tuple = ()  # the scales as PoseRow.scale ((): none)
        self._apply_scales = config.robust.learn_scale
        if self.screen is not None and self.n_mice >= 3:
            self.scales = scalelearn.ScaleLearner(
                self.model, self._to_body, self._positions, self._sigma, self.period,
                config.robust.scale_limit,
            )  # fmt: skip
            self._scale_row = self.scales.estimate.tolist()
        # The covariance's noise, learnt alongside (fusion.noiserate) in the same blocks;
        # None (the config's sigma) until learnt.
        self.noise_rate = None
        self._noise: models.StepNoise | None = None
        if self.scales is not None and self.model != "bonarini":
            self.noise_rate = noiserate.NoiseRate(
                self._positions, self._sigma, self.period, self.scales.block,
                (0, 2) if self.model == "diff-drive" else (0, 1, 2),
            )  # fmt: skip
        self.evidence = SensorEvidence(
            [1.0 / m.report_hz for m in config.mice], [m.min_squal for m in config.mice]
        )

    # ------------------------------------------------------------------ inputs

    def _index(self, mouse: int | str) -> int:
        return self._names[mouse] if isinstance(mouse, str) else int(mouse)

    def _start(self, t: float) -> None:
        if self.t0 is None:
            self.t0 = float(t)

    @property
    def frontier_time(self) -> float:
        """End of the last closed window (the start of the grid before any)."""
        return (self.t0 or 0.0) + self._closed * self.period

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
            if t and len(t) <= self._INGEST_SMALL:
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

    def push_quality(self, mouse: int | str, t: list, squal: list, overflow: list) -> None:
        """The sensor's own word on reports pushed (or about to be): SQUAL (None where
        unknown) and whether counts were lost to an overflow (``fusion.evidence``)."""
        if self.screen is not None:
            self.evidence.push(self._index(mouse), t, squal, overflow)

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
        if queued <= self._INGEST_SMALL and len(m.knots[0]) <= self._KNOTS_SMALL:
            m.ingest_small(edge)
        else:
            m.ingest(edge)

    # Up to this many queued reports (and knots already held), reports become knots on
    # Python floats and lists (the daemon's few reports per window); tests set it to 0 to
    # compare with the array path.
    _INGEST_SMALL = 64
    _KNOTS_SMALL = 256

    def complete_until(self, t: float, mouse: int | str | None = None) -> None:
        """Declare that every report stamped <= t has been pushed (one mouse, or all)."""
        self._start(t)
        if mouse is None:
            self._complete_all = max(self._complete_all, t)
            for m in self._mice:
                m.complete_to(t)
        else:
            self.complete_each([(self._index(mouse), t)])

    def complete_each(self, until: list[tuple[int, float]]) -> None:
        """For each (mouse index i, t): every report of mouse i stamped <= t has been
        pushed.  One call for all the live mice: the daemon's, every window."""
        for i, t in until:
            self._start(t)
            self._mice[i].complete_to(t)
            self._complete_all = max(self._complete_all, t)

    def set_live(self, mouse: int | str, live: bool, t: float) -> None:
        """A sensor vanished (live=False) or came back at time t.

        Windows that overlap a dead span do not use that mouse; the model goes on with
        the others while it has rank, and reports ok=False otherwise.
        """
        self._mice[self._index(mouse)].declare_live(live, t)

    def is_live(self, mouse: int | str) -> bool:
        return self._mice[self._index(mouse)].live

    # ------------------------------------------------------------------ pose commands

    @property
    def pose(self) -> tuple[float, float, float]:
        x, y, theta = self._pose
        return x, y, theta

    @property
    def pose_cov(self) -> np.ndarray:
        return np.array(self._cov)

    def reset(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> None:
        """Start the odometry frame again at the given pose, with zero uncertainty."""
        self._pose = [float(x), float(y), float(theta)]
        self._cov = [[0.0] * 3 for _ in range(3)]
        self._cov_at = self._pose[:2]
        self._rebase()

    def fix(self, x: float | None = None, y: float | None = None, theta: float | None = None):
        """Absolute fix of some coordinates only (McGill's grid-line correction).

        The fixed coordinates take the given values and lose their uncertainty; the
        others, and their correlations with each other, are kept.
        """
        cov = np.array(self._cov)
        for k, v in enumerate((x, y, theta)):
            if v is not None:
                self._pose[k] = float(v)
                cov[k, :] = 0.0
                cov[:, k] = 0.0
        self._cov = cov.tolist()
        self._cov_at = self._pose[:2]
        self._rebase()

    def _rebase(self) -> None:
        """After the pose was set from outside: the scales' give-back starts from here (it
        owes nothing for the turns and the walk before, and the jump is no step)."""
        if self.scales is not None:
            self.scales.rebase()

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
        return {
            name: {"late": self._mice[i].late, "backwards": self._mice[i].backwards}
            for name, i in self._names.items()
        }

    def poll(self) -> PoseBatch:
        """Close every window that no future report can change."""
        if self.t0 is None:
            return PoseBatch.empty(self.n_mice)
        # The earliest frontier of the live mice (a mouse that is not live waits for
        # nothing); a loop, not min() of a generator: this runs every window.
        target = math.inf if self._mice else self._complete_all
        edge = None
        for m in self._mice:
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
        return self._close_until(self._windows_ending_by(target))

    def _edge(self, k: int) -> float:
        """End of window k-1: computed exactly as _close_until computes its edges."""
        return self.t0 + self.period * k

    def _windows_ending_by(self, t: float) -> int:
        """The largest k with edge(k) <= t: no rounding tolerance, so whether a window may
        close never depends on how its end was rounded (batch and stream agree).

        The division is off by at most a step or two; where floats cannot tell edge k from
        edge k + 1 any more (times near 1e300 once looped here for ever), that is an input
        no window grid can hold, and it is refused."""
        k = math.floor((t - self.t0) / self.period)
        for _ in range(8):
            if self._edge(k + 1) <= t:
                k += 1
            elif k > 0 and self._edge(k) > t:
                k -= 1
            else:
                return k
        raise ValueError(
            f"time {t!r} is beyond what a window grid of {self.period!r} s from {self.t0!r} "
            "can resolve"
        )

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
        k = self._windows_ending_by(until)
        if k <= self._closed + 1:
            return None
        start = self.frontier_time
        for m in self._mice:
            if m.pending:
                self._ingest(m)
            kt, kx, ky = m.knots if type(m.knots) is tuple else m.knots.tolist()
            if any(kx) or any(ky) or (kt and kt[-1] > start):
                return None  # counts still to close, or reports ahead of the frontier
        self._closed = k
        end = self.frontier_time
        for m in self._mice:
            m.skip_to(end)
        return start, end

    def finish(self) -> PoseBatch:
        """End of a finite input: close every window up to the last report."""
        if self.t0 is None:
            return PoseBatch.empty(self.n_mice)
        last = max([m.last_t for m in self._mice] + [self._complete_all])
        if last == -math.inf:
            return PoseBatch.empty(self.n_mice)
        k = self._windows_ending_by(last)
        if self._edge(k) < last:
            k += 1  # the window that holds the last stamp
        out = [self._close_until(k)]
        while self._pending():
            # Counts that jump exactly on the last edge (or were moved onto the closed
            # frontier) still need one more window.
            out.append(self._close_until(self._closed + 1))
        return PoseBatch.concat(out, self.n_mice)

    def _pending(self) -> bool:
        for m in self._mice:
            self._ingest(m)
        return any(m.level().any() for m in self._mice)

    def _close_until(self, k_new: int) -> PoseBatch:
        k_old = self._closed
        if k_new <= k_old:
            return PoseBatch.empty(self.n_mice)
        edge = self.frontier_time
        small = k_new - k_old <= self._SMALL and self.n_mice > 0
        for m in self._mice:
            if m.pending:
                self._ingest(m, edge)
            if len(m.knots[0]) > self._KNOTS_SMALL:  # (n_knots, for lists or the array)
                small = False
        if small:
            return self._close_one()
        n = k_new - k_old
        edges = self.t0 + self.period * np.arange(k_old, k_new + 1)
        counts = np.zeros((n, self.n_mice, 2))
        mask = np.ones((n, self.n_mice), dtype=bool)
        end_t = float(edges[-1])
        for i, m in enumerate(self._mice):
            m.close(edges, out=counts[:, i])
            if m.dead:
                for start, end in m.dead:
                    mask[(edges[:-1] < end) & (edges[1:] > start), i] = False
                m.forget_dead(end_t)
        self._closed = k_new
        for acc, (cx, cy) in zip(self._counts_out, counts.sum(axis=0).tolist(), strict=True):
            acc[0] += cx
            acc[1] += cy
        evidence = self.evidence.windows(edges)
        if self.scales is None:
            return self._solve(edges[1:], counts, mask, evidence)
        # The learnt scales change at block ends: each block's windows with its own.
        out, a = [], 0
        while a < n:
            b = min(n, a + self.scales.until_block_end())
            ev = None if evidence is None else tuple(e[a:b] for e in evidence)
            start = self._pose[:2]
            part = self._solve(edges[a + 1 : b + 1], counts[a:b], mask[a:b], ev)
            self._learn_scales(counts[a:b], part, mask[a:b], start)
            out.append(part)
            a = b
        return PoseBatch.concat(out, self.n_mice)

    def _learn_scales_row(
        self, counts: list, row, live: tuple[bool, ...], start: list[float]
    ) -> None:
        """``_learn_scales`` for the one window the daemon closed, on Python values."""
        tracking, excluded, inconsistent = robust.TRACKING, robust.EXCLUDED, robust.INCONSISTENT
        ok = row.consistent
        usable = [ok and v and st == tracking for v, st in zip(live, row.state, strict=True)]
        held = [v and st == excluded and why == inconsistent
                for v, st, why in zip(live, row.state, row.reason, strict=True)]  # fmt: skip
        per = self.period
        q = [row.vx * per, row.vy * per, row.omega * per] if row.ok else [0.0, 0.0, 0.0]
        if self.noise_rate is not None:
            still = self._still_counts_list
            moving = any(abs(c[0]) > e or abs(c[1]) > e
                         for c, v, e in zip(counts, live, still, strict=True) if v)  # fmt: skip
            eligible = all(usable) and row.used == self.n_mice  # every mouse in the solve
            if self.noise_rate.add_row(row.residual, eligible, moving):
                self._noise_renewed()
        step = [row.x - start[0], row.y - start[1]]
        if self.scales.add_row(counts, usable, held, q, step):
            self._scales_renewed()

    def _learn_scales(
        self, counts: np.ndarray, batch: PoseBatch, live: np.ndarray, start: list[float]
    ) -> None:
        """Hand closed windows to the scale learner (mice tracking in consistent windows
        are its evidence, and the ones left out as inconsistent, against the others'
        motion); at a block end its new scales take effect."""
        state, reason = batch.state, batch.reason
        usable = (state == robust.TRACKING) & batch.consistent[:, None] & live
        held_out = (state == robust.EXCLUDED) & (reason == robust.INCONSISTENT) & live
        q = np.stack([batch.vx, batch.vy, batch.omega], axis=1) * self.period
        q[~batch.ok] = 0.0
        if self.noise_rate is not None:
            counted = (np.abs(counts) > self._still_counts[None, :, None]).any(axis=2)
            moving = np.any(counted & live, axis=1)
            eligible = usable.all(axis=1) & (batch.used == self.n_mice)  # all in the solve
            if self.noise_rate.add(batch.residual, eligible, moving):
                self._noise_renewed()
        xy = np.stack([np.concatenate([[start[0]], batch.x]),
                       np.concatenate([[start[1]], batch.y])], axis=1)  # fmt: skip
        if self.scales.add(counts, usable, held_out, q, np.diff(xy, axis=0)):
            self._scales_renewed()

    def _noise_renewed(self) -> None:
        if self.noise_rate is not None and self.noise_rate.noise is not self._noise:
            self._noise = self.noise_rate.noise
            self._linear_cache.clear()  # the one-window plans hold the covariance

    def _scales_renewed(self) -> None:
        turn, walk = self.scales.take_turn(), self.scales.take_walk().tolist()
        if self._apply_scales:
            self._to_body = self.scales.matrices()
            self._to_body_rows = self._to_body.tolist()
            # the pose those scales would have given meanwhile (ScaleLearner.take_turn);
            # the covariance is carried with the position
            self._pose[2] += turn
            for k in range(2):
                self._pose[k] += walk[k]
                self._cov_at[k] += walk[k]
        self._scale_row = self.scales.estimate.tolist()

    # Up to this many windows per poll, _close_one (floats, no validation) is used; tests
    # set it to 0 to compare it with the array path.
    _SMALL = 1

    def _solve(
        self, t_end: np.ndarray, counts: np.ndarray, mask: np.ndarray, evidence=None
    ) -> PoseBatch:
        # d[k, n, i] = sum_j M[n, i, j] c[k, n, j]: two products and one sum, as
        # onewindow.body_counts does, column by column (an einsum took twice as long, the
        # same on (k, n, 2) arrays six times: numpy is slow over a trailing axis of two)
        m = self._to_body
        d = np.empty_like(counts)
        for n in range(self.n_mice):
            cx, cy = counts[:, n, 0], counts[:, n, 1]
            for i in range(2):
                np.add(cx * m[n, i, 0], cy * m[n, i, 1], out=d[:, n, i])
        sol = models.solve(self.model, d, self._positions, self._sigma, mask, self._noise)
        sol, health, reason, consistent = self._screened(d, mask, sol, evidence)
        q = np.where(sol.ok[:, None], sol.q, 0.0)
        partials = integrate.step_partials(q)  # the noise's Jacobian; its S, C make the step
        steps = integrate.body_step(q, self.integrator, partials[:2])
        poses = integrate.compose(np.array(self._pose), steps)
        theta_before = np.concatenate([[self._pose[2]], poses[:-1, 2]])
        noise = world_step_noise(theta_before, partials, sol.cov)
        state = CovarianceState(cov=np.array(self._cov), position=np.array(self._cov_at))
        cov, state = propagate(state, poses[:, :2], noise)
        self._cov, self._cov_at = state.cov.tolist(), state.position.tolist()
        self._pose = poses[-1].tolist()
        rate = 1.0 / self.period
        return PoseBatch(
            t=t_end,
            x=poses[:, 0],
            y=poses[:, 1],
            theta=poses[:, 2],
            vx=q[:, 0] * rate,
            vy=q[:, 1] * rate,
            omega=q[:, 2] * rate,
            cov=cov,
            used=sol.used,
            ok=sol.ok,
            residual=sol.residual,
            counts=counts,
            state=health,
            reason=reason,
            consistent=consistent,
            qcov=sol.cov,
            scale=None
            if self.scales is None
            else np.broadcast_to(self.scales.estimate, counts.shape).copy(),
        )

    def _screened(self, d: np.ndarray, mask: np.ndarray, sol: models.Solution, evidence=None):
        """The fault-tolerant screen over an array of windows (mousedom.fusion.robust):
        the solution re-solved without the mice it excluded, with the covariance of
        unattributed inconsistent windows inflated, and each mouse's health per window."""
        n = len(mask)
        if self.screen is None:
            state = np.where(mask, robust.TRACKING, robust.MISSING).astype(np.int8)
            return sol, state, np.zeros_like(state), np.ones(n, dtype=bool)
        q = np.where(sol.ok[:, None], sol.q, 0.0)
        scale, low = evidence if evidence is not None else (None, None)
        used, inflate, consistent, state, reason, correction = screenbatch.screen(
            self.screen, d, mask, q, scale, low
        )
        altered = used != mask
        changed = np.flatnonzero(np.any(altered, axis=1)) if altered.any() else []
        if len(changed) or np.any(inflate != 1.0) or correction is not None:
            q, cov, res = sol.q.copy(), sol.cov.copy(), sol.residual.copy()
            n_used, ok = sol.used.copy(), sol.ok.copy()
            if len(changed):
                sub = models.solve(self.model, d[changed], self._positions, self._sigma,
                                   used[changed], self._noise)  # fmt: skip
                q[changed], cov[changed], res[changed] = sub.q, sub.cov, sub.residual
                n_used[changed], ok[changed] = sub.used, sub.ok
            cov *= inflate[:, None, None]
            if correction is not None:
                q += correction
            sol = models.Solution(q=q, cov=cov, residual=res, used=n_used, ok=ok)
        return sol, state, reason, consistent
