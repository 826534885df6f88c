"""The tracker's one-window path: closing the next window on Python floats (the daemon's).

A mixin of ``Tracker`` (tracker.py), which keeps the state: the mice's count functions,
the carried pose and covariance, the fault-tolerant screen.  The daemon closes one window
per poll; the array functions pay numpy's fixed cost per call dozens of times for it, so
here the same maths runs on floats (``onewindow``), with the same results as the array
path (tests/test_onewindow.py, tests/test_robust.py).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from mousedom.fusion import models, onewindow, robust
from mousedom.fusion.posebatch import PoseBatch, PoseRow


class LinearPlan(NamedTuple):
    """What _solve_one needs per pattern of live mice, as Python floats (A and B None
    where the live mice lack rank)."""

    a_rows: list[list[float]] | None  # the design matrix's rows
    b_rows: list[list[float]] | None  # the estimator's: q = B d
    idx: list[int]  # the live mice
    c_moving: list[list[float]]  # q's covariance in a window with counts
    c_rest: list[list[float]]  # and in one without
    cols: tuple[int, ...]  # the q components solved for


class OneWindowPath:
    """``Tracker._close_one`` and what it uses (see the module docstring)."""

    def _close_one(self) -> PoseBatch:
        """_close_until for the next window on Python floats: the daemon's case."""
        k = self._closed
        start, end = self._edge(k), self._edge(k + 1)
        counts, live = [], []
        for m, acc in zip(self._mice, self._counts_out, strict=True):
            cx, cy = m.close_one(end)
            counts.append((cx, cy))
            acc[0] += cx  # floats, not an array: numpy's += of a list cost 3 us a window
            acc[1] += cy
            live.append(not m.dead or m.live_in(start, end))
        live = tuple(live)
        self._closed = k + 1
        evidence = self.evidence.window(start, end) if self.evidence else None
        before = self._pose[:2]
        if self.model == "bonarini":  # numerical linearisation: the array path
            ev = None if evidence is None else (np.array([evidence[0]]), np.array([evidence[1]]))
            batch = self._solve(np.array([end]), np.array([counts]), np.array([live]), ev)
        else:
            batch = self._solve_one(end, counts, live, evidence)
        if self.scales is not None:
            self._learn_scales_row(counts, batch.rows()[0], live, before)
        return batch

    def _linear_plan(self, live: tuple[bool, ...]) -> LinearPlan:
        """The pattern's LinearPlan, made once."""
        plan = self._linear_cache.get(live)
        if plan is None:
            cols = (0, 1, 2) if self.model == "lsq" else (0, 2)
            key = np.array(live, dtype=bool).tobytes()
            est = None
            if any(live):
                est = models._estimator(self._positions.tobytes(), self._sigma.tobytes(), key, cols)
            c3 = np.zeros((3, 3))
            a_rows = b_rows = None
            idx = [i for i, v in enumerate(live) if v]
            c_moving = c_rest = c3.tolist()
            if est is not None:
                a_rows, b_rows = est[0].tolist(), est[1].tolist()
                if self._noise is None:
                    c3[np.ix_(cols, cols)] = est[2]
                    c_moving = c_rest = c3.tolist()
                else:
                    c_moving = models.sandwich(est[1], self._noise.moving[idx], cols).tolist()
                    c_rest = models.sandwich(est[1], self._noise.rest[idx], cols).tolist()
            plan = LinearPlan(a_rows, b_rows, idx, c_moving, c_rest, cols)
            self._linear_cache[live] = plan
        return plan

    def _solve_one(
        self,
        t_end: float,
        counts: list[tuple[float, float]],
        live: tuple[bool, ...],
        evidence: tuple[list[float], list[bool]] | None = None,
    ) -> PoseBatch:
        """_solve for one window of a linear model (see mousedom.fusion.onewindow)."""
        # Every mouse's counts in body metres, once: the solve takes the live ones, the
        # screen all (the products per mouse are the same whichever subset is asked).
        d_all = onewindow.body_counts(self._to_body_rows, counts, range(self.n_mice))
        q, residual, idx, c3, ok = self._linear_one(d_all, live)
        consistent = True
        screen = self.screen
        if screen is None or screen.fast_one(d_all, q, live, evidence is not None):
            # The common case (or no screen): every live mouse tracking, the rest missing,
            # and no reason for either (robust's health gives no other to those states).
            rows = self._steady_rows.get(live)
            if rows is None:
                rows = self._steady_rows[live] = (
                    tuple(robust.TRACKING if v else robust.MISSING for v in live),
                    (robust.NONE,) * self.n_mice,
                )
            state, reason = rows
        else:
            scale, low = evidence if evidence is not None else (None, None)
            d_pairs = np.array(d_all).reshape(self.n_mice, 2)
            dec = screen.decide(d_pairs, np.array(live, dtype=bool), scale, low)
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
        ux, uy, a = q
        sx, sy = onewindow.body_step(ux, uy, a, self.integrator)
        x0, y0, th0 = self._pose
        cb, sb = math.cos(th0), math.sin(th0)
        x, y, th = x0 + (cb * sx - sb * sy), y0 + (sb * sx + cb * sy), th0 + a
        g = onewindow.noise(th0, ux, uy, a, c3)
        cov = onewindow.propagate(self._cov, self._cov_at, (x, y), g)
        self._pose, self._cov, self._cov_at = [x, y, th], cov, [x, y]
        rate = self._rate
        pose = PoseRow(t_end, x, y, th, ux * rate, uy * rate, a * rate, cov, len(idx), ok,
                    residual, counts, state, reason, consistent, c3, self._scale_row)  # fmt: skip
        return PoseBatch.from_rows([pose])

    def _linear_one(self, d_all: list[float], live: tuple[bool, ...]):
        """(q, residual per mouse, used indices, q covariance, ok) of one window, from
        every mouse's body-frame counts ``d_all`` (x1, y1, x2, ...)."""
        a_rows, b_rows, idx, c_moving, c_rest, cols = self._linear_plan(live)
        residual = [[0.0, 0.0] for _ in range(self.n_mice)]
        q = [0.0, 0.0, 0.0]
        ok = b_rows is not None
        c3 = c_moving
        if c_rest is not c_moving:
            still = self._still
            if not any(abs(d_all[2 * i]) > still[i] or abs(d_all[2 * i + 1]) > still[i]
                       for i in idx):  # fmt: skip
                c3 = c_rest
        if ok:
            d = (
                d_all
                if len(idx) == self.n_mice
                else [v for i in idx for v in d_all[2 * i : 2 * i + 2]]
            )
            qk, res = onewindow.linear(d, a_rows, b_rows)
            for c, v in zip(cols, qk, strict=True):
                q[c] = v
            for k, i in enumerate(idx):
                residual[i] = res[2 * k : 2 * k + 2]
        return q, residual, idx, c3, ok
