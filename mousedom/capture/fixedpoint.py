"""``"%.<d>f" % x`` for whole arrays at once, digit for digit as Python writes it.

The replay CSV is millions of fixed-point numbers; formatting them one %-operation per row
was a third of a native replay.  Here the digits come from integer arithmetic on arrays, and
they are exact: Python's %-format rounds the double's exact binary value to d decimals, half
to even, and so does this.

The fraction f = |x| - floor(|x|) is exact.  s = f * 10**d rounded once, and r = rint(s)
is the exact answer unless s lies exactly half-way between integers: the exact product is
s + e, and only there does e decide (its sign; e == 0 is a true tie, half to even, which
``np.rint`` did).  e comes from splitting f * 10**d into two products that are exact in
float64 (Veltkamp's split of f into 26 + 27 bits, times a scale of at most 21 significant
bits) and Knuth's two-sum of them.

Values that are not finite or whose integer part has more than ``INT_DIGITS`` digits are
not handled: ``fixed_bytes`` returns None and the caller formats those rows itself.
"""

from __future__ import annotations

import functools

import numpy as np

INT_DIGITS = 10  # integer parts below 1e10 (epoch seconds, metres): 10 digit positions
MAX_DIGITS = 9  # decimals
_SPLIT = float(2**27 + 1)

# "0000" ... "9999": four digits per table look-up
_QUADS = np.frombuffer(b"".join(b"%04d" % i for i in range(10_000)), dtype=np.uint8).reshape(
    10_000, 4
)
_POWERS = 10 ** np.arange(INT_DIGITS, dtype=np.int64)  # 1, 10, ..., 1e9


def rounded_decimals(values: np.ndarray, digits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(integer part, decimals) of ``"%.<d>f" % abs(v)`` as int64 arrays, for finite values
    below 1e10: the decimals are ``round(frac * 10**d)``, half to even on the exact value,
    carried into the integer part when they reach ``10**d``.  ``digits`` broadcasts
    against ``values``."""
    a = np.abs(values)
    whole = np.floor(a)
    frac = a - whole  # exact
    scale = np.broadcast_to(10.0 ** np.asarray(digits, dtype=np.float64), a.shape)
    s = frac * scale  # the exact product, rounded once
    r = np.rint(s)
    diff = s - r  # exact; +-0.5 only when s is half-way and rint went to the even side
    half = np.flatnonzero(np.abs(diff) == 0.5)
    if len(half):
        # Half-way after rounding: the exact product's lost bits decide (rare: only there
        # is the product's error looked at).
        r_flat, diff_h = r.reshape(-1), diff.reshape(-1)[half]
        e = _product_error(frac.reshape(-1)[half], scale.reshape(-1)[half], s.reshape(-1)[half])
        r_flat[half] += ((diff_h > 0) & (e > 0)).astype(np.float64)
        r_flat[half] -= ((diff_h < 0) & (e < 0)).astype(np.float64)
    carry = r >= scale
    r[carry] = 0.0
    whole += carry
    return whole.astype(np.int64), r.astype(np.int64)


def _product_error(frac: np.ndarray, scale: np.ndarray, s: np.ndarray) -> np.ndarray:
    """e with frac * scale == s + e exactly, where s is the rounded product."""
    c = frac * _SPLIT
    hi = c - (c - frac)  # 26 bits
    lo = frac - hi  # 27 bits
    p1, p2 = hi * scale, lo * scale  # exact: 10**d has at most 21 significant bits for d <= 9
    # two-sum of p1 + p2 (whose rounded sum is s, as the product's is)
    b = s - p1
    return (p1 - (s - b)) + (p2 - b)


def fixed_bytes(
    values: np.ndarray, digits: np.ndarray, sep: bytes = b","
) -> tuple[np.ndarray, np.ndarray] | None:
    """For (n, k) values and k decimal counts (1..9), the bytes of each ``"%.<d>f" % v``
    followed by ``sep`` (one byte, or none), as an (n, k * FIELD) uint8 array and a mask of
    the bytes that belong (the text is the masked bytes in order: row by row, ``sep``
    after every value).  None when some value is not finite or is 1e10 or more."""
    values = np.asarray(values, dtype=np.float64)
    digits = np.asarray(digits, dtype=np.int64)
    if values.ndim != 2 or digits.shape != (values.shape[1],):
        raise ValueError("values must be (n, k) and digits (k,)")
    # No "%.0f": its tie goes to the even integer part, which the rounding above does not
    # look at (with decimals, the last decimal's parity is r's own).
    if not (digits >= 1).all() or not (digits <= MAX_DIGITS).all():
        raise ValueError(f"digits must be 1..{MAX_DIGITS}")
    if len(sep) > 1:
        raise ValueError("sep must be one byte or empty")
    if not (np.abs(values) < 10.0**INT_DIGITS).all():  # NaN fails this too
        return None
    n, k = values.shape
    whole, dec = rounded_decimals(values, digits)
    if not (whole < _POWERS[-1] * 10).all():  # 9999999999.97 rounds up to 11 digits
        return None
    dec *= 10 ** (MAX_DIGITS - digits)  # nine digits, the unused ones zero

    # The field as 7 little-endian words of 4 bytes (see _SIGN...): four digits per word,
    # each a look-up in _QUAD_WORDS; bytes that do not belong are masked out.
    words = np.empty((n, k, 7), dtype=np.uint32)
    words[:, :, 0] = (_QUAD_WORDS[whole // 100_000_000] & 0xFFFF0000) | ord("-")
    words[:, :, 1] = _QUAD_WORDS[whole // 10_000 % 10_000]
    words[:, :, 2] = _QUAD_WORDS[whole % 10_000]
    words[:, :, 3] = (ord(".") << 16) | ((ord("0") + dec // 100_000_000) << 24)
    words[:, :, 4] = _QUAD_WORDS[dec // 10_000 % 10_000]
    words[:, :, 5] = _QUAD_WORDS[dec % 10_000]
    words[:, :, 6] = sep[0] if sep else 0
    # The first three words' mask depends on the sign and the integer part's length, the
    # rest on the column only.
    n_int = np.maximum(np.searchsorted(_POWERS, whole, side="right"), 1)
    lead = np.signbit(values) * (INT_DIGITS + 1) + n_int
    keep = np.empty((n, k, 7), dtype=np.uint32)
    for w in range(3):
        keep[:, :, w] = _LEAD_MASKS[w][lead]
    keep[:, :, 3:] = _tail_masks(tuple(digits.tolist()), bool(sep))
    return words.view(np.uint8).reshape(n, -1), keep.view(bool).reshape(n, -1)


# Byte positions in a field (28 bytes = 7 words): sign, pad, two integer digits | four |
# four | pad, pad, point, first decimal | four decimals | four decimals | separator, pads.
_SIGN, _INT, _POINT, _DEC, _SEP = 0, (2, 3, *range(4, 12)), 14, (15, *range(16, 24)), 24
FIELD = 28
_QUAD_WORDS = _QUADS.copy().view("<u4").ravel()


def _word_masks(m: np.ndarray) -> np.ndarray:
    """(..., 4 * w) bool -> (..., w) uint32 words of 0/1 bytes."""
    return np.ascontiguousarray(m, dtype=np.uint8).view("<u4")


def _lead() -> list[np.ndarray]:
    """By (negative * 11 + integer digits): the masks of the first three words."""
    m = np.zeros((2, INT_DIGITS + 1, 12), dtype=bool)
    m[1, :, _SIGN] = True
    for n_int in range(1, INT_DIGITS + 1):
        m[:, n_int, list(_INT[INT_DIGITS - n_int :])] = True
    words = _word_masks(m.reshape(-1, 12))
    return [np.ascontiguousarray(words[:, w]) for w in range(3)]


_LEAD_MASKS = _lead()


@functools.lru_cache(maxsize=64)
def _tail_masks(digits: tuple[int, ...], sep: bool) -> np.ndarray:
    """(k, 4): the masks of the last four words (point, decimals, separator) per column."""
    m = np.zeros((len(digits), 16), dtype=bool)
    m[:, _POINT - 12] = True
    for j, d in enumerate(digits):
        m[j, [i - 12 for i in _DEC[:d]]] = True
    m[:, _SEP - 12] = sep
    words = _word_masks(m)
    words.setflags(write=False)  # cached: shared by every call
    return words
