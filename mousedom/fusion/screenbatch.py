"""The fault-tolerant screen (``robust.Screen``) over an array of consecutive windows.

Replay closes millions of windows at once.  Where nothing happens (every mouse tracking,
no sensor evidence, the test passed) a run of windows is accepted with a few array
operations; each window where something does happen, and the one after it, goes through
``Screen.decide``, the exact path the daemon takes too.  Runs never cross the end of one
of the noise model's learning blocks, so its factors change at the same windows as in the
daemon, and replay and daemon decide alike.
"""

from __future__ import annotations

import numpy as np

from mousedom.fusion.robust import MISSING, TRACKING, Screen


def screen(
    sc: Screen,
    d: np.ndarray,
    mask: np.ndarray,
    q: np.ndarray,
    squal_scale: np.ndarray | None = None,
    low_quality: np.ndarray | None = None,
):
    """d: (n, N, 2) readings; mask: (n, N) live mice; q: (n, 3) the plain solution with
    that mask.  Returns (used (n, N), inflate (n,), consistent (n,), state (n, N) int8,
    reason (n, N) int8)."""
    n, nm = mask.shape
    used = mask.copy()
    inflate = np.ones(n)
    consistent = np.ones(n, dtype=bool)
    state = np.where(mask, TRACKING, MISSING).astype(np.int8)
    reason = np.zeros((n, nm), dtype=np.int8)
    if n == 0:
        return used, inflate, consistent, state, reason
    p = sc.predict(q)
    codes = mask.astype(np.int64) @ (np.int64(1) << np.arange(nm, dtype=np.int64))
    changes = np.flatnonzero(codes[1:] != codes[:-1]) + 1
    evidence = np.zeros(n, dtype=bool)
    if squal_scale is not None:
        evidence |= np.any(mask & (squal_scale != 1.0), axis=1)
    if low_quality is not None:
        evidence |= np.any(mask & low_quality, axis=1)
    i = 0
    prev_altered = False
    while i < n:
        chunk_end = min(n, i + sc.noise.block - sc.noise.seen)
        fast = _fast_rows(sc, d[i:chunk_end], p[i:chunk_end], mask[i:chunk_end])
        bad = np.flatnonzero(~fast | evidence[i:chunk_end]) + i
        j = i
        while j < chunk_end:
            steady = sc.steady()
            if steady is not None and not prev_altered:
                code = sum(1 << k for k, v in enumerate(steady) if v)
                if codes[j] == code:
                    stop = min(_next(bad, j, chunk_end), _next(changes, j + 1, chunk_end))
                    if stop > j:
                        _accept(sc, d[j:stop], p[j:stop], mask[j])
                        j = stop
                        continue
            sq = None if squal_scale is None else squal_scale[j]
            lq = None if low_quality is None else low_quality[j]
            dec = sc.decide(d[j], mask[j], sq, lq)
            used[j] = dec.used
            inflate[j] = dec.inflate
            consistent[j] = dec.consistent
            state[j] = [h.state for h in sc.health]
            reason[j] = [h.reason for h in sc.health]
            # the next window's changes are from this one's own solution: decide it too
            prev_altered = not np.array_equal(dec.used, mask[j])
            j += 1
        i = chunk_end
    return used, inflate, consistent, state, reason


def _fast_rows(sc: Screen, d: np.ndarray, p: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The common case's test for every row at once, each row's previous window taken as
    the row before it unaltered (a row after an altered one goes to ``decide``)."""
    prev_p = np.concatenate([sc.prev_p[None], p[:-1]])
    floor, prop = sc.noise.parts(d, p, prev_p)
    r = d - p
    t = np.sum(np.where(mask, np.sum(r * r, axis=2) / (floor + prop), 0.0), axis=1)
    dof = 2 * mask.sum(axis=1) - sc.k
    thr = np.array(sc._thresholds)
    ok = (dof <= 0) | (t <= thr[np.maximum(dof, 0)])
    m2 = np.maximum(np.sum(d * d, axis=2), np.sum(p * p, axis=2))
    return ok & ~np.any(mask & (m2 >= sc.max_step2), axis=1)


def _accept(sc: Screen, d: np.ndarray, p: np.ndarray, live: np.ndarray) -> None:
    """Rows accepted as solved: the noise model's samples, the block count, the previous
    window's predictions (``fast_one`` for many rows of one live pattern)."""
    if sc.dof(int(live.sum())) > 0:
        prev_p = np.concatenate([sc.prev_p[None], p[:-1]])
        floor, prop = sc.noise.parts(d, p, prev_p)
        r2 = np.sum((d - p) ** 2, axis=2)
        m2 = np.maximum(np.sum(d * d, axis=2), np.sum(p * p, axis=2))
        h = np.broadcast_to(sc.leverage(live), r2.shape)
        sc.noise.sample_arrays(r2, floor, prop, h, live & (m2 > sc.noise.sig2))
    sc._set_prev(p[-1])
    sc.noise.seen += len(d)
    if sc.noise.seen >= sc.noise.block:
        sc.noise.end_block()


def _next(sorted_idx: np.ndarray, i: int, n: int) -> int:
    k = int(np.searchsorted(sorted_idx, i))
    return min(n, int(sorted_idx[k])) if k < len(sorted_idx) else n
