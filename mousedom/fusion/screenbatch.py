"""The fault-tolerant screen (``robust.Screen``) over an array of consecutive windows.

Replay closes millions of windows at once.  Where nothing happens (every mouse tracking,
no sensor evidence, the test passed) a run of windows is accepted with a few array
operations; each window where something does happen, and the one after it, goes through
``Screen.decide``, the exact path the daemon takes too.  Runs never cross the end of one
of the noise model's learning blocks unchecked: a run of accepted windows ends its blocks
all at once (``NoiseModel.extend_blocks``) and stops where a factor changes, so the factors
change at the same windows as in the daemon, and replay and daemon decide alike.
"""

from __future__ import annotations

import numpy as np

from mousedom.fusion.noisemodel import motion2, norm2
from mousedom.fusion.robust import MISSING, TRACKING, Screen
from mousedom.fusion.shortfall import SHORT, SHORT_ALONE, SHORT_OF_ALL
from mousedom.fusion.silences import SILENT_SHARE

HORIZON = 16  # learning blocks of rows tested at once after the factors changed
HORIZON_MAX = 64  # and once they stayed as they were (bounded: (rows, mice) temporaries)


def screen(
    sc: Screen,
    d: np.ndarray,
    mask: np.ndarray,
    q: np.ndarray,
    squal_scale: np.ndarray | None = None,
    low_quality: np.ndarray | None = None,
    spans: np.ndarray | None = None,
):
    """d: (n, N, 2) readings; mask: (n, N) live mice; q: (n, 3) the plain solution with
    that mask; spans: (n, N) long report spans cut by each window's edges, or None (the
    noise model's granularity term grows for them: ``_fast_rows``).  Returns (used (n, N),
    inflate (n,), consistent (n,), state (n, N) int8,
    reason (n, N) int8, correction (n, 3) or None: Decision.correction, by row, factors:
    the noise model's proportional factors each row was tested with, as (first row, its
    ``lam_r_list``) in row order: the gyro's judge takes them (gyrojudge.MiceView))."""
    n, nm = mask.shape
    used = mask.copy()
    inflate = np.ones(n)
    consistent = np.ones(n, dtype=bool)
    state = np.where(mask, TRACKING, MISSING).astype(np.int8)
    reason = np.zeros((n, nm), dtype=np.int8)
    correction = None
    factors: list[tuple[int, list[float]]] = []
    if n == 0:
        return used, inflate, consistent, state, reason, correction, factors
    p = sc.predict(q)
    codes = mask.astype(np.int64) @ (np.int64(1) << np.arange(nm, dtype=np.int64))
    changes = np.flatnonzero(codes[1:] != codes[:-1]) + 1
    evidence = np.zeros(n, dtype=bool)
    cut_rows, silent_cut = _cut_rows(sc, d, mask, spans)
    evidence |= silent_cut
    if squal_scale is not None:
        evidence |= np.any(mask & (squal_scale != 1.0), axis=1)
    if low_quality is not None:
        evidence |= np.any(mask & low_quality, axis=1)
    # Each row's live pattern and its leverages; one pattern throughout (the usual case)
    # is passed to the common case's test as one row.
    if len(changes):
        row_mask, lever = mask, _leverages(sc, mask, codes)
        gain = _per_pattern(sc.others_gain, mask, codes)
    else:
        row_mask, lever, gain = mask[0], sc.leverage(mask[0]), sc.others_gain(mask[0])
    i = 0
    prev_altered = False
    version, horizon = None, 0
    # Blocks per horizon: one while nothing is learnt yet (the first block's end nearly
    # always moves the floor's factor, and rows made ahead of it would be made again), the
    # most once a horizon ended with the factors unchanged (fewer calls), HORIZON after one
    # that changed them.
    blocks = 1 if sc.noise.version == 0 else HORIZON
    while i < n:
        if not factors or factors[-1][1] is not sc.noise.lam_r_list:
            factors.append((i, sc.noise.lam_r_list))  # (a block's end in the row before)
        if version != sc.noise.version or i >= horizon:
            # The common case's test and the noise model's samples for the rows ahead,
            # with the factors as they are; again when a block's end changes them.
            if version is not None:
                blocks = HORIZON if version != sc.noise.version else HORIZON_MAX
            version, base = sc.noise.version, i
            horizon = min(n, i + blocks * sc.noise.block)
            rows = slice(i, horizon) if row_mask.ndim == 2 else slice(None)
            fast, samples = _fast_rows(sc, d[i:horizon], p[i:horizon], row_mask[rows],
                                       lever[rows], gain[rows],
                                       None if spans is None else spans[i:horizon])  # fmt: skip
            bad = np.flatnonzero(~fast | evidence[i:horizon]) + i
        steady = sc.steady()
        opened = sc.silences.any
        if (
            steady is not None
            and not prev_altered
            and not (opened and _next(cut_rows, i, i + 1) == i)
        ):
            code = sum(1 << k for k, v in enumerate(steady) if v)
            if codes[i] == code:
                stop = min(_next(bad, i, horizon), _next(changes, i + 1, horizon))
                if opened:
                    stop = min(stop, _next(cut_rows, i + 1, horizon))
                if stop > i:
                    # A run of accepted rows, across learning blocks: up to the first
                    # block end that changes a factor (the arrays are then made again).
                    values = samples if sc.dof(int(mask[i].sum())) > 0 else None
                    stop = sc.noise.extend_blocks(values, i - base, stop - base) + base
                    sc.accepted(p[i:stop], d[i:stop], steady)
                    sc.heard_rows(p[i:stop], mask[i:stop])
                    i = stop
                    continue
        sq = None if squal_scale is None else squal_scale[i]
        lq = None if low_quality is None else low_quality[i]
        dec = sc.decide(d[i], mask[i], sq, lq, None if spans is None else spans[i])
        used[i] = dec.used
        inflate[i] = dec.inflate
        consistent[i] = dec.consistent
        if dec.correction is not None:
            if correction is None:
                correction = np.zeros((n, 3))
            correction[i] = dec.correction
        state[i] = [h.state for h in sc.health]
        reason[i] = [h.reason for h in sc.health]
        # the next window's changes are from this one's own solution: decide it too
        prev_altered = not np.array_equal(dec.used, mask[i])
        i += 1
    return used, inflate, consistent, state, reason, correction, factors


def _cut_rows(sc: Screen, d: np.ndarray, mask: np.ndarray,
              spans: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The rows that cut a long report span (sorted), and those of them in which a live
    mouse reads nothing.  The latter are the decision's: it opens a silence's account there
    (``Screen._runs``: each window at its own variance, the span's term with it; the common
    case's ``Silences.rows`` keeps one at the floor's).  While one is open, every row that
    cuts a span is the decision's too; no run of accepted rows opens one, so a run that
    starts with none open keeps none (``Screen.fast_one`` has the same rule)."""
    n = len(mask)
    if spans is None:
        return np.zeros(0, dtype=np.int64), np.zeros(n, dtype=bool)
    cut = np.any(mask & (spans > 0), axis=1)
    silent = mask & (norm2(d) <= SILENT_SHARE * sc.noise.sig2)
    return np.flatnonzero(cut), cut & np.any(silent, axis=1)


def _leverages(sc: Screen, mask: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """(n, N) each row's leverages (its live pattern's; a rig has few patterns)."""
    return _per_pattern(sc.leverage, mask, codes)


def _per_pattern(of, mask: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """(n, ...) each row's ``of(live pattern)`` (once per pattern: a rig has few)."""
    # (return_index also keeps numpy 2 from importing numpy.ma, 12 ms of a replay's start)
    _, first, which = np.unique(codes, return_index=True, return_inverse=True)
    per_pattern = np.array([of(mask[i]) for i in first.tolist()])
    return per_pattern[which.ravel()]


def _fast_rows(sc: Screen, d, p, mask, lever, gain, spans=None) -> tuple[np.ndarray, tuple]:
    """The common case's test for every row at once, each row's previous window taken as
    the row before it unaltered (a row after an altered one goes to ``decide``), and the
    noise model's samples of each row were it accepted.  ``mask`` and ``lever`` are (rows,
    N), or (N,) when every row has that live pattern (the usual case: fewer operations);
    ``gain`` (rows, N, 2, 2) or (N, 2, 2) likewise (``RigidTest.others_gain``); ``spans``
    (rows, N) the long report spans the edges cut, or None (``steady.steady_window``: a cut
    mouse's change of motion from the others' word, a row where they cannot place one
    decided)."""
    prev_p = np.concatenate([sc.prev_p[None], p[:-1]])
    m2 = motion2(d, p)
    # what the others moved each mouse (shortfall.others_word, on arrays)
    r = d - p
    ox = d[..., 0] - (gain[..., 0, 0] * r[..., 0] + gain[..., 0, 1] * r[..., 1])
    oy = d[..., 1] - (gain[..., 1, 0] * r[..., 0] + gain[..., 1, 1] * r[..., 1])
    placed = np.any(gain != 0.0, axis=(-2, -1))
    cut = None if spans is None else mask & (spans > 0)
    if cut is not None and cut.any():
        gran2 = sc.noise.gran2_for(spans)
        gran_p = p.copy()
        gran_p[..., 0] = np.where(cut, ox, p[..., 0])
        gran_p[..., 1] = np.where(cut, oy, p[..., 1])
        floor, prop = sc.noise.parts(d, p, prev_p, m2, gran2=gran2, gran_p=gran_p)
        unplaced = cut & ~placed
    else:
        floor, prop = sc.noise.parts(d, p, prev_p, m2)
        unplaced = None
    r2 = norm2(r)
    t = _row_sum(np.where(mask, r2 / (floor + prop), 0.0))
    thr = np.array(sc._thresholds)
    if mask.ndim == 1:
        dof = 2 * int(mask.sum()) - sc.k
        ok = np.full(len(t), True) if dof <= 0 else t <= thr[dof]
    else:
        dofs = 2 * _row_sum(mask.astype(np.int64)) - sc.k
        ok = (dofs <= 0) | (t <= thr[np.maximum(dofs, 0)])
    saturated = mask & (m2 >= sc.max_step2)
    # a mouse the others moved beyond its sigma that reads short of it (shortfall.reads_short,
    # the same operations on arrays): decide (Screen._quiet_blame)
    p2 = norm2(p)
    moved = mask & (p2 > sc.noise.sig2)
    along = d[..., 0] * p[..., 0] + d[..., 1] * p[..., 1]
    word = moved & placed
    o2 = ox * ox + oy * oy
    word &= o2 > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (d[..., 0] * ox + d[..., 1] * oy) / o2
        by = np.where(ratio > 0.0, np.maximum(ratio, 1.0 / ratio), np.inf)
    by = np.where(word, by, 0.0)
    # the first of the largest, as the loop takes it
    odd = (by == by.max(axis=-1, keepdims=True)) & (by > 0.0)
    odd &= np.cumsum(odd, axis=-1) == 1
    of_others = odd & (ratio < SHORT) & (along < SHORT_OF_ALL * p2)
    quiet = moved & ((along < SHORT_ALONE * p2) | of_others)
    for i in range(saturated.shape[1]):
        ok &= ~saturated[:, i]
        ok &= ~quiet[:, i]
        if unplaced is not None:
            ok &= ~unplaced[:, i]
    samples = sc.noise.samples_for(r2, floor, prop, lever, mask & (m2 > sc.noise.sig2))
    return ok, samples


def _row_sum(a: np.ndarray) -> np.ndarray:
    """Each row's sum, column after column: the order of the one-window path's sum (and of
    numpy's own over a short axis), without numpy's slow reduction over an axis of a few."""
    total = a[:, 0].copy()
    for i in range(1, a.shape[1]):
        total += a[:, i]
    return total


def _next(sorted_idx: np.ndarray, i: int, n: int) -> int:
    k = int(np.searchsorted(sorted_idx, i))
    return min(n, int(sorted_idx[k])) if k < len(sorted_idx) else n
