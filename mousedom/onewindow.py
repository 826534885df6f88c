"""The daemon's one-window path: the maths of models/integrate/covariance for a single window.

The daemon closes one window at a time; the array functions (``models.solve``,
``integrate.body_step``, ``step_jacobian``, ``compose``, ``covariance.propagate``) validate
and broadcast their inputs and pay numpy's fixed cost per call dozens of times for it, which
was most of the daemon's CPU.  Here the same formulas run on Python floats and a handful of
3x3 products.  Replay (millions of windows) keeps the array path; tests/test_onewindow.py
checks with hypothesis that both paths give the same windows (models, integrators, dead mice,
rank loss).
"""

from __future__ import annotations

import math

import numpy as np

from mousedom import integrate

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


def noise(theta_before: float, ux: float, uy: float, a: float, q_cov: np.ndarray) -> np.ndarray:
    """covariance.world_step_noise with integrate.step_jacobian, for one window (3x3)."""
    h = 0.5 * a
    sn, dsn = sinc(h), dsinc(h)
    ch, sh = math.cos(h), math.sin(h)
    s, c = sn * ch, sn * sh
    ds = 0.5 * (dsn * ch - sn * sh)
    dc = 0.5 * (dsn * sh + sn * ch)
    jac = np.array([[s, -c, ux * ds - uy * dc], [c, s, ux * dc + uy * ds], [0.0, 0.0, 1.0]])
    ct, st = math.cos(theta_before), math.sin(theta_before)
    rot = np.array([[ct, -st, 0.0], [st, ct, 0.0], [0.0, 0.0, 1.0]])
    m = rot @ jac
    return m @ q_cov @ m.T


def propagate(
    cov: np.ndarray, prev: tuple[float, float], pos: tuple[float, float], g: np.ndarray
) -> np.ndarray:
    """covariance._propagate_stepwise for one window: the symmetrised new covariance."""
    s = np.array([[1.0, 0.0, prev[1] - pos[1]], [0.0, 1.0, pos[0] - prev[0]], [0.0, 0.0, 1.0]])
    p = s @ cov @ s.T + g
    return 0.5 * (p + p.T)


def linear(
    d: np.ndarray, live: np.ndarray, est: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """models._linear for one window: (q restricted to the model's columns, residual of
    the live mice (L, 2)).  ``d`` is (N, 2), ``est`` the cached (A, B, C)."""
    a, b, _ = est
    dl = (d if live is None else d[live]).reshape(-1)
    qk = b @ dl
    return qk, (dl - a @ qk).reshape(-1, 2)
