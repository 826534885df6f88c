"""The tracker's one-window path: solving the next window on Python floats (the daemon's).

A part of ``Tracker`` (tracker.py), which closes the mice's count functions and hands each
window's counts here.  The daemon closes one window per poll; the array functions pay
numpy's fixed cost per call dozens of times for it, so here the same maths runs on floats
(``onewindow``), with the same results as the array path (tests/test_onewindow.py,
tests/test_robust.py).  Linear models only: the tracker sends bonarini's windows to the
array path (numerical linearisation).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mousedom.fusion import models, onewindow, robust
from mousedom.fusion.health import Reason
from mousedom.fusion.posebatch import PoseBatch, PoseRow
from mousedom.fusion.tracker_state import Carried, PathSetup

Live = tuple[bool, ...]  # per mouse: live over the window
Matrix3 = list[list[float]]


class LinearPlan(NamedTuple):
    """What ``OneWindowPath.solve`` needs per pattern of live mice, as Python floats (A
    and B None where the live mice lack rank)."""

    a_rows: list[list[float]] | None  # the design matrix's rows
    b_rows: list[list[float]] | None  # the estimator's: q = B d
    idx: list[int]  # the live mice
    c_moving: Matrix3  # q's covariance in a window with counts
    c_rest: Matrix3  # and in one without
    cols: tuple[int, ...]  # the q components solved for


# One window's linear solve (OneWindowPath._linear_one): the twist increment q (u_x, u_y,
# a), the residual per mouse (0 for the mice not used), the mice used, q's covariance, and
# whether those mice have rank.  A plain tuple, not a NamedTuple: made every window, and a
# NamedTuple's constructor costs several times a tuple display.
LinearSolution = tuple[list[float], list[list[float]], list[int], Matrix3, bool]


def _blame(
    state: tuple[int, ...], reason: tuple[int, ...], idx: list[int], blamed: tuple[int, ...]
) -> tuple[tuple[int, ...], tuple[int, ...], list[int]]:
    """The window's health with the mice the gyro blamed excluded (GyroJudge)."""
    st, why = list(state), list(reason)
    for i in blamed:
        st[i], why[i] = robust.EXCLUDED, Reason.GYRO
    return tuple(st), tuple(why), [i for i in idx if i not in blamed]


class OneWindowPath:
    """Solves one window of a linear model on floats (see the module docstring).

    Built with what does not change (``PathSetup``) and the tracker's ``Carried`` pose,
    which it reads and writes (shared with the array path).  What the learners renew (the
    counts matrices, the noise model, the scales reported) reaches it through ``rebind``:
    it never reads the tracker."""

    def __init__(self, setup: PathSetup, carried: Carried) -> None:
        self._model = setup.model
        self._integrator = setup.integrator
        self._positions = setup.positions
        self._sigma = setup.sigma
        self._n = setup.n_mice
        self._rate = 1.0 / setup.period
        self._screen = setup.screen
        self.gyro = setup.gyro
        self._carried = carried
        # below these a reading is no count (models.STILL), in metres
        self._still = (models.STILL * setup.sigma).tolist()
        self._plans: dict[Live, LinearPlan] = {}  # made once per pattern of live mice
        # live pattern -> (state, reason) of the common case (every live mouse tracking)
        self._steady: dict[Live, tuple[tuple[int, ...], tuple[int, ...]]] = {}
        # bound by rebind (the tracker calls it at construction and at every renewal)
        self._to_body_rows: list[list[list[float]]] = []
        self._noise: models.StepNoise | None = None
        self._scale_row: list | tuple = ()

    def rebind(
        self, to_body: np.ndarray, noise: models.StepNoise | None, scale: np.ndarray | None
    ) -> None:
        """The tracker's counts matrices (N, 2, 2), noise model and learnt scales (N, 2;
        None: none learnt) as they are now."""
        self._to_body_rows = to_body.tolist()
        if noise is not self._noise:
            self._noise = noise
            self._plans.clear()  # the plans hold the covariance
        self._scale_row = () if scale is None else scale.tolist()

    def _linear_plan(self, live: Live) -> LinearPlan:
        """The pattern's LinearPlan, made once."""
        plan = self._plans.get(live)
        if plan is None:
            cols = (0, 1, 2) if self._model == "lsq" else (0, 2)
            key = (
                self._positions.tobytes(),
                self._sigma.tobytes(),
                np.array(live, dtype=bool).tobytes(),
                cols,
            )
            est = models.estimator(*key) if any(live) else None
            c3 = np.zeros((3, 3))
            a_rows: list[list[float]] | None = None
            b_rows: list[list[float]] | None = None
            idx = [i for i, v in enumerate(live) if v]
            c_moving = c_rest = c3.tolist()
            if est is not None:
                a_rows, b_rows = est[0].tolist(), est[1].tolist()
                if self._noise is None:
                    c3[np.ix_(cols, cols)] = est[2]
                    c_moving = c_rest = c3.tolist()
                else:
                    noise = self._noise
                    c_moving = models.noise_covariance(*key, noise.moving[idx].tobytes()).tolist()
                    c_rest = models.noise_covariance(*key, noise.rest[idx].tobytes()).tolist()
            plan = LinearPlan(a_rows, b_rows, idx, c_moving, c_rest, cols)
            self._plans[live] = plan
        return plan

    def solve(
        self,
        t_end: float,
        counts: list[tuple[float, float]],
        live: Live,
        evidence: tuple[list[float], list[bool]] | None = None,
        turn: float | None = None,
        spans: list[float] | None = None,
        defer_block_end: bool = False,
    ) -> PoseBatch:
        """The window ending at ``t_end`` from each mouse's raw ``counts`` (REL_X, REL_Y),
        as ``ArrayPath.solve`` gives it for one window of a linear model; the pose
        carried on.  ``spans``: each mouse's long report span cut by the window's edges
        (CountFunction.window_span), or None where none is; ``defer_block_end``: the
        screen's noise model learns from a block this window ends at ``Screen.settle``."""
        # Every mouse's counts in body metres, once: the solve takes the live ones, the
        # screen all (the products per mouse are the same whichever subset is asked).
        n = self._n
        d_all = onewindow.body_counts(self._to_body_rows, counts)
        q, residual, idx, c3, ok = self._linear_one(d_all, live)
        consistent = True
        screen = self._screen
        # the factors this window is tested with (a block it ends may change them)
        learnt = screen.noise.lam_r_list if screen is not None else None
        if screen is None or screen.fast_one(d_all, q, live, evidence is not None,
                                             defer_block_end, spans):  # fmt: skip
            # The common case (or no screen): every live mouse tracking, the rest missing,
            # and no reason for either (robust's health gives no other to those states).
            rows = self._steady.get(live)
            if rows is None:
                rows = self._steady[live] = (
                    tuple(robust.TRACKING if v else robust.MISSING for v in live),
                    (robust.NONE,) * n,
                )
            state, reason = rows
        else:
            scale, low = evidence if evidence is not None else (None, None)
            d_pairs = np.array(d_all).reshape(n, 2)
            dec = screen.decide(d_pairs, np.array(live, dtype=bool), scale, low, spans,
                                defer_block_end)  # fmt: skip
            used = tuple(dec.used.tolist())
            if used != live:
                q, residual, idx, c3, ok = self._linear_one(d_all, used)
            if dec.correction is not None:
                q = [v + c for v, c in zip(q, dec.correction.tolist(), strict=True)]
            if dec.inflate != 1.0:
                c3 = [[v * dec.inflate for v in row] for row in c3]
            consistent = dec.consistent
            state = tuple(h.state for h in screen.health)
            reason = tuple(h.reason for h in screen.health)
        gyro: list[float] | tuple = ()
        if self.gyro is not None:  # the gyro's reading of the turn (fusion/gyro.py)
            from mousedom.fusion.gyrojudge import MiceView

            pairs = [d_all[2 * i : 2 * i + 2] for i in range(n)]
            in_solve = [i in idx for i in range(n)]
            j = self.gyro.judged(q, c3, turn, ok, MiceView(pairs, in_solve, consistent, learnt))
            q, c3, said = j.q, j.c, j.report
            gyro = said.row()
            consistent = consistent and j.consistent
            if j.blamed:
                state, reason, idx = _blame(state, reason, idx, j.blamed)
        ux, uy, a = q
        # the heading the gyro's renewals give back turns the pose, not the twist reported
        owed = self.gyro.state.take_owed() if self.gyro is not None else 0.0
        carried = self._carried
        pose_now, cov = onewindow.advance(carried.pose, carried.cov, carried.at, q, owed, c3,
                                          self._integrator)  # fmt: skip
        x, y, th = pose_now
        carried.pose, carried.cov, carried.at = pose_now, cov, [x, y]
        rate = self._rate
        pose = PoseRow(t_end, x, y, th, ux * rate, uy * rate, a * rate, cov, len(idx), ok,
                    residual, counts, state, reason, consistent, c3, self._scale_row,
                    gyro)  # fmt: skip
        return PoseBatch.from_rows([pose])

    def _linear_one(self, d_all: list[float], live: Live) -> LinearSolution:
        """One window's solve with the ``live`` mice, from every mouse's body-frame counts
        ``d_all`` (x1, y1, x2, ...)."""
        a_rows, b_rows, idx, c_moving, c_rest, cols = self._linear_plan(live)
        n = self._n
        residual = [[0.0, 0.0] for _ in range(n)]
        q = [0.0, 0.0, 0.0]
        ok = b_rows is not None
        c3 = c_moving
        if c_rest is not c_moving:
            still = self._still
            if not any(abs(d_all[2 * i]) > still[i] or abs(d_all[2 * i + 1]) > still[i]
                       for i in idx):  # fmt: skip
                c3 = c_rest
        if a_rows is not None and b_rows is not None:  # (ok)
            d = d_all if len(idx) == n else [v for i in idx for v in d_all[2 * i : 2 * i + 2]]
            qk, res = onewindow.linear(d, a_rows, b_rows)
            for c, v in zip(cols, qk, strict=True):
                q[c] = v
            for k, i in enumerate(idx):
                residual[i] = res[2 * k : 2 * k + 2]
        return q, residual, idx, c3, ok
