"""Mount positions from a reference motion: Kim & Lee section IV, and an exact fit.

Both methods take, per time window k, the body twist integrated over the window from a
reference sensor, w_k = (U_x, U_y, Θ) (metres, metres, radians), and each mouse's counts
summed over the same window.  A mouse at p reads, in body axes, exactly
(U_x - Θ p_y, U_y + Θ p_x) over any window (it integrates the body-frame velocity of its
own point, which is linear in the twist), so the windows need not have constant twist.

``kimlee``: Kim & Lee's linearised calibration, eqs. (31)-(48), kept as published.  It
corrects positions only (mount yaw and CPI are taken as configured) around the nominal
ones, dropping second-order terms (22), (27), (28).  It stacks the three rows of the
first measurement and the third row of every other one, (45)-(46), and solves with the
minimum-norm least squares (a pseudo-inverse in place of (48), which needs S^T S to be
invertible; for a pure rotation it is not, and the minimum-norm solution is what gives
their result (53)).

A limit of the published method, found while testing it: the third row of S_k is
w_k (p_true - 2 p_nominal) exactly, whatever the translation (the v_b terms of C1
and C2 cancel), so every measurement after the first adds the same equation, and S has
rank at most 3 for any motion, not 2N as (49) suggests.  With N >= 2 mice the result is
always a minimum-norm solution: right when the mounts are off by a common scale about the
centre (their example), not in general.  ``exact`` has no such limit.

``exact``: with the mouse's unknown yaw and CPI scale written as G = k R(yaw), k = 1/scale,
a reading m in the mouse's own frame (metres by the configured CPI) is G m in body axes,
so per window  k R(yaw) m = (U_x - Θ p_y, U_y + Θ p_x)  is linear in
z = (k cos yaw, k sin yaw, p_x, p_y): one small least squares per mouse gives position,
yaw and scale together, with no linearisation.  The motion must separate the unknowns:
it needs rotation (else positions are invisible), and more than a rotation about one
fixed point (else scale cannot be told from distance to that point).

A mouse's two count axes need not share one scale (the config has ``cpi: {x, y}``, and a
sensor's error on the floor differs between its axes).  One k for both, where the axes
differ, is wrong on both, and the mismatch leaks into the position: CPIs 1 % off either
way put a mouse 2.4 mm off with a stated standard error of 0.1 mm.  So ``exact_mount``
also fits G = R(yaw) diag(k_f, k_l) (forward: REL_Y's CPI, left: REL_X's), by Gauss-Newton
from the one-scale fit (only the yaw enters non-linearly), and keeps it where the two
scales differ by more than AXES_SIGMAS standard errors of their difference (and by
AXES_MIN); where they agree within that, the one-scale fit stands (one unknown fewer).
Some motions cannot tell the axes apart: without sideways motion (a differential drive
never slides) the body moves in two ways only, forward and turning, so a mouse's
readings give a 2 x 2 matrix, four numbers for five unknowns.  There (no per-axis fit,
or its difference known less well than AXES_UNSEEN) the one-scale fit stands, assuming
the configured ratio, and ``axes_seen`` is False, for the caller to say so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

# --------------------------------------------------------------------------- Kim & Lee


def kimlee_system(
    v_s: np.ndarray, v_m: np.ndarray, nominal: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """S and b of Kim & Lee eqs. (38)-(46) for M measurements.

    v_s (M, N, 2): mouse readings in body axes; v_m (M, 3): reference (v_bx, v_by, w_b);
    nominal (N, 2): nominal positions.  Velocities or per-window displacements both work
    (every term is linear in them).  Returns S ((M+2), 2N) and b (M+2,).
    """
    v_s = np.asarray(v_s, dtype=float)
    v_m = np.asarray(v_m, dtype=float).reshape(-1, 3)
    p = np.asarray(nominal, dtype=float).reshape(-1, 2)
    m_count, n = v_m.shape[0], p.shape[0]
    if v_s.shape != (m_count, n, 2):
        raise ValueError(f"v_s must have shape {(m_count, n, 2)}, got {v_s.shape}")
    vbx, vby, w = v_m[:, 0], v_m[:, 1], v_m[:, 2]
    s = np.zeros((m_count, 3, 2 * n))
    # C1 (38): third row [v_iy, -v_ix] per mouse.
    s[:, 2, 0::2] += v_s[:, :, 1]
    s[:, 2, 1::2] += -v_s[:, :, 0]
    # C2 (39)-(40): rows [0, w], [-w, 0], [c_i1, c_i2] with nominal p.
    s[:, 0, 1::2] += w[:, None]
    s[:, 1, 0::2] += -w[:, None]
    s[:, 2, 0::2] += -vby[:, None] - 2 * w[:, None] * p[None, :, 0]
    s[:, 2, 1::2] += vbx[:, None] - 2 * w[:, None] * p[None, :, 1]
    # b (43) = A^T (A v_m - v_s) with the nominal A.
    pred = np.stack(
        [vbx[:, None] - w[:, None] * p[None, :, 1], vby[:, None] + w[:, None] * p[None, :, 0]],
        axis=-1,
    )
    e = pred - v_s  # (M, N, 2)
    b = np.stack(
        [
            e[:, :, 0].sum(1),
            e[:, :, 1].sum(1),
            (-p[None, :, 1] * e[:, :, 0] + p[None, :, 0] * e[:, :, 1]).sum(1),
        ],
        axis=-1,
    )
    # (45)-(46): all of the "first" measurement, the third row of the others.  Rows 1-2
    # of a measurement are its rotation times constants, so a window without rotation
    # gives zero rows there; the window that turns most plays the first measurement.
    first = int(np.argmax(np.abs(w)))
    others = np.arange(m_count) != first
    big_s = np.concatenate([s[first], s[others, 2, :]], axis=0)
    big_b = np.concatenate([b[first], b[others, 2]])
    return big_s, big_b


@dataclass(frozen=True)
class KimLeeResult:
    positions: np.ndarray  # (N, 2) calibrated positions p~ = p_nominal + delta p
    rank: int  # rank of S; below 2N the minimum-norm solution was taken
    unknowns: int  # 2N


MAX_KIMLEE_RANK = 3  # the rank of S in exact arithmetic, whatever the motion (see above)


def kimlee(v_s: np.ndarray, v_m: np.ndarray, nominal: np.ndarray) -> KimLeeResult:
    """Kim & Lee (47) as a minimum-norm least squares; see the module docstring.

    The pseudo-inverse keeps at most the 3 largest singular values of S: in exact
    arithmetic S has no more, and with noisy counts the other directions would be filled
    with noise divided by nearly nothing (hundreds of millimetres in bench/calibration.py).
    Noise-free this is the plain pseudo-inverse, which gives their (53).
    """
    s, b = kimlee_system(v_s, v_m, nominal)
    u, sv, vt = np.linalg.svd(s, full_matrices=False)
    rank = int(min(MAX_KIMLEE_RANK, np.sum(sv > 1e-9 * sv[0]))) if sv[0] > 0 else 0
    dp = vt[:rank].T @ ((u[:, :rank].T @ b) / sv[:rank])
    p = np.asarray(nominal, dtype=float).reshape(-1, 2)
    return KimLeeResult(p + dp.reshape(-1, 2), int(rank), 2 * len(p))


# --------------------------------------------------------------------------- exact


# The two count axes' scales are fitted apart where they differ by more than this many
# standard errors of their difference; within it they agree, and one scale is fitted.
AXES_SIGMAS = 3.0
AXES_MIN = 2e-4  # ... and by more than this (0.02 %: below any CPI worth writing)
# Where that difference is known less well than this, the motion cannot tell the axes
# apart: one scale, in the configured ratio, and the caller says so.  Its standard error
# is that of a linearisation, and where the motion barely tells the axes apart it is
# too small: on random rigs with 1 % noise a report, a mouse whose axes agree was told
# 13 +- 4 % apart (3.1 standard errors) and put 22 mm off; 8.4 +- 1.5 % was real.
AXES_UNSEEN = 0.02


@dataclass(frozen=True)
class MountFit:
    x: float
    y: float
    yaw: float  # radians: from body x to the mouse's forward direction
    scale: float  # true CPI / configured CPI: both axes' (per axis: their geometric mean)
    stderr: tuple[float, float, float, float]  # of x, y (m), yaw (rad), scale
    rms: float  # residual per window and axis, metres
    rank: int
    # per count axis (REL_X, REL_Y) where fitted apart (``AXES_SIGMAS``), with their
    # standard errors; None: one scale for both
    scales: tuple[float, float] | None = None
    scales_stderr: tuple[float, float] | None = None
    # the per-axis fit's scale x - scale y and its standard error (inf: the motion cannot
    # tell the axes apart; NaN: not fitted, kimlee)
    axes_diff: float = math.nan
    axes_diff_stderr: float = math.nan

    @property
    def per_axis(self) -> bool:
        return self.scales is not None

    @property
    def scale_x(self) -> float:
        return self.scales[0] if self.scales is not None else self.scale

    @property
    def scale_y(self) -> float:
        return self.scales[1] if self.scales is not None else self.scale

    @property
    def axes_seen(self) -> bool:
        """Whether the motion told the two axes' scales apart (their difference known to
        ``AXES_UNSEEN``); False also where not fitted (kimlee)."""
        return bool(self.axes_diff_stderr <= AXES_UNSEEN)

    def as_json(self) -> dict:
        doc = {
            "x": round(self.x, 6),
            "y": round(self.y, 6),
            "yaw": round(float(np.degrees(self.yaw)), 4),
        }
        if not self.per_axis:
            doc["scale"] = round(self.scale, 6)
        doc["scale_x"] = round(self.scale_x, 6)
        doc["scale_y"] = round(self.scale_y, 6)
        return doc


class MountError(ValueError):
    """The motion cannot separate the unknowns; the message says what motion to add."""


def exact_system(m: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the per-mouse system in z = (k cos yaw, k sin yaw, p_x, p_y).

    m (n, 2): readings in the mouse frame (metres by the configured CPI); w (n, 3) twist.
      k(c m_x - s m_y) + Θ p_y = U_x
      k(s m_x + c m_y) - Θ p_x = U_y
    """
    m = np.asarray(m, dtype=float).reshape(-1, 2)
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    n = len(m)
    a = np.zeros((2 * n, 4))
    a[0::2, 0], a[0::2, 1], a[0::2, 3] = m[:, 0], -m[:, 1], w[:, 2]
    a[1::2, 0], a[1::2, 1], a[1::2, 2] = m[:, 1], m[:, 0], -w[:, 2]
    rhs = np.empty(2 * n)
    rhs[0::2], rhs[1::2] = w[:, 0], w[:, 1]
    return a, rhs


def motion_problem(w: np.ndarray, length: float = 0.1) -> str | None:
    """Why the reference motion ``w`` (n, 3) cannot give mounts, or None.

    ``length`` (metres, about the rig's size) makes turns comparable with translations.
    """
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    scaled = w * np.array([1.0, 1.0, length])
    total = np.linalg.norm(scaled)
    if total == 0:
        return "the reference shows no motion at all"
    if np.linalg.norm(scaled[:, 2]) < 0.02 * total:
        return (
            "the motion has (almost) no rotation, so it cannot show where the mice are: "
            "add turns (on the spot or along arcs)"
        )
    _, sv, vt = np.linalg.svd(scaled, full_matrices=False)
    if len(sv) < 2 or sv[1] < 0.02 * sv[0]:
        v = vt[0]
        cx, cy = -v[1] / v[2] * length, v[0] / v[2] * length  # v + w x c = 0
        return (
            f"all the motion is a rotation about one point (x={cx:.3f}, y={cy:.3f} m), "
            "which cannot tell a mouse's CPI scale from its distance to that point: add "
            "a straight drive or a turn about another point"
        )
    return None


def exact_mount(m: np.ndarray, w: np.ndarray) -> MountFit:
    """Position, yaw and scale of one mouse; raises MountError if they are not separable,
    or if the readings are a mirror image of the motion (the config's ``flip`` is wrong).
    The scale is one for both axes unless the two differ plainly (module docstring)."""
    if mirrored(m, w):
        raise MountError(
            "its readings are a mirror image of the reference motion, which no rotation and "
            "scale undo: the config's `flip` for it is wrong"
        )
    one = _one_scale(m, w)
    axes = _axes_fit(m, w, one)
    if axes is None:
        return replace(one, axes_diff=math.nan, axes_diff_stderr=math.inf)
    diff, diff_se = axes.axes_diff, axes.axes_diff_stderr
    if diff_se <= AXES_UNSEEN and abs(diff) > max(AXES_SIGMAS * diff_se, AXES_MIN):
        return axes
    if not diff_se <= AXES_UNSEEN:
        diff_se = math.inf
    return replace(one, axes_diff=diff, axes_diff_stderr=diff_se)


def mirrored(m: np.ndarray, w: np.ndarray) -> bool:
    """Whether the readings ``m`` (n, 2) are a mirror image of the motion ``w`` (n, 3).

    G = k R(yaw) (or R diag(k_f, k_l)) has a positive determinant; a mouse whose ``flip``
    is configured wrong reads through a reflection, which no such G represents, and the
    one-scale fit then returns a mount 0.1 m and a CPI 60 % off with nothing to show
    for it but a large residual.  The free linear map B m = (U_x - Θ p_y, U_y + Θ p_x),
    six unknowns (B, p_x, p_y) and linear, tells: det B < 0.  Only where the motion
    determines B (it needs sideways motion: without it the readings give four numbers,
    as ``_axes_fit`` says, and a mirror cannot be seen); a reflection's determinant is
    -k^2, so noise that flips its sign would be 100 % of the motion."""
    m = np.asarray(m, dtype=float).reshape(-1, 2)
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    n = len(m)
    if n < 4:  # 2n equations, 6 unknowns and a residual
        return False
    a = np.zeros((2 * n, 6))  # (B11, B12, B21, B22, p_x, p_y)
    a[0::2, 0], a[0::2, 1], a[0::2, 5] = m[:, 0], m[:, 1], w[:, 2]
    a[1::2, 2], a[1::2, 3], a[1::2, 4] = m[:, 0], m[:, 1], -w[:, 2]
    rhs = np.empty(2 * n)
    rhs[0::2], rhs[1::2] = w[:, 0], w[:, 1]
    norms = np.linalg.norm(a, axis=0)
    if np.any(norms == 0) or not np.all(np.isfinite(a)) or not np.all(np.isfinite(rhs)):
        return False
    an = a / norms
    sv = np.linalg.svd(an, compute_uv=False)
    if sv[-1] <= 1e-6 * sv[0]:
        return False
    zn, *_ = np.linalg.lstsq(an, rhs, rcond=None)
    b11, b12, b21, b22 = (zn / norms)[:4]
    det = b11 * b22 - b12 * b21
    # Mirrored only where the map is plainly a reflection: its determinant negative and
    # as large as a rotation's would be (|det| = |B|^2 / 2 for k R(yaw) and for a mirror).
    return bool(det < -0.25 * (b11**2 + b12**2 + b21**2 + b22**2) / 2)


def _one_scale(m: np.ndarray, w: np.ndarray) -> MountFit:
    """The fit with one scale for both axes: linear in z (``exact_system``)."""
    a, rhs = exact_system(m, w)
    if len(rhs) < 4:
        raise MountError(f"{len(rhs) // 2} window(s) of motion, need at least 2")
    norms = np.linalg.norm(a, axis=0)
    if np.any(norms == 0):
        raise MountError("this mouse or the reference shows no motion in some unknown")
    an = a / norms
    sv = np.linalg.svd(an, compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * sv[0]))
    if rank < 4:
        raise MountError("the motion cannot separate position, yaw and scale of this mouse")
    zn, *_ = np.linalg.lstsq(an, rhs, rcond=None)
    z = zn / norms
    res = rhs - a @ z
    dof = len(rhs) - 4
    sigma2 = float(res @ res) / dof if dof > 0 else 0.0
    cov = sigma2 * np.linalg.inv(a.T @ a)
    c, s, px, py = z
    k = float(np.hypot(c, s))
    if k == 0:
        raise MountError("the mouse's readings do not follow the reference at all")
    yaw = float(np.arctan2(s, c))
    g_k = np.array([c / k, s / k, 0, 0])
    g_yaw = np.array([-s / k**2, c / k**2, 0, 0])
    se_k = float(np.sqrt(max(g_k @ cov @ g_k, 0.0)))
    se_yaw = float(np.sqrt(max(g_yaw @ cov @ g_yaw, 0.0)))
    stderr = (float(np.sqrt(cov[2, 2])), float(np.sqrt(cov[3, 3])), se_yaw, se_k / k**2)
    rms = float(np.sqrt(np.mean(res**2)))
    return MountFit(float(px), float(py), yaw, 1.0 / k, stderr, rms, rank)


def _axes_residual(theta: np.ndarray, m: np.ndarray, w: np.ndarray):
    """The per-axis model's residual (2n,) and Jacobian (2n, 5) at theta = (yaw, k_f,
    k_l, p_x, p_y): R(yaw) diag(k_f, k_l) m - (U_x - Θ p_y, U_y + Θ p_x)."""
    yaw, kf, kl, px, py = theta
    c, s = math.cos(yaw), math.sin(yaw)
    mf, ml, turn = m[:, 0], m[:, 1], w[:, 2]
    res = np.empty(2 * len(m))
    res[0::2] = c * kf * mf - s * kl * ml + turn * py - w[:, 0]
    res[1::2] = s * kf * mf + c * kl * ml - turn * px - w[:, 1]
    jac = np.zeros((2 * len(m), 5))
    jac[0::2, 0], jac[1::2, 0] = -s * kf * mf - c * kl * ml, c * kf * mf - s * kl * ml
    jac[0::2, 1], jac[1::2, 1] = c * mf, s * mf
    jac[0::2, 2], jac[1::2, 2] = -s * ml, c * ml
    jac[1::2, 3] = -turn
    jac[0::2, 4] = turn
    return res, jac


def _axes_fit(m: np.ndarray, w: np.ndarray, one: MountFit) -> MountFit | None:
    """The fit with a scale per count axis, by Gauss-Newton from the one-scale fit ``one``;
    None where the motion cannot separate the five unknowns."""
    m = np.asarray(m, dtype=float).reshape(-1, 2)
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    if len(m) < 3:  # 2n equations, 5 unknowns and a residual
        return None
    theta = np.array([one.yaw, 1.0 / one.scale, 1.0 / one.scale, one.x, one.y])
    for _ in range(50):
        res, jac = _axes_residual(theta, m, w)
        norms = np.linalg.norm(jac, axis=0)
        if np.any(norms == 0) or not np.all(np.isfinite(jac)):
            return None
        step, *_ = np.linalg.lstsq(jac / norms, -res, rcond=None)
        theta = theta + step / norms
        if np.all(np.abs(step) <= 1e-12 * (1.0 + np.abs(theta * norms))):
            break
    res, jac = _axes_residual(theta, m, w)
    norms = np.linalg.norm(jac, axis=0)
    sv = np.linalg.svd(jac / norms, compute_uv=False)
    if not np.all(np.isfinite(sv)) or sv[-1] <= 1e-9 * sv[0]:
        return None
    dof = len(res) - 5
    sigma2 = float(res @ res) / dof
    cov = sigma2 * np.linalg.inv(jac.T @ jac)
    yaw, kf, kl, px, py = (float(v) for v in theta)
    if not (kf > 0 and kl > 0):  # a reading against its axis: no scale (the yaw is wrong)
        return None
    sy, sx = 1.0 / kf, 1.0 / kl
    grad = {  # of scale y, scale x, their difference and geometric mean, in (k_f, k_l)
        "y": np.array([0, -1 / kf**2, 0, 0, 0]),
        "x": np.array([0, 0, -1 / kl**2, 0, 0]),
    }
    grad["d"] = grad["x"] - grad["y"]
    gm = 1.0 / math.sqrt(kf * kl)
    grad["g"] = np.array([0, -0.5 * gm / kf, -0.5 * gm / kl, 0, 0])
    se = {k: float(np.sqrt(max(g @ cov @ g, 0.0))) for k, g in grad.items()}
    stderr = (float(np.sqrt(cov[3, 3])), float(np.sqrt(cov[4, 4])),
              float(np.sqrt(cov[0, 0])), se["g"])  # fmt: skip
    yaw = math.remainder(yaw, 2 * math.pi)
    rms = float(np.sqrt(np.mean(res**2)))
    return MountFit(px, py, yaw, gm, stderr, rms, 5, (sx, sy), (se["x"], se["y"]),
                    sx - sy, se["d"])  # fmt: skip
