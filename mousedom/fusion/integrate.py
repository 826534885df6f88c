"""Integrators: one window's twist increment -> body-frame step, and pose composition.

A window's twist increment is q = (u_x, u_y, a): the body-frame displacement of the body
origin's *velocity* integrated over the window (what the models return) and the heading
change a = dtheta.  Under a constant twist the body origin travels along a circular arc and
its displacement, in the body frame at the start of the window, is the SE(2) exponential

    step = V(a) u,   V(a) = [[S, -C], [C, S]],  S = sin(a)/a,  C = (1 - cos a)/a.

Half-angle identities give V(a) = sinc(a/2) R(a/2): the exact step is the chord of the arc,
of length sinc(a/2)|u|, along the mean heading a/2.  Written this way it has no cancellation
anywhere (1 - cos a would lose all its digits near 0); only sinc needs a series near 0.

The seeds' approximations are the same step with a cheaper V:
- ``taylor`` (Hong): S ~ 1 - a^2/6, C ~ a/2.
- ``euler`` (Hong's "previous approximation"): V ~ R(a), motion along the final heading.
- ``midpoint`` (McGill): V ~ R(a/2), the exact direction with the sinc length factor dropped.

Everything works on arrays of windows; nothing loops per window.
"""

from __future__ import annotations

import math

import numpy as np

from mousedom.fusion.choices import INTEGRATORS as INTEGRATORS  # the integrators here

# sinc(h) = sum_k (-1)^k h^(2k) / (2k+1)!  and its derivative.  Evaluated by Horner in h^2.
# Below _SINC_SWITCH the series with these terms is exact to rounding: the first omitted term
# of sinc is h^20/21! < 2e-20 at h = 1 and the derivative's is 22 h^21/23! < 1e-21.  Above it the
# closed forms are used; they lose at most a few ulp there (sin(h)/h has no cancellation,
# h cos h - sin h loses about log10(3/h^2) < 1 digit for h >= 1).
_SINC_TERMS = 10
_SINC_COEF = np.array([(-1) ** k / math.factorial(2 * k + 1) for k in range(_SINC_TERMS)])
# sinc'(h) = h * sum_{k>=1} (-1)^k 2k h^(2k-2) / (2k+1)!
_DSINC_COEF = np.array(
    [(-1) ** k * 2 * k / math.factorial(2 * k + 1) for k in range(1, _SINC_TERMS + 1)]
)
_SINC_SWITCH = 1.0


def _horner(h2: np.ndarray, coef: np.ndarray) -> np.ndarray:
    acc = np.full_like(h2, coef[-1])
    for c in coef[-2::-1]:
        acc = acc * h2 + c
    return acc


def sinc(h: np.ndarray | float) -> np.ndarray:
    """sin(h)/h (unnormalised), accurate to rounding for every h including 0."""
    h = np.asarray(h, dtype=float)
    small = np.abs(h) < _SINC_SWITCH
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.sin(h) / h
    return np.where(small, _horner(h * h, _SINC_COEF), out)


def dsinc(h: np.ndarray | float) -> np.ndarray:
    """d/dh sinc(h) = (h cos h - sin h)/h^2, with the series near 0 (no cancellation)."""
    h = np.asarray(h, dtype=float)
    small = np.abs(h) < _SINC_SWITCH
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (h * np.cos(h) - np.sin(h)) / (h * h)
    return np.where(small, h * _horner(h * h, _DSINC_COEF), out)


def _as_q(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != 3:
        raise ValueError(f"expected an (n, 3) array of windows, got shape {q.shape}")
    return q


def exp_coefficients(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S, C) = (sin(a)/a, (1 - cos a)/a) without cancellation: sinc(a/2) (cos, sin)(a/2)."""
    h = 0.5 * np.asarray(a, dtype=float)
    s = sinc(h)
    return s * np.cos(h), s * np.sin(h)


def body_step(
    q: np.ndarray, method: str = "exact", coefficients: tuple | None = None
) -> np.ndarray:
    """Body-frame step (dx, dy, dtheta) of each window with twist increment q (n, 3).

    ``exact`` is the SE(2) exponential V(a) u; ``taylor``, ``euler`` and ``midpoint`` are the
    approximations of Hong and of the McGill notes (see the module docstring).
    ``coefficients``: the exact step's (S, C) when already made (``step_partials`` makes
    them too).
    """
    q = _as_q(q)
    ux, uy, a = q[:, 0], q[:, 1], q[:, 2]
    if method == "exact":
        s, c = exp_coefficients(a) if coefficients is None else coefficients
    elif method == "taylor":
        s, c = 1.0 - a * a / 6.0, 0.5 * a
    elif method == "euler":
        s, c = np.cos(a), np.sin(a)
    elif method == "midpoint":
        s, c = np.cos(0.5 * a), np.sin(0.5 * a)
    else:
        raise ValueError(f"unknown integrator {method!r}; choose one of {', '.join(INTEGRATORS)}")
    out = np.empty_like(q)
    out[:, 0] = ux * s - uy * c
    out[:, 1] = ux * c + uy * s
    out[:, 2] = a
    return out


def step_partials(q: np.ndarray) -> tuple[np.ndarray, ...]:
    """(S, C, dx/da, dy/da) of each window: the exact step's Jacobian by q is
    [[S, -C, dx/da], [C, S, dy/da], [0, 0, 1]] (see ``step_jacobian``)."""
    q = _as_q(q)
    ux, uy, a = q[:, 0], q[:, 1], q[:, 2]
    h = 0.5 * a
    sn, dsn = sinc(h), dsinc(h)
    ch, sh = np.cos(h), np.sin(h)
    s, c = sn * ch, sn * sh
    ds = 0.5 * (dsn * ch - sn * sh)
    dc = 0.5 * (dsn * sh + sn * ch)
    return s, c, ux * ds - uy * dc, ux * dc + uy * ds


def step_jacobian(q: np.ndarray) -> np.ndarray:
    """d(exact step)/dq, shape (n, 3, 3): rows (dx, dy, dtheta), columns (u_x, u_y, a).

    With h = a/2: S = sinc(h) cos h, C = sinc(h) sin h, so
    dS/da = (sinc'(h) cos h - sinc(h) sin h)/2 and dC/da = (sinc'(h) sin h + sinc(h) cos h)/2,
    both free of cancellation thanks to the series of sinc'.
    """
    s, c, dx_da, dy_da = step_partials(q)
    jac = np.zeros((len(s), 3, 3))
    jac[:, 0, 0] = s
    jac[:, 0, 1] = -c
    jac[:, 0, 2] = dx_da
    jac[:, 1, 0] = c
    jac[:, 1, 1] = s
    jac[:, 1, 2] = dy_da
    jac[:, 2, 2] = 1.0
    return jac


def inverse_exact(step: np.ndarray) -> np.ndarray:
    """The twist increment q whose exact step is ``step``: u = R(-a/2) t / sinc(a/2).

    Defined for |a| < 2 pi (a whole turn within one window has no unique twist).
    """
    step = _as_q(step)
    h = 0.5 * step[:, 2]
    inv = 1.0 / sinc(h)
    ch, sh = np.cos(h), np.sin(h)
    q = np.empty_like(step)
    q[:, 0] = (ch * step[:, 0] + sh * step[:, 1]) * inv
    q[:, 1] = (-sh * step[:, 0] + ch * step[:, 1]) * inv
    q[:, 2] = step[:, 2]
    return q


def compose(start: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Poses (n, 3) after each body-frame step, starting from ``start`` = (x, y, theta).

    theta_k = theta_{k-1} + dtheta_k and p_k = p_{k-1} + R(theta_{k-1}) step_k, as running
    sums seeded with the start value.  numpy's accumulate adds left to right, so composing in
    batches (each starting from the previous batch's last pose) gives the very same floats as
    one big batch.  The heading is left unwrapped; whoever displays it may wrap it.
    """
    start = np.asarray(start, dtype=float).reshape(3)
    steps = _as_q(steps)
    n = len(steps)
    out = np.empty((n, 3))
    if n == 0:
        return out
    theta = np.cumsum(np.concatenate(([start[2]], steps[:, 2])))
    before = theta[:-1]
    cb, sb = np.cos(before), np.sin(before)
    wx = cb * steps[:, 0] - sb * steps[:, 1]
    wy = sb * steps[:, 0] + cb * steps[:, 1]
    out[:, 0] = np.cumsum(np.concatenate(([start[0]], wx)))[1:]
    out[:, 1] = np.cumsum(np.concatenate(([start[1]], wy)))[1:]
    out[:, 2] = theta[1:]
    return out
