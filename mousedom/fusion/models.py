"""Motion models: per window, the mice's body-frame displacements -> the body twist increment.

Over a window with constant body twist, mouse i at body position p_i moves (in body axes, as
its readings integrate) by d_i = (u_x - a p_iy, u_y + a p_ix): d = A q with A from
``geometry.design_matrix`` (Kim & Lee eq. 3-6, displacements in place of velocities).
``integrate.body_step`` then turns q into the window's step.

- ``lsq``: weighted least squares over any N >= 2 live mice not all at one point
  (Kim & Lee eq. 7-8 with W = diag(1/sigma^2)).
- ``diff-drive``: the same with u_y = 0 (a differential-drive robot does not slide sideways at
  its axle midpoint, the body origin).  One mouse off the axle is enough: Hong's Theorem 1.
- ``bonarini``: the two-mouse geometric solution of Bonarini, Matteucci & Restelli (2004),
  eqs. (3)-(14), evaluated as published (one deviation, see ``_bonarini_mid``).
- ``wheels``: the McGill differential-drive encoder formulas, as a reference.

Arrays in, arrays out: windows that share a pattern of live mice are solved together with one
precomputed matrix; nothing loops per window.  Where the live mice cannot determine the model,
the window gets ok=False and q = 0, cov = 0: never invent motion.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from mousedom.fusion import integrate
from mousedom.fusion.choices import MODELS as MODELS  # models.MODELS: these models
from mousedom.fusion.geometry import design_matrix

# Windows of a batch: all of them (a slice) or those at an index array.
Rows = slice | np.ndarray

# Relative singular-value threshold for "the live mice determine the model" (as geometry.py).
_RANK_TOL = 1e-9


# A reading within this fraction of its mouse's sigma is no count: the rounding dust a
# split at a window edge can leave (1e-17 counts on the daemon's float path where replay's
# arrays give 0).  Whether a window "counted" (StepNoise.moving or .rest) must not hang on it.
STILL = 1e-9


@dataclass(frozen=True)
class StepNoise:
    """Each mouse's reading error that accumulates (per axis, variances in metres^2 per
    window), learnt from the redundancy (``noiserate``): ``moving`` for windows in which a
    live mouse counted, ``rest`` for windows without a count.  Given to ``solve``, the
    covariance of q is the sandwich B diag(v) B^T of the estimator B (whose weights stay
    the config's sigma): exact for the estimator in use, whatever its weights."""

    moving: np.ndarray  # (N,)
    rest: np.ndarray  # (N,)


@dataclass(frozen=True)
class Solution:
    """Per-window result of a model.

    q: (n, 3) twist increment (u_x, u_y, dtheta), metres and radians, body frame.
    cov: (n, 3, 3) covariance of q given the mice's sigma, or their learnt StepNoise where
        given (zero where ok is False).
    residual: (n, N, 2) d - A q per mouse, body axes, metres; zero for mice that took no part
        and for windows that could not be solved (nothing was checked there).
    used: (n,) number of live mice in the window.
    ok: (n,) False where the live mice could not determine the model (q is then 0).
    """

    q: np.ndarray
    cov: np.ndarray
    residual: np.ndarray
    used: np.ndarray
    ok: np.ndarray

    def __len__(self) -> int:
        return len(self.q)


def solve(
    model: str,
    d: np.ndarray,
    positions: np.ndarray,
    sigma: np.ndarray | float,
    mask: np.ndarray | None = None,
    noise: StepNoise | None = None,
) -> Solution:
    """Solve ``model`` for every window.

    d: (n, N, 2) each mouse's displacement over each window, body axes, metres.
    positions: (N, 2) mouse mounts in the body frame, metres.
    sigma: (N,) (or a scalar) noise standard deviation per axis per window, metres.
    mask: (n, N) bool, which mice are live in each window; None means all.
    noise: the covariance's error model (StepNoise) where learnt; None: sigma's.
    """
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    d = np.asarray(d, dtype=float)
    if d.ndim != 3 or d.shape[2] != 2:
        raise ValueError(f"d must have shape (n, N, 2), got {d.shape}")
    n, nm, _ = d.shape
    positions = np.asarray(positions, dtype=float)
    if positions.shape != (nm, 2):
        raise ValueError(f"positions must have shape ({nm}, 2), got {positions.shape}")
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (nm,))
    if not np.all(sigma > 0) or not np.all(np.isfinite(sigma)):
        raise ValueError(f"sigma must be positive and finite, got {sigma}")
    if model == "bonarini" and nm != 2:
        raise ValueError(f"bonarini takes exactly two mice, got {nm}")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (n, nm):
            raise ValueError(f"mask must have shape ({n}, {nm}), got {mask.shape}")

    q = np.zeros((n, 3))
    cov = np.zeros((n, 3, 3))
    residual = np.zeros((n, nm, 2))
    ok = np.zeros(n, dtype=bool)
    if mask is None or mask.all():  # every mouse live (the usual case): no row sums
        used = np.full(n, nm, dtype=int)
    else:
        used = mask.sum(axis=1).astype(int)

    for live, rows in live_patterns(mask, n, nm):
        if not live.any():
            continue
        if model == "bonarini":
            if not live.all():
                continue  # it needs both mice
            qg, cg = _bonarini(d[rows], positions, sigma)
            q[rows] = qg
            cov[rows] = cg
            ok[rows] = True
            a = design_matrix(positions)
            residual[rows] = d[rows] - (qg @ a.T).reshape(-1, nm, 2)
        else:
            cols = [0, 1, 2] if model == "lsq" else [0, 2]
            _linear(d, positions, sigma, live, rows, cols, q, cov, residual, ok, noise)
    return Solution(q=q, cov=cov, residual=residual, used=used, ok=ok)


def live_patterns(mask: np.ndarray | None, n: int, nm: int) -> Iterator[tuple[np.ndarray, Rows]]:
    """(live mice, rows) for each distinct mask pattern; rows is a slice or an index array."""
    if mask is None or mask.all():
        yield np.ones(nm, dtype=bool), slice(None)
        return
    if nm > 62:
        raise ValueError("at most 62 mice")
    codes = mask.astype(np.int64) @ (np.int64(1) << np.arange(nm, dtype=np.int64))
    # (return_inverse also keeps numpy 2 from importing numpy.ma, 12 ms of a replay's start)
    distinct, which = np.unique(codes, return_inverse=True)
    which = which.ravel()
    for k, code in enumerate(distinct.tolist()):
        live = ((code >> np.arange(nm)) & 1).astype(bool)
        yield live, np.flatnonzero(which == k)


def _linear(
    d: np.ndarray,
    positions: np.ndarray,
    sigma: np.ndarray,
    live: np.ndarray,
    rows: Rows,
    cols: list[int],
    q: np.ndarray,
    cov: np.ndarray,
    residual: np.ndarray,
    ok: np.ndarray,
    noise: StepNoise | None = None,
) -> None:
    """Weighted LSQ on the live mice for the windows ``rows``, restricted to q[cols]."""
    idx = np.flatnonzero(live)
    key = (positions.tobytes(), sigma.tobytes(), live.tobytes(), tuple(cols))
    est = estimator(*key)
    if est is None:
        return  # rank deficient: ok stays False, q and cov stay 0
    a, b, c = est
    dl = d[rows] if live.all() else d[rows][:, idx]
    m = len(dl)
    dl = dl.reshape(m, 2 * len(idx))
    qk = dl @ b.T
    res = (dl - qk @ a.T).reshape(m, len(idx), 2)
    if noise is None:
        c3 = np.zeros((3, 3))
        c3[np.ix_(cols, cols)] = c
    else:
        moving = np.any(np.abs(dl) > np.repeat(STILL * sigma[idx], 2), axis=1)
        c3 = np.where(
            moving[:, None, None],
            noise_covariance(*key, noise.moving[idx].tobytes()),
            noise_covariance(*key, noise.rest[idx].tobytes()),
        )
    if isinstance(rows, slice) and live.all():
        q[rows, cols] = qk
        residual[rows] = res
    else:
        # whole-row writes: much faster than 2-D fancy indexing on millions of windows
        q3 = np.zeros((m, 3))
        q3[:, cols] = qk
        q[rows] = q3
        r3 = np.zeros((m, len(live), 2))
        r3[:, idx] = res
        residual[rows] = r3
    cov[rows] = c3
    ok[rows] = True


def sandwich(b: np.ndarray, variance: np.ndarray, cols: tuple[int, ...] | list[int]) -> np.ndarray:
    """The 3x3 covariance B diag(v) B^T of q = B d (B: (k, 2L) over the live mice, v their
    per-axis variances (L,)), with zeros outside ``cols``."""
    c = (b * np.repeat(variance, 2)) @ b.T
    c3 = np.zeros((3, 3))
    c3[np.ix_(list(cols), list(cols))] = 0.5 * (c + c.T)
    return c3


@functools.lru_cache(maxsize=256)
def noise_covariance(
    positions: bytes, sigma: bytes, live: bytes, cols: tuple[int, ...], variance: bytes
) -> np.ndarray:
    """``sandwich`` of the estimator ``estimator(positions, sigma, live, cols)`` (which
    must not be None) with the live mice's ``variance`` (L,), read-only.  Cached on the
    values, not on the StepNoise: the noise rate renews its StepNoise at every block end,
    where only the moving variances change (the rest ones are the config's sigma times a
    constant), and the screen's re-solve reuses the block's noise; a key of values needs
    no invalidation when the tracker rebinds."""
    est = estimator(positions, sigma, live, cols)
    assert est is not None  # the caller solved with it
    c3 = sandwich(est[1], np.frombuffer(variance), cols)
    c3.flags.writeable = False
    return c3


@functools.lru_cache(maxsize=256)
def estimator(
    positions: bytes, sigma: bytes, live: bytes, cols: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(A, B, C) for the live mice: B = (A^T W A)^-1 A^T W, C = (A^T W A)^-1; None if the
    live mice lack rank.  Cached: a rig has few live patterns, and the daemon solves one
    window at a time, where a fresh SVD per call would be most of the cost."""
    p = np.frombuffer(positions).reshape(-1, 2)
    s = np.frombuffer(sigma)
    idx = np.flatnonzero(np.frombuffer(live, dtype=bool))
    a = design_matrix(p[idx])[:, list(cols)]  # (2L, k)
    w = np.repeat(1.0 / s[idx] ** 2, 2)  # per row: x1, y1, x2, ...
    sv = np.linalg.svd(a * np.sqrt(w)[:, None], compute_uv=False)
    if len(sv) < len(cols) or not sv[-1] > _RANK_TOL * sv[0]:
        return None
    c = np.linalg.inv(a.T @ (w[:, None] * a))
    b = c @ (a.T * w)  # (k, 2L)
    for m in (a, b, c):
        m.flags.writeable = False
    return a, b, c


# --- Bonarini, Matteucci & Restelli (2004) -----------------------------------------------


def bonarini_frame(positions: np.ndarray) -> tuple[int, int, np.ndarray, np.ndarray, float]:
    """Their frame for two mice at body ``positions``: (left, right, origin, R, D).

    x runs along the joining line from the "left" mouse (at -D/2) to the "right" one (+D/2),
    y is x turned +90 degrees (forward in their Figure 1), the origin is the midpoint.  R's
    columns are those axes in body coordinates.  "Left" is the mouse that makes their y point
    forward (positive body x); for mice in a line along body x, the one behind.
    """
    p = np.asarray(positions, dtype=float).reshape(2, 2)
    v = p[1] - p[0]
    left, right = (0, 1) if (v[1] < 0 or (v[1] == 0 and v[0] > 0)) else (1, 0)
    ex = p[right] - p[left]
    dist = float(np.hypot(ex[0], ex[1]))
    if dist == 0:
        raise ValueError("bonarini needs the two mice apart (D > 0)")
    ex = ex / dist
    rot = np.array([[ex[0], -ex[1]], [ex[1], ex[0]]])
    return left, right, 0.5 * (p[0] + p[1]), rot, dist


def _alpha_length(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (3) alpha = arctan(y/x) (the published arctan, not atan2) and eq. (4) l, signed."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        alpha = np.arctan(y / x)
        alpha = np.where(x == 0, np.where(y == 0, 0.0, np.copysign(np.pi / 2, y)), alpha)
        # Eq. (4) says l = |x| for alpha = 0; |x| would turn a backward step into a forward
        # one, so l = x there (the one deviation).  Elsewhere l = y / sin(alpha), signed, so
        # that (l cos alpha, l sin alpha) = (x, y) whatever quadrant arctan folded into.
        # That l is the projection x cos(alpha) + y sin(alpha), which is how it is computed:
        # y / sin(alpha) is the same number but loses all its digits when alpha is tiny but
        # not zero (hypothesis found a window moving along the joining line that did).
        length = x * np.cos(alpha) + y * np.sin(alpha)
    return alpha, length


def bonarini_mid(
    xl: np.ndarray, yl: np.ndarray, xr: np.ndarray, yr: np.ndarray, dist: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Their eqs. (3)-(14): readings in their frame -> (dx, dy, dtheta) of the midpoint.

    Eqs. (9)-(12) are r (sin(alpha + t) - sin alpha) sign(t) with r = l/|t| (eqs. 6-7), i.e.
    (l/t)(sin(alpha + t) - sin alpha) = l sinc(t/2) cos(alpha + t/2) by the sum-to-product
    identity; likewise y' = l sinc(t/2) sin(alpha + t/2).  This is the same number, and its
    t -> 0 limit needs no division by zero (sinc has its series near 0).
    """
    al, ll = _alpha_length(xl, yl)
    ar, lr = _alpha_length(xr, yr)
    # Eq. (8): sqrt(l_l^2 + l_r^2 - 2 cos(gamma) l_l l_r) with gamma = |alpha_l - alpha_r| is
    # the law of cosines (eq. 5) for the side joining the vectors l (cos alpha, sin alpha) of
    # the two mice.  Evaluated as written it cancels: for a nearly straight window the result
    # keeps only half the digits (an error of sqrt(eps) |l| / D, ~2e-9 rad at 3 cm per window
    # and D = 0.25 m).  The length of the difference of those two vectors is the same number
    # without the cancellation, so that is how it is computed.
    ex = ll * np.cos(al) - lr * np.cos(ar)
    ey = ll * np.sin(al) - lr * np.sin(ar)
    dth = np.sign(yr - yl) * np.hypot(ex, ey) / dist  # eq. (8)
    half = 0.5 * dth
    k = integrate.sinc(half)
    xr2 = lr * k * np.cos(ar + half) + 0.5 * dist  # eq. (9)
    yr2 = lr * k * np.sin(ar + half)  # eq. (10)
    xl2 = ll * k * np.cos(al + half) - 0.5 * dist  # eq. (11)
    yl2 = ll * k * np.sin(al + half)  # eq. (12)
    return 0.5 * (xr2 + xl2), 0.5 * (yr2 + yl2), dth  # eqs. (13), (14)


def _bonarini_q(readings: np.ndarray, origin: np.ndarray, rot: np.ndarray, dist: float):
    """readings (..., 4) = (x_l, y_l, x_r, y_r) in their frame -> q (..., 3) at the body origin.

    Their step Delta_M is of the midpoint frame M = B T_c (T_c: translation c, rotation R).
    The body's step is Delta_B = T_c Delta_M T_c^-1: translation R t_M + (I - R(dtheta)) c,
    rotation dtheta.  Then q = V(dtheta)^-1 step, so bonarini + exact reproduces their step.
    """
    mx, my, dth = bonarini_mid(
        readings[..., 0], readings[..., 1], readings[..., 2], readings[..., 3], dist
    )
    cth, sth = np.cos(dth), np.sin(dth)
    tx = rot[0, 0] * mx + rot[0, 1] * my + (1.0 - cth) * origin[0] + sth * origin[1]
    ty = rot[1, 0] * mx + rot[1, 1] * my - sth * origin[0] + (1.0 - cth) * origin[1]
    step = np.stack([tx, ty, dth], axis=-1)
    shape = step.shape
    return integrate.inverse_exact(step.reshape(-1, 3)).reshape(shape)


def _bonarini(
    d: np.ndarray, positions: np.ndarray, sigma: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """q (m, 3) and cov (m, 3, 3) for windows d (m, 2, 2) of two live mice.

    The covariance linearises the whole map numerically (central differences over the four
    readings, all windows at once) and propagates diag(sigma^2).  The step h = 1e-3 sigma is
    small against the noise, so the linearisation is local, and large against rounding.

    Eq. (8) turns with the sign of y_r - y_l: where the two forward readings are nearly
    equal (a straight window with noise) the turn jumps from +|e|/D to -|e|/D as they
    cross.  A central difference whose two points straddle that jump is no slope (it gave
    a heading variance up to 2.4e7 times the least squares' in one window of a straight
    drive in 1,700): there the difference is taken on the side of the window's own
    readings.  (Near straight driving the turn's spread is then about twice what this
    linearisation says, from the jump itself: docs/models.md.)
    """
    left, right, origin, rot, dist = bonarini_frame(positions)
    proj_l = d[:, left] @ rot  # body -> their frame: (x . ex, x . ey)
    proj_r = d[:, right] @ rot
    base = np.concatenate([proj_l, proj_r], axis=1)  # (m, 4)
    s4 = np.array([sigma[left], sigma[left], sigma[right], sigma[right]])
    h = 1e-3 * s4
    pert = np.broadcast_to(base, (9,) + base.shape).copy()
    for j in range(4):
        pert[1 + 2 * j, :, j] += h[j]
        pert[2 + 2 * j, :, j] -= h[j]
    qs = _bonarini_q(pert, origin, rot, dist)  # (9, m, 3)
    side = np.sign(pert[..., 3] - pert[..., 1])  # (9, m): which side of eq. (8)'s jump
    cols = []
    for j in range(4):
        plus, minus = 1 + 2 * j, 2 + 2 * j
        slope = (qs[plus] - qs[minus]) / (2 * h[j])
        straddle = side[plus] != side[minus]
        if straddle.any():
            ahead = (straddle & (side[plus] == side[0]))[:, None]
            behind = (straddle & (side[plus] != side[0]))[:, None]
            slope = np.where(ahead, (qs[plus] - qs[0]) / h[j], slope)
            slope = np.where(behind, (qs[0] - qs[minus]) / h[j], slope)
        cols.append(slope)
    jac = np.stack(cols, axis=-1)
    cov = (jac * s4**2) @ jac.transpose(0, 2, 1)
    return qs[0], cov


# --- McGill wheel odometry -----------------------------------------------------------------


def wheels(
    d_left: np.ndarray,
    d_right: np.ndarray,
    r_left: float,
    r_right: float,
    track: float,
    sigma: float = 0.0,
) -> Solution:
    """Differential-drive wheel encoders (McGill ECSE 211 notes), as a reference model.

    d_left, d_right: (n,) wheel angle increments per window, radians (their dlambda, drho).
    dC = (drho r_R + dlambda r_L)/2 is the arc length of the axle midpoint and
    dtheta = (drho r_R - dlambda r_L)/w, so q = (dC, 0, dtheta).  ``midpoint`` integration
    of this q is their recursion; ``exact`` adds their sinc(dtheta/2) length factor.
    sigma: optional noise std of each wheel angle increment (radians) for the covariance.
    """
    dl = np.asarray(d_left, dtype=float).reshape(-1)
    dr = np.asarray(d_right, dtype=float).reshape(-1)
    if dl.shape != dr.shape:
        raise ValueError(f"left and right wheel arrays differ in shape: {dl.shape} {dr.shape}")
    if not track > 0:
        raise ValueError(f"track must be positive, got {track}")
    n = len(dl)
    q = np.zeros((n, 3))
    q[:, 0] = 0.5 * (dr * r_right + dl * r_left)
    q[:, 2] = (dr * r_right - dl * r_left) / track
    jac = np.array([[0.5 * r_left, 0.5 * r_right], [0.0, 0.0], [-r_left / track, r_right / track]])
    c = sigma**2 * jac @ jac.T
    return Solution(
        q=q,
        cov=np.broadcast_to(c, (n, 3, 3)).copy(),
        residual=np.zeros((n, 0, 2)),
        used=np.full(n, 2, dtype=int),
        ok=np.ones(n, dtype=bool),
    )
