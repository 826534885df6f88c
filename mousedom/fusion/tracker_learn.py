"""The tracker's learners: the mice's scales and the covariance's noise, fed closed windows.

A part of ``Tracker`` (tracker.py), made with the fault screen on three or more mice.  The
scale learner (``scalelearn``) takes the windows in which the mice tracked consistently as
its evidence, and the ones in which the screen left a mouse out as inconsistent against
the others' motion; the noise rate (``noiserate``) learns the reading error that
accumulates, from the residuals of the windows that used every mouse.  Both renew their
estimates at block ends; the tracker then rebinds its solving paths (``Renewal``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mousedom.config import RobustConfig
from mousedom.fusion import models, noiserate, robust, scalelearn
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

    @property
    def noise(self) -> models.StepNoise | None:
        """The noise model learnt (None: not yet, the config's sigma holds)."""
        return None if self.noise_rate is None else self.noise_rate.noise

    def add_row(
        self, counts: list[tuple[float, float]], row: PoseRow, live: tuple[bool, ...],
        start: list[float],
    ) -> None:  # fmt: skip
        """``add`` for the one window the daemon closed, on Python values, without the
        learning: where a block is full (``due``), ``end_block`` comes before the next."""
        tracking, excluded, inconsistent = robust.TRACKING, robust.EXCLUDED, robust.INCONSISTENT
        ok = row.consistent
        usable = [ok and v and st == tracking for v, st in zip(live, row.state, strict=True)]
        held = [v and st == excluded and why == inconsistent
                for v, st, why in zip(live, row.state, row.reason, strict=True)]  # fmt: skip
        per = self._period
        q = [row.vx * per, row.vy * per, row.omega * per] if row.ok else [0.0, 0.0, 0.0]
        noise = False
        if self.noise_rate is not None:
            still = self._still_counts_list
            moving = any(abs(c[0]) > e or abs(c[1]) > e
                         for c, v, e in zip(counts, live, still, strict=True) if v)  # fmt: skip
            eligible = all(usable) and row.used == self._n  # every mouse in the solve
            noise = self.noise_rate.add_row(row.residual, eligible, moving)
        step = [row.x - start[0], row.y - start[1]]
        in_solve = row.used == self._n  # every mouse in the pose (whatever the screen said)
        heading = row.theta - 0.5 * q[2]  # the window's middle
        scales = self.scales.add_row(counts, usable, held, q, step, in_solve, heading)
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
        self, counts: np.ndarray, batch: PoseBatch, live: np.ndarray, start: list[float]
    ) -> Renewal | None:
        """Hand closed windows (at most ``until_block_end()``) to the learners: mice
        tracking in consistent windows are the scales' evidence, and the ones left out as
        inconsistent, against the others' motion; ``start`` is the position before them."""
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
            noise = self.noise_rate.add(batch.residual, eligible, moving)
        # the steps: each window's position less the one before it (np.diff's subtraction,
        # without its stack of concatenations)
        xy = np.empty((len(q) + 1, 2))
        xy[0] = start
        xy[1:, 0], xy[1:, 1] = batch.x, batch.y
        in_solve = batch.used == self._n
        heading = batch.theta - 0.5 * q[:, 2]
        scales = self.scales.add(counts, usable, held_out, q, xy[1:] - xy[:-1], in_solve,
                                 heading)  # fmt: skip
        return self._renewal(noise, scales)

    def _renewal(self, noise: bool, scales: bool) -> Renewal | None:
        if scales:
            # taken at every renewal, applied or not (ScaleLearner.take_turn)
            turn, walk = self.scales.take_turn(), self.scales.take_walk().tolist()
            if self._apply:
                return Renewal(self.scales.matrices(), turn, walk)
        if noise or scales:
            return Renewal(None, 0.0, [0.0, 0.0])
        return None

    def until_block_end(self) -> int:
        """Windows ``add`` takes before the current block ends (at least 1)."""
        return self.scales.until_block_end()

    def rebase(self) -> None:
        """The pose was set from outside: the scales' give-back starts from here (it owes
        nothing for the turns and the walk before, and the jump is no step)."""
        self.scales.rebase()
