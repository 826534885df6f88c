"""The rigid-body consistency test of a set of mice in one window.

Over a window the live mice's readings d (N x 2, body frame) should be those of one rigid
motion q: d_i = A_i q.  ``RigidTest`` solves q by the configured weights on any subset of
mice, predicts each mouse's reading from q, and tests a subset:
T = min_q sum_i |d_i - A_i q|^2 / s_i^2 against the chi-square quantile of its degrees of
freedom.  ``robust.Screen`` builds its decisions on it (which mice to blame, their health).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from mousedom.fusion import chi2, models
from mousedom.fusion.geometry import design_matrix

# A mouse whose hat block has an eigenvalue of this or more has no word from the others on
# it (RigidTest.others_gain): its residual under them would be its residual in use
# multiplied by 10 or more.
OTHERS_LEVERAGE = 0.9


class Statistic(NamedTuple):
    """The consistency test of one set of mice in one window."""

    t: float  # min over q of sum |d_i - A_i q|^2 / s2_i
    dof: int  # 2 * mice - unknowns
    q: np.ndarray  # the set's solution by the configured weights


class RigidTest:
    """The test of one rig's mice (``model``'s unknowns, mice at ``positions`` with
    ``sigma``) at the false-alarm rate ``alpha``.  No I/O, no clock."""

    def __init__(self, model: str, positions: np.ndarray, sigma: np.ndarray, alpha: float) -> None:
        self.n = len(positions)
        self.positions = np.asarray(positions, dtype=float)
        self.sigma = np.asarray(sigma, dtype=float)
        self.cols = (0, 2) if model == "diff-drive" else (0, 1, 2)
        self.k = len(self.cols)
        self.alpha = alpha
        self._thresholds = [math.inf] + [self.threshold(k) for k in range(1, 2 * self.n + 1)]
        self._leverages: dict[bytes, np.ndarray] = {}
        self._gains: dict[bytes, np.ndarray] = {}  # others_gain's, per live pattern
        self._gain_lists: dict[tuple[bool, ...], list[list[float]]] = {}
        # Python copies for fast paths on floats, which must not touch numpy: the daemon
        # runs one once per window after a sleep, when numpy's first call costs tens of
        # microseconds (cold caches), more than the test itself.
        self._xy = self.positions.tolist()

    def threshold(self, dof: int) -> float:
        return chi2.quantile(1.0 - self.alpha, dof)

    def dof(self, n_used: int) -> int:
        return 2 * n_used - self.k

    def leverage(self, used: np.ndarray) -> np.ndarray:
        """(N,) trace of each used mouse's 2x2 block of the hat matrix A B (0 if unused)."""
        key = np.asarray(used, dtype=bool).tobytes()
        h = self._leverages.get(key)
        if h is None:
            h = np.zeros(self.n)
            hat = self._hat(key)
            if hat is not None:
                diag = np.diag(hat)
                h[np.frombuffer(key, dtype=bool)] = diag[0::2] + diag[1::2]
            self._leverages[key] = h
        return h

    def _hat(self, key: bytes) -> np.ndarray | None:
        """The hat matrix A B (2L, 2L) of the solve with the used mice ``key`` (a bool
        array's bytes), by the configured weights; None without rank or without mice."""
        if not any(key):
            return None
        est = models.estimator(self.positions.tobytes(), self.sigma.tobytes(), key, self.cols)
        return None if est is None else est[0] @ est[1]

    def hat_block(self, used: np.ndarray, j: int) -> np.ndarray | None:
        """Mouse j's 2x2 block of the hat matrix A B of the solve with ``used`` (j among
        them): its reading's share in its own prediction.  Its residual with it in use is
        (I - block) times its residual under the others (block deletion); None without
        rank."""
        used = np.asarray(used, dtype=bool)
        hat = self._hat(used.tobytes())
        if hat is None or not used[j]:
            return None
        k = int(np.count_nonzero(used[:j]))
        return hat[2 * k : 2 * k + 2, 2 * k : 2 * k + 2]

    def others_gain(self, used: np.ndarray) -> np.ndarray:
        """(N, 2, 2) per used mouse, (I - block)^-1 of its hat block (``hat_block``): its
        residual under the others (the solve without it) is this times its residual in
        use, so ``d_i - gain_i (d_i - p_i)`` is what the others moved it.  Zero (no word)
        where the others cannot say (its block's eigenvalue OTHERS_LEVERAGE or more: the
        rest lack the rank or nearly so, the others' word on it would be noise
        multiplied), and for a mouse not used (the solve is the others' word on it)."""
        key = np.asarray(used, dtype=bool).tobytes()
        gain = self._gains.get(key)
        if gain is None:
            gain = np.zeros((self.n, 2, 2))
            hat = self._hat(key)
            if hat is not None:
                for k, i in enumerate(np.flatnonzero(np.frombuffer(key, dtype=bool)).tolist()):
                    block = hat[2 * k : 2 * k + 2, 2 * k : 2 * k + 2]
                    if np.all(np.abs(np.linalg.eigvals(block)) < OTHERS_LEVERAGE):
                        gain[i] = np.linalg.inv(np.eye(2) - block)
            self._gains[key] = gain
        return gain

    def others_gain_list(self, used: tuple[bool, ...]) -> list[list[float]]:
        """``others_gain`` as floats, (m00, m01, m10, m11) per mouse, for the float path
        (keyed by the tuple itself: no numpy call once a pattern is known)."""
        rows = self._gain_lists.get(used)
        if rows is None:
            gain = self.others_gain(np.array(used, dtype=bool))
            rows = self._gain_lists[used] = gain.reshape(self.n, 4).tolist()
        return rows

    def prediction_cov(self, used: np.ndarray, s2: np.ndarray) -> np.ndarray:
        """(N, 2, 2) the covariance of each mouse's predicted motion, from the error of the
        twist solved on the ``used`` mice (by the config's weights, ``_solve``) whose
        readings have the variances per axis ``s2`` (N,): A_i B diag(s2) B^T A_i^T, the
        estimator's sandwich (the learnt variances need not be in the config's
        proportions).  What a mouse held out is compared with is itself uncertain by this
        much: far from mice that fix the turn poorly (two close together), many times the
        mouse's own noise across the line to them.  inf without rank."""
        used = np.asarray(used, dtype=bool)
        est = models.estimator(self.positions.tobytes(), self.sigma.tobytes(),
                                used.tobytes(), self.cols)  # fmt: skip
        if est is None:
            return np.full((self.n, 2, 2), math.inf)
        b = est[1]  # (k, 2L)
        cov_q = (b * np.repeat(np.asarray(s2, dtype=float)[used], 2)) @ b.T
        a = design_matrix(self.positions).reshape(self.n, 2, 3)[:, :, list(self.cols)]
        return np.einsum("nij,jk,nlk->nil", a, cov_q, a)

    def predict(self, q: np.ndarray) -> np.ndarray:
        """Each mouse's displacement (..., N, 2) under body twist increments q (..., 3)."""
        q = np.asarray(q, dtype=float)
        ux, uy, a = q[..., 0], q[..., 1], q[..., 2]
        # mouse by mouse into the (..., N, 2) array: numpy is slow over short trailing axes
        out = np.empty((*q.shape[:-1], self.n, 2))
        for i, (x, y) in enumerate(self._xy):
            out[..., i, 0] = ux - a * y
            out[..., i, 1] = uy + a * x
        return out

    def _solve(self, d: np.ndarray, used: np.ndarray) -> np.ndarray | None:
        """q (3,) by the configured weights on the ``used`` mice; None without rank."""
        if not used.any():
            return None
        est = models.estimator(
            self.positions.tobytes(), self.sigma.tobytes(), used.tobytes(), self.cols
        )
        if est is None:
            return None
        q = np.zeros(3)
        q[list(self.cols)] = est[1] @ d[used].reshape(-1)
        return q

    def _statistic(self, d: np.ndarray, used: np.ndarray, s2: np.ndarray) -> Statistic | None:
        """The test of the ``used`` mice, or None without rank."""
        q = self._solve(d, used)
        if q is None:
            return None
        dof = self.dof(int(used.sum()))
        if dof <= 0:
            return Statistic(0.0, dof, q)
        s = np.sqrt(s2)[used]
        a = np.zeros((int(used.sum()), 2, 3))
        pos = self.positions[used]
        a[:, 0, 0] = 1.0
        a[:, 1, 1] = 1.0
        a[:, 0, 2] = -pos[:, 1]
        a[:, 1, 2] = pos[:, 0]
        a = (a[:, :, list(self.cols)] / s[:, None, None]).reshape(-1, self.k)
        b = (d[used] / s[:, None]).reshape(-1)
        sol = np.linalg.lstsq(a, b, rcond=None)[0]
        r = b - a @ sol
        return Statistic(float(r @ r), dof, q)

    def _passes(self, stat: Statistic | None) -> bool:
        return stat is not None and stat.dof > 0 and stat.t <= self._thresholds[stat.dof]
