"""The tracker's learners: the mice's scales and the covariance's noise, fed closed windows.

A part of ``Tracker`` (tracker.py), made with the fault screen on three or more mice.  The
scale learner (``scalelearn``) takes the windows in which the mice tracked consistently as
its evidence, and the ones in which the screen left a mouse out as inconsistent against
the others' motion; the noise rate (``noiserate``) learns the reading error that
accumulates, from the residuals of the windows that used every mouse.  Both renew their
estimates at block ends; the tracker then rebinds its solving paths (``Renewal``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from mousedom.config import RobustConfig
from mousedom.fusion import integrate, models, noiserate, robust, scalelearn
from mousedom.fusion.covariance import CovarianceState, propagate, world_step_noise
from mousedom.fusion.posebatch import PoseBatch, PoseRow
from mousedom.fusion.tracker_state import PathSetup


class Renewal(NamedTuple):
    """A block end renewed the noise model or the scales: the tracker rebinds its paths to
    ``Learners.noise`` and ``scales.estimate``, and where new scales are applied
    (``robust.learn_scale``) takes their counts matrices and moves the pose by what they
    would have given meanwhile (``ScaleLearner.take_turn``, ``take_walk``)."""

    to_body: np.ndarray | None  # (N, 2, 2) with the new scales; None: nothing to apply
    turn: float  # radians, with to_body only
    walk: list[float]  # metres, world axes, with to_body only
    # added to the carried covariance where the noise is first learnt: the windows before
    # restated with it (WarmUp.restatement); None: nothing to add
    cov_add: np.ndarray | None = None
    # the mice the block's scales found faulty, no wrong CPI (ScaleLearner._faults): the
    # screen excludes them from the next window on
    faults: tuple[int, ...] = ()
    # the mice whose scale the evidence puts beyond the bounds (ScaleLearner.beyond): the
    # screen holds them out while it does
    beyond: tuple[int, ...] = ()


class WarmUp:
    """The covariance the windows before the noise rate's first estimate carried with the
    config's sigma, restated with that estimate (``restatement``).

    Until the noise is learnt (seconds of motion), the covariance takes each mouse's noise
    as its config's sigma says; a mouse five times noisier was accounted at a
    twenty-fifth of its variance for good (NEES 5.2 over 30 s drives where 3 is right,
    from those seconds alone: the estimate itself is within 5 % of the truth).  P is linear
    in each window's twist covariance B diag(v) B^T, and so in each mouse's variance: one
    covariance per mouse and per kind of window (moving, at rest), propagated as the
    pose's is and fed B_i B_i^T, is what that mouse's variance adds, and the difference of
    the learnt variance from sigma^2 times it is what the pose's covariance lacks.

    The windows are kept as they close (a list append: no per-window work in the daemon)
    and worked through at once when the estimate comes, in the learning after the POSE;
    while it does not come (a rig standing still learns nothing for as long as it stands),
    ``KEEP`` of them at a time at the learning's block ends (``settle``)."""

    KEEP = 500  # windows (5 s at 100 Hz): a fold's work stays a few ms

    @staticmethod
    def applies(setup: PathSetup) -> bool:
        """Whether the windows' covariance is B diag(v) B^T (times the screen's inflation),
        linear in each mouse's variance: not where a gyro's reading of the turn is fused
        into the windows (``use: both`` or ``gyro``).  There a window's covariance is the
        mice's after the gyro's update, whose gain was made from the config's sigma, and
        taking each mouse's unit part off as if no update had shrunk it took off more than
        the windows held: with the noise learnt at 1/600 of sigma^2, the pose's covariance
        went negative (608 of 1,358 windows of a clean 4-mouse drive, its smallest
        eigenvalue -1.4e-6).  Those windows keep the config's sigma until the noise is
        learnt, as before the restatement existed; the gyro's heading dominates them."""
        return setup.gyro is None or setup.gyro.use == "mice"

    def __init__(self, setup: PathSetup) -> None:
        self._positions = setup.positions
        self._sigma = setup.sigma
        self._sig2 = setup.sigma**2
        self._cols = (0, 2) if setup.model == "diff-drive" else (0, 1, 2)
        n = setup.n_mice
        self._states = [CovarianceState() for _ in range(2 * n)]  # moving 0..n-1, rest n..
        self._chunks: list[tuple] = []  # (x, y, theta, q, ok, used, moving, qcov) each
        self._kept = 0
        self.open = True

    def add(
        self, x: ArrayLike, y: ArrayLike, theta: ArrayLike, q: ArrayLike, ok: ArrayLike,
        used: ArrayLike, moving: ArrayLike, qcov: ArrayLike,
    ) -> None:  # fmt: skip
        """Windows solved with the config's sigma: the poses after each, the twists, whether
        solved, the mice in each solve (n, N), whether any mouse counted, and the twists'
        covariance (its ratio to the estimator's own is the screen's inflation); arrays,
        or one window's values in lists of one."""
        if not self.open:
            return
        self._chunks.append((x, y, theta, q, ok, used, moving, qcov))
        self._kept += len(np.asarray(x))

    def settle(self) -> None:
        """Fold the windows kept once there are ``KEEP`` of them: where the learning runs
        (the daemon's after its POSE, ``Learners.end_block``), not in a window's way."""
        if self._kept >= self.KEEP:
            self._fold()

    def _fold(self) -> None:
        """Propagate the unit covariances through the windows kept, and forget them."""
        if not self._chunks:
            return
        # (each is only read: a lone chunk may be the caller's array)
        x, y, theta, q, ok, used, moving, qcov = (
            scalelearn.joined([c[k] for c in self._chunks], dt)
            for k, dt in enumerate((float, float, float, float, bool, bool, bool, float))
        )
        self._chunks, self._kept = [], 0
        n_mice = len(self._sig2)
        unit = np.zeros((2 * n_mice, len(x), 3, 3))
        # per live pattern of the solved windows (a rig has few): each mouse's unit
        # sandwich, and the estimator's own covariance on sigma, whose ratio to a window's
        # is the screen's inflation
        solved = np.flatnonzero(ok)
        for mask, among in models.live_patterns(used[solved], len(solved), n_mice):
            rows = solved[among]
            est = models.estimator(self._positions.tobytes(), self._sigma.tobytes(),
                                    mask.tobytes(), self._cols)  # fmt: skip
            if est is None:
                continue
            idx = np.flatnonzero(mask)
            c3 = models.sandwich(est[1], self._sig2[idx], self._cols)
            inflate = qcov[rows, 2, 2] / c3[2, 2] if c3[2, 2] > 0 else np.ones(len(rows))
            for j, i in enumerate(idx.tolist()):
                e = np.zeros(len(idx))
                e[j] = 1.0
                one = models.sandwich(est[1], e, self._cols)
                for kind, these in ((0, moving[rows]), (n_mice, ~moving[rows])):
                    unit[kind + i, rows[these]] = inflate[these, None, None] * one
        theta_before = theta - q[:, 2]
        partials = integrate.step_partials(q)
        xy = np.stack([x, y], axis=1)
        for m in range(2 * n_mice):
            g = world_step_noise(theta_before, partials, unit[m])
            _, self._states[m] = propagate(self._states[m], xy, g)

    def restatement(self, noise: models.StepNoise) -> np.ndarray:
        """What the windows so far carry too little (or too much): the sum over mice of
        (learnt - sigma^2) times their unit covariance; the accounting closes."""
        self._fold()
        self.open = False
        n_mice = len(self._sig2)
        out = np.zeros((3, 3))
        for i in range(n_mice):
            out += (noise.moving[i] - self._sig2[i]) * self._states[i].cov
            out += (noise.rest[i] - self._sig2[i]) * self._states[n_mice + i].cov
        return 0.5 * (out + out.T)


class Learners:
    """The scale learner and the noise rate, and what they are fed (module docstring)."""

    def __init__(
        self, setup: PathSetup, to_body: np.ndarray, sigma_counts: np.ndarray,
        settings: RobustConfig,
    ) -> None:  # fmt: skip
        self._n = setup.n_mice
        self._period = setup.period
        self.scales = scalelearn.ScaleLearner(
            setup.model, to_body, setup.positions, setup.sigma, setup.period,
            settings.scale_limit,
        )  # fmt: skip
        # The covariance's noise, learnt in the same blocks; None (the config's sigma)
        # until learnt.  Not for bonarini (no linear estimator to carry it).
        self.noise_rate: noiserate.NoiseRate | None = None
        if setup.model != "bonarini":
            self.noise_rate = noiserate.NoiseRate(
                setup.positions, setup.sigma, setup.period, self.scales.block,
                (0, 2) if setup.model == "diff-drive" else (0, 1, 2),
            )  # fmt: skip
        self._apply = settings.learn_scale
        # below these a reading is no count (models.STILL), in counts
        self._still_counts = models.STILL * sigma_counts
        self._still_counts_list = self._still_counts.tolist()  # add_row's
        self._full = (False, False)  # (noise rate, scales): a block add_row filled
        self._setup = setup
        # the windows' covariance until the noise is first learnt, restated then; not
        # where a gyro's turn is fused into the windows (``WarmUp.applies``)
        self._warm = (WarmUp(setup) if self.noise_rate is not None and self.noise_rate.active
                      and WarmUp.applies(setup) else None)  # fmt: skip

    @property
    def noise(self) -> models.StepNoise | None:
        """The noise model learnt (None: not yet, the config's sigma holds)."""
        return None if self.noise_rate is None else self.noise_rate.noise

    def add_row(
        self, counts: list[tuple[float, float]], row: PoseRow, live: tuple[bool, ...],
        start: list[float], taken: Sequence[tuple[int, int, int]] = (),
    ) -> None:  # fmt: skip
        """``add`` for the one window the daemon closed, on Python values, without the
        learning: where a block is full (``due``), ``end_block`` comes before the next."""
        tracking, excluded, inconsistent = robust.TRACKING, robust.EXCLUDED, robust.INCONSISTENT
        ok = row.consistent
        usable = [ok and v and st == tracking for v, st in zip(live, row.state, strict=True)]
        per = self._period
        q = [row.vx * per, row.vy * per, row.omega * per] if row.ok else [0.0, 0.0, 0.0]
        noise = False
        if self.noise_rate is not None:
            still = self._still_counts_list
            moving = any(abs(c[0]) > e or abs(c[1]) > e
                         for c, v, e in zip(counts, live, still, strict=True) if v)  # fmt: skip
            eligible = all(usable) and row.used == self._n  # every mouse in the solve
            noise = self.noise_rate.add_row(row.residual, eligible, moving)
            if self._warm is not None and self._warm.open:
                used = [v and st in (robust.TRACKING, robust.SUSPECT)
                        for v, st in zip(live, row.state, strict=True)]  # fmt: skip
                self._warm.add([row.x], [row.y], [row.theta], [q], [row.ok], [used],
                               [moving], [row.qcov])  # fmt: skip
        scales = False
        if self.scales.active:  # (two mice learn only the noise: nothing more per window)
            held = [v and st == excluded and why == inconsistent
                    for v, st, why in zip(live, row.state, row.reason, strict=True)]  # fmt: skip
            step = [row.x - start[0], row.y - start[1]]
            in_solve = row.used == self._n  # every mouse in the pose (whatever the screen said)
            heading = row.theta - 0.5 * q[2]  # the window's middle
            scales = self.scales.add_row(counts, usable, held, q, step, in_solve, heading, taken)
        self._full = (noise, scales)

    @property
    def due(self) -> bool:
        """add_row filled a block that end_block has not learnt from yet."""
        return any(self._full)

    def end_block(self) -> Renewal | None:
        """The learning of the block ``add_row`` filled (the two learners are independent:
        each learns from its own rows), and what the tracker renews from it."""
        noise_full, scales_full = self._full
        self._full = (False, False)
        noise = noise_full and self.noise_rate is not None and self.noise_rate.end_block()
        scales = scales_full and self.scales.end_block()
        return self._renewal(noise, scales)

    def add(
        self, counts: np.ndarray, batch: PoseBatch, live: np.ndarray, start: list[float],
        taken: Sequence[tuple[int, int, int]] = (),
    ) -> Renewal | None:  # fmt: skip
        """Hand closed windows (at most ``until_block_end()``) to the learners: mice
        tracking in consistent windows are the scales' evidence, and the ones left out as
        inconsistent, against the others' motion; ``start`` is the position before them;
        ``taken``: the screen's take-backs up to the last of them (``Screen.hand_taken``)."""
        state, reason = batch.state, batch.reason
        usable = (state == robust.TRACKING) & batch.consistent[:, None] & live
        held_out = (state == robust.EXCLUDED) & (reason == robust.INCONSISTENT) & live
        q = np.stack([batch.vx, batch.vy, batch.omega], axis=1) * self._period
        q[~batch.ok] = 0.0
        noise = False
        if self.noise_rate is not None:
            counted = (np.abs(counts) > self._still_counts[None, :, None]).any(axis=2)
            moving = np.any(counted & live, axis=1)
            eligible = usable.all(axis=1) & (batch.used == self._n)  # all in the solve
            if self._warm is not None and self._warm.open:
                used = live & ((state == robust.TRACKING) | (state == robust.SUSPECT))
                self._warm.add(batch.x, batch.y, batch.theta, q, batch.ok, used, moving, batch.qcov)
            noise = self.noise_rate.add(batch.residual, eligible, moving)
        # the steps: each window's position less the one before it (np.diff's subtraction,
        # without its stack of concatenations)
        xy = np.empty((len(q) + 1, 2))
        xy[0] = start
        xy[1:, 0], xy[1:, 1] = batch.x, batch.y
        in_solve = batch.used == self._n
        heading = batch.theta - 0.5 * q[:, 2]
        scales = self.scales.add(counts, usable, held_out, q, xy[1:] - xy[:-1], in_solve,
                                 heading, taken)  # fmt: skip
        return self._renewal(noise, scales)

    def _renewal(self, noise: bool, scales: bool) -> Renewal | None:
        cov_add = None
        warm = self._warm
        if warm is not None and warm.open:
            if noise and self.noise is not None:
                cov_add = warm.restatement(self.noise)
            else:
                warm.settle()
        faults = tuple(self.scales.faults) if scales else ()
        beyond = tuple(self.scales.beyond)
        if scales:
            # taken at every renewal, applied or not (ScaleLearner.take_turn)
            turn, walk = self.scales.take_turn(), self.scales.take_walk().tolist()
            if self._apply:
                return Renewal(self.scales.matrices(), turn, walk, cov_add, faults, beyond)
        if noise or scales:
            return Renewal(None, 0.0, [0.0, 0.0], cov_add, faults, beyond)
        return None

    def until_block_end(self) -> int:
        """Windows ``add`` takes before the current block ends (at least 1). The two
        learners' blocks are one length and end together; two mice learn only the noise
        (the scales count no windows there), so its count is the one to follow."""
        if self.scales.active or self.noise_rate is None:
            return self.scales.until_block_end()
        return self.noise_rate.until_block_end()

    def rebase(self) -> None:
        """The pose was set from outside: the scales' give-back starts from here (it owes
        nothing for the turns and the walk before, and the jump is no step)."""
        self.scales.rebase()
        if self._warm is not None and self._warm.open:  # the covariance so far is gone
            self._warm = WarmUp(self._setup)
