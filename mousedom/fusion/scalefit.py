"""The scale learner's fits (``scalelearn``): pure functions of the evidence.

Every mouse's body displacement as its config reads it, d_i = M_i c_i, given a scale g_i:
J g = (g_1 d_1, ..., g_N d_N).  A rigid rig's readings are A q for some twist q; P = I -
A (A' W A)^-1 A' W keeps what no twist explains (W: the config's sigmas), and with the true
scales P J g is only noise: the scales minimise g' S g, S = sum over the evidence of
(P J)' W (P J) (``projected``).  S has one null direction, the common mode (all mice
scaled together change no prediction): g solves (S + mu) g = mu 1 and is divided by its
median mouse (``scales``), its spread the residual per degree of freedom through S's
inverse off that direction (``fit``), widened to the jackknife's over the segments of
evidence (``jackknife``, ``widened``).  Per count axis the same with J's column per mouse
split in two (``fit_axes``, ``axis_scales``); a change of scale between the recent
segments and the older ones (``scales_differ``, ``change_point``).  The learner's state,
its blocks and what it applies are scalelearn.py's; docs/calibration.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from mousedom.fusion import student

# The fit's scales are plain where beyond this many of their standard deviations from 1
# (what the learner applies, ``ScaleLearner``), and their spread widened by the jackknife
# to the normal's equivalent of that (``widened``); no scale from fewer groups than
# MIN_GROUPS of evidence (a second of motion: the first second's estimate is no better
# than its start).
PLAIN = 3.0
_PLAIN_P = math.erf(PLAIN / math.sqrt(2.0))  # (the normal's chance within them: 0.9973)
MIN_GROUPS = 10
_RIDGE = 1e-6  # S + mu, mu this times S's diagonal: what the evidence leaves free stays near 1
_MIN_EVIDENCE = 1e-3  # a mouse seen this little (S's diagonal against the most seen): not estimated
# S's eigenvalues after the common mode's, against its largest: at least 0.3 on the rigs of
# fusion/scenarios.py and triangles, squares, polygons and kites of 3-7 mice; 0.015-0.03
# with a mouse 2 cm off a line across the robot; 1e-5-2e-2 with the three or four in line.
_MIN_SEPARATION = 1e-2
# A change of scale (a mouse onto another floor, its lens dirtied: a CPI step) is looked for
# at each renewal (``ScaleLearner._changed``): the scales of the last CHANGE_SEGMENTS
# segments of evidence against those of the older ones, the change plain where beyond
# CHANGE_SIGMAS of the two fits' combined spread and CHANGE_MIN.
CHANGE_SEGMENTS = 10
CHANGE_SIGMAS = 5.0
CHANGE_MIN = 0.01
# The change test corrects each count axis by its scale over the older evidence first
# (``ScaleLearner._change_evidence``), drawn to 1 where that evidence knows it less well
# than this (``axis_scales``): a mouse off on one axis is then one scale throughout.
_AXIS_PRIOR = 0.01


def medians(v: np.ndarray) -> np.ndarray:
    """``np.median`` over the last axis of a finite array, bit for bit, without its first
    call's import of numpy.ma (8 ms): in the daemon that call is the loop's first scale
    solve, and every mouse's window waited behind it."""
    ordered = np.sort(v, axis=-1)
    k = v.shape[-1] // 2
    # np.median's own last step: the mean of the middle one or two (a mean of -0.0 is 0.0)
    middle = ordered[..., k : k + 1] if v.shape[-1] % 2 else ordered[..., k - 1 : k + 1]
    return np.mean(middle, axis=-1)


def scales(s: np.ndarray) -> np.ndarray:
    """``fit``'s scales for a stack of S (..., N, N): the solution of (S + mu) g = mu,
    divided by its median mouse (``medians``), NaN where S gives none."""
    evidence = np.diagonal(s, axis1=-2, axis2=-1)
    mu = _RIDGE * np.maximum(evidence, 1e-12 * evidence.max(axis=-1, keepdims=True))
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.linalg.solve(s + mu[..., :, None] * np.eye(s.shape[-1]), mu[..., None])[..., 0]
        mid = medians(g)[..., None]
        return np.where(mid > 0, g / mid, np.nan)


def reads(g: float, digits: int = 0) -> str:
    """How a mouse whose counts need the scale ``g`` reads against the truth it is held
    to, in words: "7.4 % less" (g > 1: it needs more of its counts) or "... more"."""
    return f"{abs(1.0 / g - 1.0) * 100:.{digits}f} % {'less' if g > 1.0 else 'more'}"


def plain_change(diff: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """Which mice's scales differ plainly between two fits (``ScaleLearner._changed``):
    by more than CHANGE_SIGMAS of the difference's ``spread``, and CHANGE_MIN."""
    return (diff > CHANGE_SIGMAS * spread) & (diff > CHANGE_MIN)


def jackknife(s: np.ndarray, segments: Sequence[np.ndarray]) -> np.ndarray:
    """(N,) the standard error of ``fit``'s scales by a jackknife over the ``segments`` of
    evidence that S sums (blocks of windows): each left out in turn, the scales' spread
    over the fits of the rest, times (B - 1) / B.  Inf where fewer than two segments, or
    where a fit without one gives none.

    ``fit``'s own spread takes the residual as white noise.  It is not: a reading's error
    follows the motion (stamps late while a turn speeds up, a group cut inside a long
    span), so evidence from one stretch of driving is biased alike, and one block of hard
    motion can outweigh the rest (a healthy close pair told a mouse 2.3 % off from four
    blocks, 3.4 of fit's spreads, where leaving each block out moved the estimate by 1.9 %;
    applied, it bent a 30 s drive 98 mm against 14).  Over segments the spread is that of
    the evidence as it came, whatever its errors' structure."""
    b = len(segments)
    if b < 2:
        return np.full(len(s), np.inf)
    loo = scales(s[None] - np.stack(segments))
    var = (b - 1) / b * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0)
    return np.where(np.isfinite(var), np.sqrt(var), np.inf)


def widened(spread: np.ndarray, s: np.ndarray, segments: Sequence[np.ndarray]) -> np.ndarray:
    """``fit``'s ``spread`` of the scales of S ``s``, widened to the jackknife's over the
    ``segments`` S sums as the normal's equivalent: PLAIN of it is t's quantile for its
    degrees (the segments less one: with four, 9.2 of the jackknife's standard errors).
    Inf with fewer than two segments."""
    b = len(segments)
    if b < 2:
        return np.full(len(spread), np.inf)
    t = student.quantile(_PLAIN_P, b - 1)
    return np.maximum(spread, jackknife(s, segments) * (t / PLAIN))


def motion_columns(positions: np.ndarray, cols: tuple[int, ...]) -> np.ndarray:
    """A (2N, len(cols)): the stacked displacements (x, y per mouse) a unit rig motion
    (forward, sideways, turn; ``cols`` of them) gives mice at ``positions`` (N, 2)."""
    a = np.zeros((2 * len(positions), 3))
    a[0::2, 0] = 1.0
    a[1::2, 1] = 1.0
    a[0::2, 2] = -positions[:, 1]
    a[1::2, 2] = positions[:, 0]
    return a[:, list(cols)]


def projector(a: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """P = I - A (A' W A)^-1 A' W: what of the stacked displacements no rig motion
    explains (W: ``weight``, per reading); I for one mouse (nothing to compare with)."""
    n2 = len(a)
    if n2 < 4:
        return np.eye(n2)
    aw = a.T * weight
    return np.eye(n2) - a @ np.linalg.solve(aw @ a, aw)


def projected(
    body: np.ndarray, project: np.ndarray, weight: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Groups' readings (G, N, 2) as configured: J g stacked (mouse i's two rows of column
    i), the part of it no rig motion explains per unit scale, P J (G, 2N, N), and its
    weighted square summed over the groups, S (N, N)."""
    n = body.shape[1]
    j = np.zeros((len(body), 2 * n, n))
    for i in range(n):
        j[:, 2 * i : 2 * i + 2, i] = body[:, i]
    pj = np.einsum("rs,gst->grt", project, j)
    return pj, np.einsum("grt,r,grs->ts", pj, weight, pj)


def residual_per_dof(s: np.ndarray, g: np.ndarray, groups: float, cols: int) -> float:
    """g' S g over its degrees of freedom: ``groups`` groups of 2N readings of N mice, less
    the rig motion's ``cols`` per group and the N - 1 scales fitted."""
    n = len(g)
    return float(g @ s @ g) / max(1.0, groups * (2 * n - cols) - (n - 1))


def fit(s: np.ndarray, groups: float, n: int, cols: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The scales g (N,) that minimise g' S g, drawn to 1 only where the evidence is
    silent, the common mode pinned by the median mouse, and their spreads (N,) (inf: not
    estimated), from ``groups`` groups of evidence of N mice and a rig motion of ``cols``
    degrees of freedom; None where S gives nothing."""
    evidence = np.diag(s).copy()
    if not np.all(np.isfinite(s)) or evidence.max() <= 0:
        return None
    g = scales(s)
    if not np.all(np.isfinite(g)):
        return None
    # the spread: the fit's residual per degree of freedom, through the inverse of S off
    # its null direction (the common mode)
    r2 = residual_per_dof(s, g, groups, cols)
    w, v = np.linalg.eigh(s)  # ascending: the first is the common mode's (near 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = (v[:, 1:] / w[1:]) @ v[:, 1:].T
        spread = np.sqrt(np.maximum(np.diag(inv), 0.0) * r2)
    spread = np.where(np.isfinite(spread), spread, np.inf)  # another null direction
    # A second direction the rig's geometry barely separates from the common mode (mice
    # in a line across the robot: scales growing along the line read alike but in
    # turns): the estimate follows whatever bias the readings have (a late mouse's timing
    # gave 1.86 and 0.14 on healthy mice, with spreads of 2 %), and pinning the common
    # mode on the median mouse spreads that over every other mouse: none is estimated
    # (docs/models.md, "Scales").
    if w[1] < _MIN_SEPARATION * w[-1]:
        spread = np.full(n, np.inf)
    known = evidence >= _MIN_EVIDENCE * evidence.max()
    return np.where(known, g, 1.0), np.where(known, spread, np.inf)


# ``fit_axes``' evidence: the per-axis S, its segments, the groups, N mice, the rig
# motion's degrees of freedom
AxisEvidence = tuple[np.ndarray, Sequence[np.ndarray], float, int, int]


def axis_map(split: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ``split`` (N,): each unknown's mouse (an axis of each split mouse, one scale of
    each other), and T (2N, unknowns), the unknowns -> the count axes."""
    n = len(split)
    owner = np.repeat(np.arange(n), np.where(split, 2, 1))
    t_map = np.zeros((2 * n, len(owner)))
    col = 0
    for i in range(n):
        if split[i]:
            t_map[2 * i, col], t_map[2 * i + 1, col + 1] = 1.0, 1.0
        else:
            t_map[2 * i : 2 * i + 2, col] = 1.0
        col += 2 if split[i] else 1
    return owner, t_map


def unexplained(s: np.ndarray, split: np.ndarray) -> float:
    """What the per-axis evidence S (2N x 2N) leaves unexplained at its best scales with
    a scale per axis for the ``split`` mice and one for each other: g' S g at ``scales``'
    solution, however weakly the evidence tells those scales apart (``fit_axes`` draws
    what it does not tell apart to 1; here only the fit counts)."""
    t_map = axis_map(split)[1]
    st = t_map.T @ s @ t_map
    try:
        with np.errstate(invalid="ignore"):
            g = scales(st)
    except np.linalg.LinAlgError:  # (no evidence at all)
        return math.nan
    return float(g @ st @ g) if np.all(np.isfinite(g)) else math.nan


def fit_axes(
    s: np.ndarray,
    segments: Sequence[np.ndarray],
    groups: float,
    n: int,
    cols: int,
    split: np.ndarray | None = None,
    jackknifed: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """A scale per count axis from the per-axis evidence S (2N x 2N, rows mouse-major:
    mouse i's x then y) and its ``segments``: (g (N, 2), spread (N, 2), g_x - g_y (N,),
    its spread (N,)), as ``fit`` and ``ScaleLearner._solve`` give one per mouse (the
    scales drawn to 1 only where the evidence is silent, the common mode pinned by the
    median, the spread the larger of the residual's and the jackknife's over the
    segments).  ``split`` (N,): the mice given a scale per axis (default all); the others
    one scale for both (their difference 0, its spread NaN): once a mouse off on one
    axis is known, the others' one scale is no longer bent by it (a healthy mouse beside
    one 2-4 % off on one axis was given 0.5-0.8 % by one scale per mouse).  An axis the
    evidence does not separate from the others (its variance through the inverse of S,
    the common mode pinned, beyond 1 / _MIN_SEPARATION of S's largest eigenvalue's
    inverse: e.g. the sideways axes of a drive that never slides) has an infinite spread,
    and so has its mouse's difference.  None where S gives nothing (too little
    evidence).  ``jackknifed=False``: the spreads the residual's alone, a lower bound,
    without the jackknife's solve per segment (what can be plain at all)."""
    m = 2 * n
    if groups < MIN_GROUPS or s.shape != (m, m) or not np.all(np.isfinite(s)):
        return None
    if np.diag(s).max() <= 0 or len(segments) < 2:
        return None
    split = np.ones(n, bool) if split is None else np.asarray(split, bool)
    owner, t_map = axis_map(split)
    k = len(owner)
    s = t_map.T @ s @ t_map
    evidence = np.diag(s)
    g = scales(s)
    if not np.all(np.isfinite(g)):
        return None
    dof = max(1.0, groups * (2 * n - cols) - (k - 1))
    r2 = float(g @ s @ g) / dof
    # The inverse of S with the common mode pinned (S + l c c', c the unit common mode):
    # other directions S leaves (nearly) free show as large variances.  A drive that never
    # slides leaves one such on a rig whose mice sit at two distances along x only (a
    # triangle, a square): every sideways axis against every forward one, which a
    # sideways drift of the rig proportional to its turn reads alike.
    top = float(np.linalg.eigvalsh(s)[-1])
    common = np.full(k, 1.0 / math.sqrt(k))
    try:
        inv = np.linalg.inv(s + top * np.outer(common, common))
    except np.linalg.LinAlgError:
        return None
    # a split mouse's two unknowns are neighbours: x at ``first``, y next
    first = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])[split]
    var = np.diag(inv)
    var_d = var[first] + var[first + 1] - 2 * inv[first, first + 1]
    # (u' inv u against |u|^2 = 2 for the difference u = e_x - e_y)
    free = 1.0 / _MIN_SEPARATION / top
    weak = ~(var < free) | (evidence < _MIN_EVIDENCE * evidence.max())
    weak_d = ~(var_d < 2 * free) | weak[first] | weak[first + 1]
    spread = np.sqrt(np.maximum(var, 0.0) * r2)
    spread_d = np.sqrt(np.maximum(var_d, 0.0) * r2)
    if jackknifed:
        b = len(segments)
        loo = scales(s[None] - np.stack([t_map.T @ seg @ t_map for seg in segments]))
        t = student.quantile(_PLAIN_P, b - 1) / PLAIN
        with np.errstate(invalid="ignore", over="ignore"):
            jack = np.sqrt((b - 1) / b * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0))
            loo_d = loo[:, first] - loo[:, first + 1]
            jack_d = np.sqrt((b - 1) / b * np.sum((loo_d - loo_d.mean(axis=0)) ** 2, axis=0))
        spread = np.maximum(spread, jack * t)
        spread_d = np.maximum(spread_d, jack_d * t)
    spread = np.where(np.isfinite(spread) & ~weak, spread, np.inf)
    g = np.where(weak, 1.0, g)
    d_all, spread_d_all = np.zeros(n), np.full(n, np.nan)
    d_all[split] = g[first] - g[first + 1]
    spread_d_all[split] = np.where(np.isfinite(spread_d) & ~weak_d, spread_d, np.inf)
    axis_of = np.argmax(t_map, axis=1)  # each axis's unknown
    return g[axis_of].reshape(n, 2), spread[axis_of].reshape(n, 2), d_all, spread_d_all


def axis_scales(
    s: np.ndarray, groups: float, n: int, cols: int, prior: np.ndarray | None = None
) -> np.ndarray:
    """(2N,) each count axis's scale from per-axis evidence S (2N x 2N, ``fit_axes``') of
    ``groups`` groups of N mice and a rig motion of ``cols`` degrees of freedom, drawn to
    ``prior`` (default all ones) as far as the evidence leaves it open: the solution of
    (S + mu) g = mu prior, mu the residual per degree of freedom over _AXIS_PRIOR squared
    (a direction of g known to better than _AXIS_PRIOR is the data's, one known less well
    stays near the prior's: the common mode, and what the drive leaves nearly free, such
    as the sideways axes against the forward ones of a drive that never slides), divided
    by its median.  The prior where S gives nothing (too little evidence, or a scale not
    positive)."""
    ones = np.ones(len(s))
    p = ones if prior is None else prior
    if groups < MIN_GROUPS or not np.all(np.isfinite(s)) or not np.diag(s).max() > 0:
        return p
    g = scales(s)
    if not np.all(np.isfinite(g)):
        return p
    dof = max(1.0, groups * (2 * n - cols) - (2 * n - 1))
    mu = max(float(g @ s @ g) / dof, 0.0) / _AXIS_PRIOR**2 + _RIDGE * float(np.diag(s).max())
    g = np.linalg.solve(s + mu * np.eye(len(s)), mu * p)
    mid = float(medians(g))
    if not mid > 0 or not np.all(g > 0):
        return p
    return g / mid


def scales_differ(segments: np.ndarray, recent: int) -> bool:
    """Whether the scales alone of the last ``recent`` of the ``segments`` and of the
    older ones differ by CHANGE_MIN for any mouse (one solve for both): a change under
    that is none, whatever the spreads (a healthy rig's stay within a few tenths of a per
    cent)."""
    sums = np.stack([segments[-recent:].sum(axis=0), segments[:-recent].sum(axis=0)])
    with np.errstate(invalid="ignore"):
        return bool(np.any(np.abs(np.subtract(*scales(sums))) > CHANGE_MIN))


def change_point(segments: np.ndarray) -> int:
    """How many of the recent ``segments`` are after the change of scale ``_changed``
    found: the last k (2 <= k <= CHANGE_SEGMENTS) whose fit and the older ones' leave the
    least residual together (the change's most likely place, to a block)."""
    ks = np.arange(2, CHANGE_SEGMENTS + 1)
    total = np.cumsum(segments[::-1], axis=0)  # total[k - 1]: the last k summed
    after = total[ks - 1]
    parts = np.concatenate([after, total[-1][None] - after])
    with np.errstate(invalid="ignore"):
        g = np.nan_to_num(scales(parts), nan=1.0)
        residual = np.einsum("ki,kij,kj->k", g, parts, g)
    cost = residual[: len(ks)] + residual[len(ks) :]
    return int(ks[np.argmin(cost)])
