"""``"%.<d>e" % x`` for whole arrays at once, digit for digit as Python writes it.

The replay CSV's covariance columns span many decades (1e-12 m^2 to 1 rad^2), so they are
written in exponent form; one %-operation per value would cost more than the rest of a row
(see ``mousedom.capture.fixedpoint`` for the fixed-point columns).

For |x| = m 10^e with 1 <= m < 10, the mantissa is computed in floating point, m = |x| 10^-e,
with a relative error of a few ulp (the power of ten is exact up to 10^22, the product rounded
once; a wrong guess of e from log10 costs one more rounding).  Rounding s = m 10^d to an
integer then gives Python's digits unless the exact s lies within that error of a half-way
point: those few values (found with a margin of 10^-14 s, some twenty times the error) are
formatted by Python itself.  So the text equals Python's for every finite double whose
exponent is within +-300; other values (and NaN, infinities) make ``scientific_bytes``
return None, and the caller formats those rows itself.
"""

from __future__ import annotations

import numpy as np

MAX_DIGITS = 9  # decimals of the mantissa
MAX_EXPONENT = 300  # |e| beyond this (1e-300, subnormals): None
_TIE_MARGIN = 1e-14
# "0000" ... "9999": four digits per table look-up
_QUAD_WORDS = np.frombuffer(b"".join(b"%04d" % i for i in range(10_000)), dtype="<u4").copy()
_E_PLUS = ord("e") | (ord("+") << 8)
_E_MINUS = ord("e") | (ord("-") << 8)
_POWERS = 10.0 ** np.arange(MAX_EXPONENT + 1)  # exact up to 1e22


def width(digits: int) -> int:
    """Bytes of one field (those that do not belong are masked out): a word of sign,
    digit and point; the decimals four to a word; a word of 'e' and the exponent's sign;
    one of the exponent's (up to) three digits; one of the separator."""
    return 4 * (4 + _quads(digits))


def _quads(digits: int) -> int:
    return -(-digits // 4)


def scientific_bytes(
    values: np.ndarray, digits: int, sep: bytes = b","
) -> tuple[np.ndarray, np.ndarray] | None:
    """For (n, k) values, the bytes of each ``"%.<digits>e" % v`` followed by ``sep`` (one
    byte, or none), as an (n, k * width(digits)) uint8 array and a mask of the bytes that
    belong (the text is the masked bytes in order).  None when a value is not finite or
    its exponent is beyond +-MAX_EXPONENT."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2:
        raise ValueError("values must be (n, k)")
    if not 1 <= digits <= MAX_DIGITS:
        raise ValueError(f"digits must be 1..{MAX_DIGITS}")
    if len(sep) > 1:
        raise ValueError("sep must be one byte or empty")
    if not np.isfinite(values).all():
        return None
    n, k = values.shape
    a = np.abs(values)
    nonzero = a > 0
    if nonzero.any():
        a_nz = a[nonzero]
        if not ((a_nz >= 10.0**-MAX_EXPONENT) & (a_nz < 10.0**MAX_EXPONENT)).all():
            return None
    e = np.zeros(a.shape, dtype=np.int64)
    with np.errstate(divide="ignore"):
        e[nonzero] = np.floor(np.log10(a[nonzero])).astype(np.int64)
    m = _mantissa(a, e)
    # log10 rounded across a power of ten: one step back
    over, under = m >= 10.0, nonzero & (m < 1.0)
    e += over.astype(np.int64) - under.astype(np.int64)
    if over.any() or under.any():
        m = _mantissa(a, e)
    s = m * 10.0**digits
    r = np.rint(s)
    tie = np.abs(np.abs(s - np.floor(s)) - 0.5) <= _TIE_MARGIN * s
    r_int = r.astype(np.int64)
    top = 10 ** (digits + 1)
    carry = r_int >= top  # 9.9999996 -> 1.000000e+01
    r_int[carry] //= 10
    e[carry] += 1
    for i, j in zip(*np.nonzero(tie), strict=True):
        mant, ex = ("%.*e" % (digits, values[i, j])).split("e")  # noqa: UP031 - the reference
        r_int[i, j] = int(mant.lstrip("-").replace(".", ""))
        e[i, j] = int(ex)

    q = _quads(digits)
    flat_r, flat_e = r_int.reshape(-1), e.reshape(-1)
    words = np.empty((n * k, 4 + q), dtype="<u4")
    lead = flat_r // 10**digits
    words[:, 0] = ord("-") | ((ord("0") + lead) << 8) | (ord(".") << 16)
    dec = flat_r - lead * 10**digits
    for j in range(q):  # most significant group first
        words[:, 1 + j] = _QUAD_WORDS[dec // 10 ** (4 * (q - 1 - j)) % 10_000]
    words[:, 1 + q] = np.where(flat_e < 0, _E_MINUS, _E_PLUS)
    ae = np.abs(flat_e)
    words[:, 2 + q] = _QUAD_WORDS[ae]
    words[:, 3 + q] = sep[0] if sep else 0
    keep = np.zeros((n * k, 4 + q, 4), dtype=bool)
    keep[:, 0, 0] = np.signbit(values).reshape(-1)
    keep[:, 0, 1:3] = True
    keep.reshape(n * k, -1)[:, 4 + 4 * q - digits : 4 + 4 * q] = True  # the decimals
    keep[:, 1 + q, :2] = True
    keep[:, 2 + q, 1] = ae >= 100
    keep[:, 2 + q, 2:] = True
    keep[:, 3 + q, 0] = bool(sep)
    w = width(digits)
    return words.view(np.uint8).reshape(n, k * w), keep.reshape(n, k * w)


def _mantissa(a: np.ndarray, e: np.ndarray) -> np.ndarray:
    """|x| 10^-e, with the power of ten on the side where it is exact (10^22 at most)."""
    pos = e >= 0
    return a * _POWERS[np.where(pos, 0, -e)] / _POWERS[np.where(pos, e, 0)]
