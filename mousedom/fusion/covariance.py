"""Pose covariance over a whole batch of windows at once.

Composition pose_k = pose_{k-1} (+) step_k has the Jacobian S(p_k - p_{k-1}) with respect
to the previous pose, where S(d) = [[1, 0, -d_y], [0, 1, d_x], [0, 0, 1]].  These matrices
form a group, S(a) S(b) = S(a + b), so the covariance after window k is

    P_k = sum_j S(p_k - p_j) G_j S(p_k - p_j)^T

over every noise input j (the starting covariance counts as one, at the start position),
with G_j the step noise in world axes.  Expanding S with e = J p_k - J p_j (J the 90 degree
rotation) makes every term a cumulative sum over j, so a batch of windows needs no Python
loop.  The running sums are rebased onto the last pose at the end of every batch, which
keeps them small and makes batch-by-batch equal to one big batch.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _perp(p: np.ndarray) -> np.ndarray:
    """J p: rotate (n,2) vectors by +90 degrees."""
    return np.stack([-p[..., 1], p[..., 0]], axis=-1)


@dataclass
class CovarianceState:
    """Covariance of the pose at ``position`` (3x3 over x, y, theta)."""

    cov: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    position: np.ndarray = field(default_factory=lambda: np.zeros(2))


def world_step_noise(
    theta_before: np.ndarray, partials: tuple[np.ndarray, ...], q_cov: np.ndarray
) -> np.ndarray:
    """G_k = M Q M^T with M = blockdiag(R(theta_{k-1}), 1) J, shapes (n,3,3), for the exact
    step's Jacobian J = [[S, -C, dx/da], [C, S, dy/da], [0, 0, 1]] given by its entries
    ``partials`` = (S, C, dx/da, dy/da) (``integrate.step_partials``).

    Written out entry by entry on (n,) arrays: numpy's stacked matmul of 3x3 matrices
    costs several times more per window.  M's last row is (0, 0, 1), so the terms it
    would multiply by 0 are left out and those by 1 taken as they are (the values of the
    full product, but for the sign of a zero)."""
    s, c, jx, jy = partials
    ct, st = np.cos(theta_before), np.sin(theta_before)
    m0 = (ct * s - st * c, ct * -c - st * s, ct * jx - st * jy)
    m1 = (st * s + ct * c, st * -c + ct * s, st * jx + ct * jy)
    n = len(theta_before)
    qc = np.broadcast_to(q_cov, (n, 3, 3))
    q = [[qc[:, r, k] for k in range(3)] for r in range(3)]
    mq0 = [m0[0] * q[0][k] + m0[1] * q[1][k] + m0[2] * q[2][k] for k in range(3)]
    mq1 = [m1[0] * q[0][k] + m1[1] * q[1][k] + m1[2] * q[2][k] for k in range(3)]
    out = np.empty((n, 3, 3))
    out[:, 0, 0] = mq0[0] * m0[0] + mq0[1] * m0[1] + mq0[2] * m0[2]
    out[:, 0, 1] = out[:, 1, 0] = mq0[0] * m1[0] + mq0[1] * m1[1] + mq0[2] * m1[2]
    out[:, 1, 1] = mq1[0] * m1[0] + mq1[1] * m1[1] + mq1[2] * m1[2]
    out[:, 0, 2] = out[:, 2, 0] = mq0[2]
    out[:, 1, 2] = out[:, 2, 1] = mq1[2]
    out[:, 2, 2] = q[2][2]
    return out


# Up to this many windows the plain recursion is cheaper than the cumulative sums (the
# daemon closes one window at a time); tests check both paths against each other.
_SMALL = 4


def _propagate_stepwise(
    state: CovarianceState, positions: np.ndarray, noise: np.ndarray
) -> tuple[np.ndarray, CovarianceState]:
    """P_k = S(p_k - p_{k-1}) P_{k-1} S(p_k - p_{k-1})^T + G_k, one window at a time."""
    out = np.empty((len(positions), 3, 3))
    p = state.cov
    prev = state.position
    s = np.eye(3)
    for k in range(len(positions)):
        d = positions[k] - prev
        s[0, 2], s[1, 2] = -d[1], d[0]
        p = s @ p @ s.T + noise[k]
        out[k] = p
        prev = positions[k]
    out = 0.5 * (out + np.swapaxes(out, 1, 2))
    return out, CovarianceState(cov=out[-1].copy(), position=positions[-1].copy())


def propagate(
    state: CovarianceState, positions: np.ndarray, noise: np.ndarray
) -> tuple[np.ndarray, CovarianceState]:
    """Pose covariances (n,3,3) after each window, and the state rebased on the last one.

    ``positions`` (n,2) are the poses' positions after each window; ``noise`` (n,3,3) the
    world-frame step noise G_k entering at those positions.
    """
    n = len(positions)
    if n == 0:
        return np.zeros((0, 3, 3)), state
    if n <= _SMALL:
        return _propagate_stepwise(state, positions, noise)
    # Inputs: the carried covariance (at its position) followed by each window's noise.
    # Only position differences matter: work relative to the carried position, or far
    # from the origin (map coordinates) the expanded sums cancel catastrophically.
    rel = positions - state.position
    g = np.concatenate([state.cov[None], noise])
    b = _perp(np.concatenate([np.zeros((1, 2)), rel]))
    a = _perp(rel)
    # Row 0 is the carried input, so every window's cumulative sum includes it.  Each entry
    # is its own (n,) array, computed from the matrix expression
    #   pp = s1 + a s2^T - s3 + s2 a^T - s3^T + s4 a a^T - a s5^T - s5 a^T + s6
    # (the diagonal in its order): numpy's operations over trailing axes of two cost
    # several times as much per element.
    gtt = g[:, 2, 2]
    ai, bi = (a[:, 0], a[:, 1]), (b[:, 0], b[:, 1])
    gpt = (g[:, 0, 2], g[:, 1, 2])
    gtb = (gtt * bi[0], gtt * bi[1])
    # Every running sum in one cumsum along the rows of a stack: numpy accumulates each
    # row in sequence as it does a lone array (the same additions, bit for bit), at one
    # call's fixed cost for fifteen (a block of 50 windows is mostly fixed costs).
    sums = np.cumsum(
        np.stack([
            g[:, 0, 0], g[:, 1, 1], g[:, 0, 1], gpt[0], gpt[1], gtt, gtb[0], gtb[1],
            bi[0] * gpt[0], bi[1] * gpt[1], bi[0] * gpt[1], bi[1] * gpt[0],
            gtb[0] * bi[0], gtb[1] * bi[1], gtb[0] * bi[1],
        ]),
        axis=1,
    )[:, 1:]  # fmt: skip
    s1 = {(0, 0): sums[0], (1, 1): sums[1], (0, 1): sums[2]}  # g's
    s2, s4, s5 = (sums[3], sums[4]), sums[5], (sums[6], sums[7])
    s3 = {(0, 0): sums[8], (1, 1): sums[9], (0, 1): sums[10], (1, 0): sums[11]}  # b_i g_j
    s6 = {(0, 0): sums[12], (1, 1): sums[13], (0, 1): sums[14]}  # g_tt b_i b_j

    def pp(i: int) -> np.ndarray:
        return (
            s1[i, i] + ai[i] * s2[i] - s3[i, i] + s2[i] * ai[i] - s3[i, i]
            + s4 * (ai[i] * ai[i]) - ai[i] * s5[i] - s5[i] * ai[i] + s6[i, i]
        )  # fmt: skip

    out = np.empty((n, 3, 3))
    out[:, 0, 0] = pp(0)
    out[:, 1, 1] = pp(1)
    # The off-diagonal entry once, as the mean of pp's two (equal but for rounding) sides:
    # exactly symmetric, as consumers rely on, for half of their work.
    a0, a1 = ai
    out[:, 0, 1] = out[:, 1, 0] = (
        s1[0, 1] + (a0 * s2[1] + s2[0] * a1) - (s3[0, 1] + s3[1, 0]) + s4 * (a0 * a1)
        - (a0 * s5[1] + s5[0] * a1) + s6[0, 1]
    )  # fmt: skip
    for i in range(2):
        out[:, i, 2] = out[:, 2, i] = s2[i] + ai[i] * s4 - s5[i]
    out[:, 2, 2] = s4
    return out, CovarianceState(cov=out[-1].copy(), position=positions[-1].copy())
