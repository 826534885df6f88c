"""The daemon's one-window path: the maths of models/integrate/covariance for a single window.

The daemon closes one window at a time; the array functions (``models.solve``,
``integrate.body_step``, ``step_jacobian``, ``compose``, ``covariance.propagate``) validate
and broadcast their inputs and pay numpy's fixed cost per call dozens of times for it, which
was most of the daemon's CPU.  Here the same formulas run on Python floats and a handful of
3x3 products.  Replay (millions of windows) keeps the array path; tests/test_onewindow.py
checks with hypothesis that both paths give the same windows (models, integrators, dead mice,
rank loss).

``body_counts``, ``linear`` and ``advance`` run in the compiled core where it is built
(csrc/onewindow.c, issue 28): the functions here are its specification, and
tests/test_core_window.py holds the two equal bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from operator import mul

from mousedom import core
from mousedom.fusion import integrate

_SINC = [float(c) for c in integrate._SINC_COEF]
_DSINC = [float(c) for c in integrate._DSINC_COEF]
_SWITCH = integrate._SINC_SWITCH


def _horner(h2: float, coef: list[float]) -> float:
    acc = coef[-1]
    for c in coef[-2::-1]:
        acc = acc * h2 + c
    return acc


def sinc(h: float) -> float:
    """integrate.sinc for one float."""
    if abs(h) < _SWITCH:
        return _horner(h * h, _SINC)
    return math.sin(h) / h


def dsinc(h: float) -> float:
    """integrate.dsinc for one float."""
    if abs(h) < _SWITCH:
        return h * _horner(h * h, _DSINC)
    return (h * math.cos(h) - math.sin(h)) / (h * h)


def body_step(ux: float, uy: float, a: float, method: str) -> tuple[float, float]:
    """integrate.body_step for one window: the step's (dx, dy); dtheta is ``a``."""
    if method == "exact":
        h = 0.5 * a
        sn = sinc(h)
        s, c = sn * math.cos(h), sn * math.sin(h)
    elif method == "taylor":
        s, c = 1.0 - a * a / 6.0, 0.5 * a
    elif method == "euler":
        s, c = math.cos(a), math.sin(a)
    elif method == "midpoint":
        s, c = math.cos(0.5 * a), math.sin(0.5 * a)
    else:
        raise ValueError(f"unknown integrator {method!r}")
    return ux * s - uy * c, ux * c + uy * s


Matrix3 = list[list[float]]


def _mul(a: Matrix3, b: Matrix3) -> Matrix3:
    """a @ b for 3x3 row lists."""
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return [
        [r0 * b00 + r1 * b10 + r2 * b20, r0 * b01 + r1 * b11 + r2 * b21,
         r0 * b02 + r1 * b12 + r2 * b22]
        for r0, r1, r2 in a
    ]  # fmt: skip


def _mul_t(a: Matrix3, b: Matrix3) -> Matrix3:
    """a @ b.T for 3x3 row lists."""
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return [
        [r0 * b00 + r1 * b01 + r2 * b02, r0 * b10 + r1 * b11 + r2 * b12,
         r0 * b20 + r1 * b21 + r2 * b22]
        for r0, r1, r2 in a
    ]  # fmt: skip


def noise(theta_before: float, ux: float, uy: float, a: float, q_cov: Matrix3) -> Matrix3:
    """covariance.world_step_noise with integrate.step_jacobian, for one window (3x3):
    G = M Q M^T with M = blockdiag(R(theta_before), 1) @ d step / d q."""
    h = 0.5 * a
    sn, dsn = sinc(h), dsinc(h)
    ch, sh = math.cos(h), math.sin(h)
    s, c = sn * ch, sn * sh
    ds = 0.5 * (dsn * ch - sn * sh)
    dc = 0.5 * (dsn * sh + sn * ch)
    j02, j12 = ux * ds - uy * dc, ux * dc + uy * ds  # the step's derivative by dtheta
    ct, st = math.cos(theta_before), math.sin(theta_before)
    m = [
        [ct * s - st * c, -ct * c - st * s, ct * j02 - st * j12],
        [st * s + ct * c, -st * c + ct * s, st * j02 + ct * j12],
        [0.0, 0.0, 1.0],
    ]
    return _mul_t(_mul(m, q_cov), m)


def propagate(cov: Matrix3, prev: Sequence[float], pos: Sequence[float], g: Matrix3) -> Matrix3:
    """covariance._propagate_stepwise for one window: S P S^T + G, symmetrised, where
    S = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]] moves the covariance's reference point by
    (dx, dy) from ``prev`` to ``pos``."""
    u, v = prev[1] - pos[1], pos[0] - prev[0]  # S's third column
    c0, c1, c2 = cov
    sp = [  # S P: rows 0 and 1 take u (or v) times row 2
        [c0[0] + u * c2[0], c0[1] + u * c2[1], c0[2] + u * c2[2]],
        [c1[0] + v * c2[0], c1[1] + v * c2[1], c1[2] + v * c2[2]],
        c2,
    ]
    p = [
        [r[0] + r[2] * u + gr[0], r[1] + r[2] * v + gr[1], r[2] + gr[2]]
        for r, gr in zip(sp, g, strict=True)
    ]
    return [[0.5 * (p[i][j] + p[j][i]) for j in range(3)] for i in range(3)]


def body_counts(to_body: list[list[list[float]]], counts: list[tuple[float, float]]) -> list[float]:
    """Every mouse's counts in body-frame metres, flattened (x1, y1, x2, ...): einsum
    "nij,nj->ni" of the tracker's array path (two products and one sum per entry, which
    floating-point addition gives the same whatever the order)."""
    native = core.native
    if native is not None:
        done = native.body_counts(to_body, counts)
        if done is not None:
            return done
    d: list[float] = []
    for i, ((m00, m01), (m10, m11)) in enumerate(to_body):
        cx, cy = counts[i]
        d += (m00 * cx + m01 * cy, m10 * cx + m11 * cy)
    return d


def linear(
    d: list[float], a_rows: list[list[float]], b_rows: list[list[float]]
) -> tuple[list[float], list[float]]:
    """models._linear for one window: q restricted to the model's columns (B d) and the
    residual d - A q of the live mice, flattened like ``d``.  A and B are the cached
    estimator's matrices as row lists."""
    native = core.native
    if native is not None:
        done = native.linear(d, a_rows, b_rows)
        if done is not None:
            return done
    # map(mul) rather than comprehensions: no frame per dot product (Python 3.11)
    qk = [sum(map(mul, row, d)) for row in b_rows]
    return qk, [v - sum(map(mul, row, qk)) for v, row in zip(d, a_rows, strict=True)]


def advance(
    pose: Sequence[float], cov: Matrix3, at: Sequence[float], q: Sequence[float], owed: float,
    c3: Matrix3, method: str,
) -> tuple[list[float], Matrix3]:  # fmt: skip
    """The pose (x, y, theta) and its covariance about the point ``at`` carried over one
    window's twist ``q`` (ux, uy, a) of covariance ``c3``, turned by ``owed`` radians more
    (the gyro's renewals give heading back to the pose, not to the twist): the pose and
    its covariance (about the new position) after the window."""
    native = core.native
    if native is not None:
        done = native.advance(pose, cov, at, q, owed, c3, method, _SINC, _DSINC, _SWITCH)
        if done is not None:
            return done
    ux, uy, a = q
    sx, sy = body_step(ux, uy, a + owed, method)
    x0, y0, th0 = pose
    cb, sb = math.cos(th0), math.sin(th0)
    x, y, th = x0 + (cb * sx - sb * sy), y0 + (sb * sx + cb * sy), th0 + a + owed
    g = noise(th0, ux, uy, a + owed, c3)
    return [x, y, th], propagate(cov, at, (x, y), g)
