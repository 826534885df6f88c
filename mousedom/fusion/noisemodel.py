"""Each mouse's expected reading error over a window, for the consistency test (``robust``).

    s_i^2 = lf_i sigma_i^2 + lr_i ((rho max(|d_i|, |p_i|))^2 + (g_i |p_i - p_i'|)^2)

- sigma_i: the config's ``sigma`` (counts per axis per window, in metres): the floor.
- rho: ``robust.relative_noise``, the error in proportion to motion (CPI off by a few per
  cent, arrival stamps jittering against a window of 10 ms).
- g_i = min(1, P_i / T) / 4 for a mouse reporting every P_i into windows of T: a report that
  straddles a window edge is split in proportion to time, which is wrong by up to a quarter
  of the change of motion within it (p_i' is the previous window's prediction).
- lf_i, lr_i >= 1: learned.  A config's sigma is a guess; a mouse at 1 kHz with noisy
  reports, or a floor that makes one mouse read a few per cent off, would fail a test built
  on the guess again and again.  So every ``block`` windows each factor is re-estimated from
  that mouse's residuals in the windows it was used in, consistent and moving (its last
  _KEEP (1024) samples of each; ``block`` is a second's windows): the floor's from windows where
  the floor is at least a quarter of the proportional part (that part subtracted), the
  proportional one's likewise.  For a
  2-D residual of per-axis variance s^2 (1 - h/2) (h: the mouse's leverage, the trace of its
  block of the hat matrix), |r|^2 / (s^2 (1 - h/2)) is chi-square with 2 degrees of freedom,
  whose median is 2 ln 2; the factor is the blocks' median over that.  It grows at once and
  shrinks by half-steps (geometric mean with the old one), and never goes below 1: the
  config's sigma is the least error a mouse is granted.  The floor's factor starts at 100
  (ten times the config's sigma) and comes down as the mouse shows it is quieter: starting
  strict would exclude a noisy mouse in exactly the windows that would have taught the model
  its noise, and with a generous floor those windows are plentiful (the floor then dominates
  at all but high speeds).  Faults at speed are caught by the proportional part meanwhile
  (which starts at 1: a generous start there, tried, missed a lift in its first window).
  A median is not moved by the few faulty windows that pass the test; windows that fail
  it, and excluded mice, give no samples.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

_MEDIAN_CHI2_2 = 2.0 * math.log(2.0)
_MIN_SAMPLES = 10
_START_FLOOR = 100.0  # the floor's factor before anything is learnt (see the docstring)
_KEEP = 1024  # samples per factor and mouse the estimate is made from
_MAX_FACTOR = 1e4


class _Samples:
    """One factor's samples from one mouse, oldest first.  The one-window path adds them a
    float at a time, the array path an array at a time; both are kept as they come (a list
    of floats, or the array) and joined into one array once per block, when the factor is
    estimated: no conversion per sample either way."""

    __slots__ = ("_chunks", "_n")

    def __init__(self) -> None:
        self._chunks: list = []  # lists of floats and arrays, in order
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def append(self, value: float) -> None:
        chunks = self._chunks
        if chunks and type(chunks[-1]) is list:
            chunks[-1].append(value)
        else:
            chunks.append([value])
        self._n += 1

    def extend(self, values: np.ndarray) -> None:
        self._chunks.append(values)
        self._n += len(values)

    def reset(self, values: np.ndarray) -> None:
        """Hold exactly ``values`` (oldest first)."""
        self._chunks, self._n = [values], len(values)

    def newest(self, keep: int) -> np.ndarray:
        """The newest ``keep`` samples as one array; older ones are forgotten."""
        chunks = self._chunks
        if len(chunks) == 1 and type(chunks[0]) is not list:
            values = chunks[0]
        else:
            values = np.concatenate([np.asarray(c, dtype=float) for c in chunks] or [np.zeros(0)])
        values = values[-keep:]
        self._chunks, self._n = [values], len(values)
        return values


def _middles(rows: np.ndarray, tail: float | None = None) -> np.ndarray:
    """Each row's estimate of its factor: its median, or its upper tail's estimate where
    that is larger (``_tail_rank``)."""
    n = rows.shape[1]
    mid = n // 2
    hi = _tail_rank(n)
    # The middle value and the tail's in place (a partition: the same values as a full
    # sort); the one below the middle of an even length is the largest of the part before.
    rows = np.partition(rows, (mid, hi) if hi > mid else (mid,), axis=1)
    middle = rows[:, mid] if n % 2 else 0.5 * (rows[:, :mid].max(axis=1) + rows[:, mid])
    if hi <= mid:
        return middle
    return np.maximum(middle, (_TAIL_TO_MEDIAN if tail is None else tail) * rows[:, hi])


# Timing noise (stamps that bunch after a delay) has a heavier tail than a Gaussian: a
# factor fitted to the median alone leaves the 1e-4 test failing a healthy mouse every few
# hundred windows.  So a factor is also fitted to the samples' 99.5th percentile, and the
# larger is kept; over _KEEP samples (1024: ten seconds of motion) that quantile is the
# sixth largest, not moved by one faulty window that passed the test.  The percentile is
# taken as the start of a tail that falls exponentially in |r| (what stamps late by an
# exponential delay give, the heaviest seen), not as a Gaussian's: from it to the test's
# false-alarm rate _TAIL_ALPHA |r| grows by ln(1/alpha) / ln(200) (a Gaussian's by the
# square root of that), and the factor makes the test's threshold (chi-square with 2
# degrees of freedom: 2 ln(1/alpha)) reach there.  Fitted as a Gaussian's, a mouse with
# exponential stamp delays of mean 3 ms was excluded 2.4 times per 10,000 windows (30 drives
# of 60 s); so, 1.6, most of them in the first two seconds of motion, before anything is
# learnt (0.5 after them; issue 31).  A mouse whose tail is Gaussian gets a tolerance 1.3
# times wider (sd) than its median alone would give: faults are far beyond that.
_TAIL = 0.995


def tail_to_median(alpha: float) -> float:
    """The factor that maps the tail's sample onto the median's scale for a test at
    false-alarm rate ``alpha`` (see above)."""
    return math.log(2.0) * math.log(1.0 / alpha) / math.log(1.0 / (1.0 - _TAIL)) ** 2


_TAIL_TO_MEDIAN = tail_to_median(1e-4)  # at robust.false_alarm's default


def _tail_rank(n: int) -> int:
    """The index, in n sorted samples, of the tail's quantile (the median's where n is
    too small to have a tail)."""
    return int(math.floor(_TAIL * (n - 1))) if n >= 20 else n // 2


# A median within [_STAYS_LOW, _STAYS_HIGH] times its factor cannot move it (see _moved: a
# factor moves when its estimate is over 1.05 times it, or under 0.95^2 times it), with a
# margin far wider than rounding.  Most factors sit at 1 (a config's sigma is a generous
# guess), where no estimate below can move them.
_STAYS_LOW = 0.9025 * (1.0 + 1e-6)
_STAYS_HIGH = 1.05 * (1.0 - 1e-6)
# A factor this close to 1 cannot fall by 5 % (it never goes below 1): no low bound.
_CANNOT_FALL = (1.0 / 0.95) * (1.0 - 1e-6)


def _estimates(
    joined: np.ndarray,
    sizes: np.ndarray,
    lam: np.ndarray,
    first: np.ndarray,
    series: np.ndarray,
    tail: float | None = None,
) -> np.ndarray:
    """For _moved: the median of each window of _KEEP samples where it may move its factor,
    the factor itself where the median surely lies in the band that leaves it as it is.

    ``joined`` holds the series one after the other (``sizes`` samples each, factors
    ``lam``); window k starts at ``first[k]`` in series ``series[k]``.  Counting decides:
    the median of an even number L of values is at least a if fewer than L/2 of them are
    below a, and at most b if more than L/2 are at most b (an odd L: its middle one, the
    same counts); running counts over ``joined`` give every window's at once.  NaN counts
    as above every bound, as in the partition.  In a steady run hardly any window needs
    its partition."""
    low = np.repeat(np.where(lam <= _CANNOT_FALL, -np.inf, _STAYS_LOW * lam), sizes)
    high = np.repeat(_STAYS_HIGH * lam, sizes)
    below = np.concatenate([[0], np.cumsum(joined < low)])
    at_most = np.concatenate([[0], np.cumsum(joined <= high)])
    end = first + _KEEP
    half, odd = _KEEP // 2, _KEEP % 2
    stays = (below[end] - below[first] <= half - 1 + odd) & (
        at_most[end] - at_most[first] >= half + 1
    )
    # ... and the tail's estimate stays below the band's top: at most the tail's share of
    # samples lies above it (then the rank of the tail quantile is at or under it)
    tail = _TAIL_TO_MEDIAN if tail is None else tail
    over = np.repeat(_STAYS_HIGH * lam / tail, sizes)
    tail_in = np.concatenate([[0], np.cumsum(joined <= over)])
    stays &= tail_in[end] - tail_in[first] >= _tail_rank(_KEEP) + 1
    out = lam[series]
    if not stays.all():
        windows = np.lib.stride_tricks.sliding_window_view(joined, _KEEP)
        out[~stays] = _middles(windows[first[~stays]], tail)
    return out


def _medians(samples: list[np.ndarray], tail: float | None = None) -> list[float]:
    """Each array's estimate of its factor (``_middles``: the median, or the tail's).
    Arrays of one length are partitioned as one (replay ends a block every second of data,
    thousands of times a run, and the mice's samples are usually all full)."""
    out: list[float] = [0.0] * len(samples)
    by_length: dict[int, list[int]] = {}
    for k, values in enumerate(samples):
        by_length.setdefault(len(values), []).append(k)
    for which in by_length.values():
        middle = _middles(np.stack([samples[k] for k in which]), tail)
        for k, v in zip(which, middle.tolist(), strict=True):
            out[k] = v
    return out


def _moved(lam: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each factor moved towards its estimate (module docstring: at once up, by half-steps
    down, within [1, _MAX_FACTOR]), and whether it moves at all: a step of under 5 % is
    noise of the median, not news, and is not taken (replay's arrays of the common case
    stay valid).  A NaN estimate leaves the factor at 1."""
    new = np.where(est > lam, est, np.sqrt(lam * np.maximum(est, 0.0)))
    new = np.minimum(_MAX_FACTOR, np.fmax(1.0, new))
    return new, np.abs(new - lam) > 0.05 * lam


def norm2(v: np.ndarray) -> np.ndarray:
    """|v|^2 of 2-vectors (..., 2): the same value as ``np.sum(v * v, axis=-1)`` (x^2 + y^2
    either way), several times faster (numpy's reduction over an axis of two is slow)."""
    x, y = v[..., 0], v[..., 1]
    return x * x + y * y


def motion2(d: np.ndarray, p: np.ndarray) -> np.ndarray:
    """max(|d|^2, |p|^2) per mouse for readings and predictions (..., N, 2)."""
    return np.maximum(norm2(d), norm2(p))


def sample_values(
    r2: float, floor: float, prop: float, h: float, sig2: float, lam_r: float
) -> tuple[float | None, float | None]:
    """One window's samples of a mouse's floor factor and proportional factor (None: no
    sample) from its squared residual ``r2``, the two parts of its current s^2, its
    leverage ``h``, its sigma^2 and its proportional factor now.  Each factor is estimated
    from windows where its part is at least a quarter of the other, the other part taken
    as it stands (``samples_for`` is this on arrays)."""
    expected = _MEDIAN_CHI2_2 * (1.0 - 0.5 * h)
    if expected <= 0:
        return None, None
    v = r2 / expected
    by_floor = (v - prop) / sig2 if 4.0 * floor >= prop else None
    by_prop = (v - floor) / (prop / lam_r) if 4.0 * prop >= floor and prop > 0 else None
    return by_floor, by_prop


class NoiseModel:
    def __init__(
        self,
        sigma: np.ndarray,
        rho: float,
        report_periods: np.ndarray,
        window: float,
        alpha: float = 1e-4,
    ) -> None:
        self.sig2 = np.asarray(sigma, dtype=float) ** 2
        self.tail = tail_to_median(alpha)  # the test's false-alarm rate (robust.false_alarm)
        self.n = len(self.sig2)
        self.rho2 = float(rho) ** 2
        periods = np.asarray(report_periods, dtype=float)
        self.gran2 = (0.25 * np.minimum(1.0, periods / window)) ** 2
        self.window = float(window)
        self.block = max(20, math.ceil(1.0 / window - 1e-9))
        self.lam_f = np.full(self.n, _START_FLOOR)
        self.lam_r = np.ones(self.n)
        self.seen = 0  # windows sampled in the current block
        self.version = 0  # bumped whenever a factor changes
        self._floor = [_Samples() for _ in range(self.n)]
        self._prop = [_Samples() for _ in range(self.n)]
        self._seen_len = [0] * (2 * self.n)  # samples each series held at the last block end
        self._sync()

    def _sync(self) -> None:
        # Python copies for the one-window path (which touches no numpy: see robust.fast_one)
        self.sig2_list = self.sig2.tolist()
        self.lam_r_list = self.lam_r.tolist()
        self.f_floor = (self.lam_f * self.sig2).tolist()
        self.f_rho2 = (self.lam_r * self.rho2).tolist()
        self.f_gran2 = (self.lam_r * self.gran2).tolist()

    # ----------------------------------------------------------------- the variance

    def parts(
        self,
        d: np.ndarray,
        p: np.ndarray,
        prev_p: np.ndarray,
        m2: np.ndarray | None = None,
        gran2: np.ndarray | None = None,
        gran_p: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(floor (N,), proportional (..., N)) parts of s^2 for readings d and predictions p
        (..., N, 2); ``m2``, if given, is ``motion2(d, p)``; ``gran2`` the granularity
        coefficients where not the mice's own (``gran2_for``), ``gran_p`` the predictions
        its change of motion is taken from where not p (``Screen._span_p``)."""
        if m2 is None:
            m2 = motion2(d, p)
        a2 = norm2((p if gran_p is None else gran_p) - prev_p)
        g2 = self.gran2 if gran2 is None else gran2
        # the floor per mouse (N,): it broadcasts against the (..., N) proportional part
        return self.lam_f * self.sig2, self.lam_r * (self.rho2 * m2 + g2 * a2)

    def gran2_for(self, spans: ArrayLike | None) -> np.ndarray | None:
        """The granularity coefficients (squared) of a window whose edges cut report spans
        ``spans`` (N,) s long (0: none; None: no window has one).  An edge inside a span
        of length L took a share of its counts in proportion to time, while the motion
        changed over L by L/T times its change over a window of T (|p - p'|, with which
        the term is multiplied): wrong by up to L/8 of that change of velocity, so the
        coefficient is (L/T)^2 / 8 where that exceeds the mouse's own."""
        if spans is None:
            return None
        g = (np.asarray(spans, dtype=float) / self.window) ** 2 / 8.0
        return np.maximum(self.gran2, g * g)

    def f_gran2_for(self, spans: list[float]) -> list[float]:
        """``f_gran2`` for a window whose edges cut report spans ``spans`` (``gran2_for``)."""
        coef = self.gran2_for(spans)
        return self.f_gran2 if coef is None else (self.lam_r * coef).tolist()

    # ----------------------------------------------------------------- learning

    def sample(self, i: int, r2: float, floor: float, prop: float, h: float) -> None:
        """One window's evidence from mouse i: squared residual r2, the two parts of its
        current s^2 and its leverage h (``sample_values``)."""
        by_floor, by_prop = sample_values(r2, floor, prop, h, self.sig2_list[i],
                                          self.lam_r_list[i])  # fmt: skip
        self.take([(i, by_floor)] if by_floor is not None else [],
                  [(i, by_prop)] if by_prop is not None else [])  # fmt: skip

    def take(self, by_floor: list[tuple[int, float]], by_prop: list[tuple[int, float]]) -> None:
        """Samples of the floor factor and of the proportional one, as (mouse, value)."""
        for i, v in by_floor:
            self._floor[i].append(v)
        for i, v in by_prop:
            self._prop[i].append(v)

    def samples_for(self, r2, floor, prop, h, eligible) -> tuple:
        """``sample``'s values for (n, N) arrays, where ``eligible``: (floor samples, where
        they count, proportional samples, where they count), for ``extend``."""
        expected = _MEDIAN_CHI2_2 * (1.0 - 0.5 * h)
        ok = eligible & (expected > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            v = r2 / expected
            fl = (v - prop) / self.sig2
            pr = (v - floor) / (prop / self.lam_r)
        return fl, ok & (4.0 * floor >= prop), pr, ok & (4.0 * prop >= floor) & (prop > 0)

    def extend(self, values: tuple, rows: slice) -> None:
        """Add the ``rows`` of ``samples_for``'s arrays, mouse by mouse in row order."""
        fl, by_floor, pr, by_prop = values
        for i in range(self.n):
            f = fl[rows, i][by_floor[rows, i]]
            if len(f):
                self._floor[i].extend(f)
            g = pr[rows, i][by_prop[rows, i]]
            if len(g):
                self._prop[i].extend(g)

    def end_block(self) -> None:
        """Re-estimate the factors from the last samples (module docstring); a factor
        without new samples since the last block stays as it is."""
        due, got = [], []  # the series whose estimate is due, and their samples
        for k, store in enumerate(self._stores()):
            if len(store) == self._seen_len[k]:
                continue  # no new evidence
            samples = store.newest(_KEEP)
            self._seen_len[k] = len(samples)
            if len(samples) >= _MIN_SAMPLES:
                due.append(k)
                got.append(samples)
        changed = False
        if due:
            lam = np.concatenate([self.lam_f, self.lam_r])
            new, moved = _moved(lam[due], np.array(_medians(got, self.tail)))
            if moved.any():
                lam[np.array(due)[moved]] = new[moved]
                self.lam_f[:], self.lam_r[:] = np.split(lam, 2)
                changed = True
        self.seen = 0
        if changed:
            self.version += 1
            self._sync()

    def _stores(self) -> list[_Samples]:
        """Every factor's samples: the floor's of each mouse, then the proportional ones
        (the order of ``_seen_len`` and of the factors' concatenation)."""
        return [*self._floor, *self._prop]

    def extend_blocks(self, values: tuple | None, start: int, stop: int) -> int:
        """Rows [start, stop) of ``samples_for``'s arrays accepted one after the other (None:
        rows that give no samples), with ``end_block`` wherever a block ends among them:
        the same samples, trims and factors as ``extend`` and ``end_block`` called window
        by window, but every block's medians taken at once.  Stops after the first block
        end that changes a factor (later rows' samples were made with the old ones);
        returns the row it stopped before (``stop`` if no factor changed)."""
        first_end = start + self.block - self.seen
        if first_end > stop:  # no block ends here
            if values is not None:
                self.extend(values, slice(start, stop))
            self.seen += stop - start
            return stop
        ends = list(range(first_end, stop + 1, self.block))
        last = ends[-1]
        # The factor series (floor of each mouse, then proportional) are the columns: every
        # array below is (block end, series).  Each series' samples, everything held
        # (untrimmed) and then the new ones up to the last block end, are one stretch of
        # ``joined``; ``hi`` is where each block end falls in its series.
        stores = self._stores()
        held = np.array([len(st) for st in stores])
        parts = [st.newest(len(st)) for st in stores]
        at = np.array(ends) - start - 1
        if values is None:
            new_at = np.zeros((len(ends), len(stores)), dtype=np.int64)
        else:
            # (series, row) here: each series' samples are then contiguous, in row order
            ok = np.concatenate([values[1][start:last].T, values[3][start:last].T])
            cols = np.concatenate([values[0][start:last].T, values[2][start:last].T])
            new_at = np.cumsum(ok, axis=1)[:, at].T
            fresh = np.split(cols[ok], np.cumsum(new_at[-1])[:-1])  # per series, in order
            parts = [x for pair in zip(parts, fresh, strict=True) for x in pair]
        joined = np.concatenate(parts)
        offset = np.concatenate([[0], np.cumsum(held + new_at[-1])[:-1]])
        hi = held + new_at
        # What end_block would do at each end: where there is new evidence since the last
        # end, trim to the newest _KEEP (lo: the first sample kept) and estimate if enough.
        fresh_evidence = np.empty(hi.shape, dtype=bool)
        fresh_evidence[0] = hi[0] != np.array(self._seen_len)
        fresh_evidence[1:] = hi[1:] != hi[:-1]
        lo = np.maximum(np.maximum.accumulate(np.where(fresh_evidence, hi - _KEEP, 0)), 0)
        size = hi - lo
        due = fresh_evidence & (size >= _MIN_SAMPLES)
        lam = np.concatenate([self.lam_f, self.lam_r])
        est = np.zeros(hi.shape)
        full = due & (size == _KEEP)
        if full.any():
            est[full] = _estimates(joined, held + new_at[-1], lam, (offset + lo)[full],
                                   np.nonzero(full)[1], self.tail)  # fmt: skip
        short = due & ~full
        if short.any():
            spans = zip((offset + lo)[short].tolist(), (offset + hi)[short].tolist(), strict=True)
            est[short] = _medians([joined[a:b] for a, b in spans], self.tail)
        # The factors stay as they are up to the first block end that moves one.
        new, moved = _moved(lam[None, :], est)
        moved &= due
        changed = bool(moved.any())
        done = int(np.flatnonzero(moved.any(axis=1))[0]) if changed else len(ends) - 1
        if changed:
            self.lam_f[:], self.lam_r[:] = np.split(np.where(moved[done], new[done], lam), 2)
        # Each series as end_block would have left it at block end ``done``.
        trimmed: list[bool] = np.any(fresh_evidence[: done + 1], axis=0).tolist()
        for k, (st, a, b) in enumerate(zip(stores, (offset + lo[done]).tolist(),
                                           (offset + hi[done]).tolist(), strict=True)):  # fmt: skip
            st.reset(joined[a:b])
            if trimmed[k]:
                self._seen_len[k] = b - a
        end, self.seen = ends[done], 0
        if changed:  # the caller goes on from here, with the new factors' arrays
            self.version += 1
            self._sync()
            return end
        if values is not None and end < stop:
            self.extend(values, slice(end, stop))
        self.seen = stop - end
        return stop
