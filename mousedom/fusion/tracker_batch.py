"""The tracker's array path: solving many closed windows at once (replay's case).

A part of ``Tracker`` (tracker.py), which closes the mice's count functions and hands the
windows' counts here: the models solve them as arrays (``models.solve``), the fault screen
judges them (``screenbatch``), and the pose and its covariance are carried through them.
``tracker_one.OneWindowPath`` is the same for one window on floats (the daemon's).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from mousedom.fusion import integrate, models, robust, screenbatch
from mousedom.fusion.covariance import CovarianceState, propagate, world_step_noise
from mousedom.fusion.health import Reason
from mousedom.fusion.posebatch import GYRO_FIELDS, PoseBatch
from mousedom.fusion.tracker_state import Carried, PathSetup

if TYPE_CHECKING:
    from mousedom.fusion.gyro import GyroFusion

# per window: the scale evidence and whether it is low (fusion.evidence), as arrays
Evidence = tuple[np.ndarray, np.ndarray]


class ArrayPath:
    """Solves windows as arrays (see the module docstring).

    Built with what does not change (``PathSetup``) and the tracker's ``Carried`` pose,
    which it reads on entry and writes on exit (shared with the one-window path).  What
    the learners renew (the counts matrices, the noise model, the scales reported) reaches
    it through ``rebind``: it never reads the tracker."""

    def __init__(self, setup: PathSetup, carried: Carried) -> None:
        self._setup = setup
        self._n = setup.n_mice
        self._carried = carried
        # bound by rebind (the tracker calls it at construction and at every renewal)
        self._to_body = np.zeros((self._n, 2, 2))
        self._noise: models.StepNoise | None = None
        self._scale: np.ndarray | None = None

    def rebind(
        self, to_body: np.ndarray, noise: models.StepNoise | None, scale: np.ndarray | None
    ) -> None:
        """The tracker's counts matrices (N, 2, 2), noise model and learnt scales (N, 2;
        None: none learnt) as they are now."""
        self._to_body, self._noise, self._scale = to_body, noise, scale

    def solve(
        self,
        t_end: np.ndarray,
        counts: np.ndarray,
        mask: np.ndarray,
        evidence: Evidence | None = None,
        turn: np.ndarray | None = None,
        spans: np.ndarray | None = None,
    ) -> PoseBatch:
        """The windows ending at ``t_end`` (n,) from each mouse's raw ``counts`` (n, N, 2)
        with the mice live in each (``mask``, (n, N)); the pose carried through them.
        ``spans`` (n, N): the long report spans each window's edges cut (CountFunction),
        or None where there are none."""
        setup = self._setup
        # d[k, n, i] = sum_j M[n, i, j] c[k, n, j]: two products and one sum, as
        # onewindow.body_counts does, column by column (an einsum took twice as long, the
        # same on (k, n, 2) arrays six times: numpy is slow over a trailing axis of two)
        m = self._to_body
        d = np.empty_like(counts)
        for n in range(self._n):
            cx, cy = counts[:, n, 0], counts[:, n, 1]
            for i in range(2):
                np.add(cx * m[n, i, 0], cy * m[n, i, 1], out=d[:, n, i])
        sol = models.solve(setup.model, d, setup.positions, setup.sigma, mask, self._noise)
        screened = self._screened(d, mask, sol, evidence, spans)
        sol, health, reason, consistent, in_solve, factors = screened
        q = np.where(sol.ok[:, None], sol.q, 0.0)
        qcov, gyro = sol.cov, None
        used = sol.used
        turned = q  # what the pose turns by: q, and the heading the gyro's renewals give back
        if setup.gyro is not None and turn is not None:  # the gyro's reading of the turns
            q, qcov, gyro, used, owed = self._with_gyro(setup.gyro, q, sol, d, in_solve, turn,
                                                        health, reason, consistent,
                                                        factors)  # fmt: skip
            turned = q.copy()
            turned[:, 2] += owed
        partials = integrate.step_partials(turned)  # the noise's Jacobian; its S, C: the step
        steps = integrate.body_step(turned, setup.integrator, partials[:2])
        carried = self._carried
        poses = integrate.compose(np.array(carried.pose), steps)
        theta_before = np.concatenate([[carried.pose[2]], poses[:-1, 2]])
        noise = world_step_noise(theta_before, partials, qcov)
        state = CovarianceState(cov=np.array(carried.cov), position=np.array(carried.at))
        cov, state = propagate(state, poses[:, :2], noise)
        carried.cov, carried.at = state.cov.tolist(), state.position.tolist()
        carried.pose = poses[-1].tolist()
        rate = 1.0 / setup.period
        return PoseBatch(
            t=t_end,
            x=poses[:, 0],
            y=poses[:, 1],
            theta=poses[:, 2],
            vx=q[:, 0] * rate,
            vy=q[:, 1] * rate,
            omega=q[:, 2] * rate,
            cov=cov,
            used=used,
            ok=sol.ok,
            residual=sol.residual,
            counts=counts,
            state=health,
            reason=reason,
            consistent=consistent,
            qcov=qcov,
            scale=None
            if self._scale is None
            else np.broadcast_to(self._scale, counts.shape).copy(),
            gyro=gyro,
        )

    def _with_gyro(
        self,
        fusion: GyroFusion,
        q: np.ndarray,
        sol: models.Solution,
        d: np.ndarray,
        in_solve: np.ndarray,
        turn: np.ndarray,
        health: np.ndarray,
        reason: np.ndarray,
        consistent: np.ndarray,
        factors: list[tuple[int, list[float]]],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The gyro's turn in each window, judged where it disagrees (GyroFusion.judged),
        in window order (the bias is sequential), ``in_solve`` (n, N) the mice each
        window's solve used (the screen's: not only the excluded are out of it, a late
        mouse is too, as the one-window path's MiceView says); the mice it blames excluded
        in ``health`` and ``reason`` and ``consistent`` cleared where nobody could be, in
        place; ``factors`` the screen's learnt proportional factors by row (screenbatch).
        Returns (q, q's covariance, the gyro's columns, mice used, the heading
        its renewals give back in each window: gyrobias.BiasLearner.renew)."""
        from mousedom.fusion.gyrojudge import MiceView

        n = len(q)
        q2, c2 = q.copy(), sol.cov.copy()
        gyro = np.empty((n, GYRO_FIELDS))
        used = sol.used.copy()
        owed = np.zeros(n)
        learnt, changes = None, iter(factors)
        change = next(changes, None)
        for k in range(n):
            while change is not None and change[0] <= k:
                learnt, change = change[1], next(changes, None)
            tk = float(turn[k])
            mice = MiceView(d[k].tolist(), in_solve[k].tolist(), bool(consistent[k]), learnt)
            j = fusion.judged(q[k].tolist(), sol.cov[k].tolist(),
                              None if math.isnan(tk) else tk, bool(sol.ok[k]), mice)  # fmt: skip
            q2[k], c2[k] = j.q, j.c
            gyro[k] = j.report.row()
            owed[k] = fusion.state.take_owed()
            consistent[k] = consistent[k] and j.consistent
            for i in j.blamed:
                health[k, i], reason[k, i] = robust.EXCLUDED, Reason.GYRO
                used[k] -= 1
        return q2, c2, gyro, used, owed

    def _screened(
        self,
        d: np.ndarray,
        mask: np.ndarray,
        sol: models.Solution,
        evidence: Evidence | None,
        spans: np.ndarray | None = None,
    ) -> tuple[
        models.Solution, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
        list[tuple[int, list[float]]],
    ]:  # fmt: skip
        """The fault-tolerant screen over an array of windows (mousedom.fusion.robust):
        the solution re-solved without the mice it excluded, with the covariance of
        unattributed inconsistent windows inflated, and each mouse's health per window:
        (solution, state, reason, consistent, the mice in each window's solve, the noise
        model's proportional factors by row: screenbatch.screen's)."""
        n = len(mask)
        setup = self._setup
        if setup.screen is None:
            state = np.where(mask, robust.TRACKING, robust.MISSING).astype(np.int8)
            return sol, state, np.zeros_like(state), np.ones(n, dtype=bool), mask, []
        q = np.where(sol.ok[:, None], sol.q, 0.0)
        scale, low = evidence if evidence is not None else (None, None)
        used, inflate, consistent, state, reason, correction, factors = screenbatch.screen(
            setup.screen, d, mask, q, scale, low, spans
        )
        altered = used != mask
        changed = np.flatnonzero(np.any(altered, axis=1)) if altered.any() else np.zeros(0, int)
        if len(changed) or np.any(inflate != 1.0) or correction is not None:
            q, cov, res = sol.q.copy(), sol.cov.copy(), sol.residual.copy()
            n_used, ok = sol.used.copy(), sol.ok.copy()
            if len(changed):
                sub = models.solve(setup.model, d[changed], setup.positions, setup.sigma,
                                   used[changed], self._noise)  # fmt: skip
                q[changed], cov[changed], res[changed] = sub.q, sub.cov, sub.residual
                n_used[changed], ok[changed] = sub.used, sub.ok
            cov *= inflate[:, None, None]
            if correction is not None:
                q += correction
            sol = models.Solution(q=q, cov=cov, residual=res, used=n_used, ok=ok)
        return sol, state, reason, consistent, used, factors
