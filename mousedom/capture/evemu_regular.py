"""evemu event lines as evemu writes them, parsed at fixed offsets from each line's point.

evemu writes ``E: %lu.%06u %04x %04x %d`` (1.3 writes the value as ``%04d`` followed by a
tab and a ``#`` comment).  So each line holds one decimal point, and the fraction, type
and code sit at fixed offsets after it.  Every field is then read with one gather per line:
8 or 4 bytes at once, through a view of the block whose elements start at every byte
(stride 1).  Each field's bytes are then split into pairs of characters looked up in a
table of the 65,536 pairs.  The table gives a pair's value, or -1 if either byte is not a
digit.  That is one pass per field where the general parser (``evemu_lines``) makes one
per digit.

A field of variable width (the seconds, the value) is right- or left-aligned in its 8
bytes, and the bytes outside it are replaced by ``"0"``.  Anything this layout does not
describe returns None, and ``evemu_lines.general_events`` decides.
"""

from __future__ import annotations

import numpy as np

_ZEROS = 0x3030303030303030  # "00000000"


def _pair_table(digits: bytes) -> np.ndarray:
    """The value of two characters (the first in the low byte) for every 16-bit pair; -1
    unless both are in ``digits``."""
    table = np.full(1 << 16, -1, dtype=np.int16)
    base = 16 if len(digits) > 10 else 10
    for a in digits:
        for c in digits:
            table[a | c << 8] = int(bytes([a, c]), base)
    return table


_DEC_PAIRS = _pair_table(b"0123456789")
_HEX_PAIRS = _pair_table(b"0123456789abcdefABCDEF")


def _masks(size: int, dtype: type) -> tuple[np.ndarray, np.ndarray]:
    """For a field of w = 0..size characters in a word of ``size`` bytes, by w: the bits
    of its top w bytes, and "0"s in the other bytes."""
    full = (1 << 8 * size) - 1
    low = [(1 << 8 * (size - w)) - 1 for w in range(size + 1)]
    keep: np.ndarray = np.array([full & ~m for m in low], dtype=dtype)
    fill: np.ndarray = np.array([_ZEROS & m for m in low], dtype=dtype)
    return keep, fill


_KEEP8, _FILL8 = _masks(8, np.uint64)
_KEEP4, _FILL4 = _masks(4, np.uint32)
_POW10 = 10 ** np.arange(5, dtype=np.int64)


class _Words:
    """The block's bytes as 8- and 4-byte little-endian words starting at every byte."""

    def __init__(self, block: bytes | memoryview) -> None:
        n = len(block)
        self.w8 = np.ndarray((max(n - 7, 0),), dtype="<u8", buffer=block, strides=(1,))
        self.w4 = np.ndarray((max(n - 3, 0),), dtype="<u4", buffer=block, strides=(1,))


def _pairs(words: np.ndarray, table: np.ndarray, count: int):
    """The first ``count`` character pairs of each word looked up: (n, count) int16, or
    None if any is not a pair of digits."""
    per_word = words.dtype.itemsize // 2
    pairs = table[words.view("<u2").reshape(-1, per_word)[:, :count]]
    if len(pairs) and pairs.min() < 0:
        return None
    return pairs


def _combine(pairs: np.ndarray, base: int) -> np.ndarray:
    """The pairs' values as one number each (the first pair the most significant)."""
    scale = base * base
    value = pairs[:, 0].astype(np.int64)
    for k in range(1, pairs.shape[1]):
        value *= scale
        value += pairs[:, k]
    return value


def _right_aligned(words: _Words, end: np.ndarray, width: np.ndarray):
    """Decimal fields of 1 to 12 digits ending just before ``end``; None if malformed.
    Each field's last 8 (then 4 more) bytes, kept where the field is, "0"s elsewhere."""
    low_w = np.minimum(width, 8)
    low = (words.w8[end - 8] & _KEEP8[low_w]) | _FILL8[low_w]
    low_pairs = _pairs(low, _DEC_PAIRS, 4)
    if low_pairs is None:
        return None
    value = _combine(low_pairs, 10)
    if width.max() > 8:
        high_w = np.maximum(width - 8, 0)
        high = (words.w4[end - 12] & _KEEP4[high_w]) | _FILL4[high_w]
        high_pairs = _pairs(high, _DEC_PAIRS, 2)
        if high_pairs is None:
            return None
        value += _combine(high_pairs, 10) * 100_000_000
    return value


def _left_aligned(words: _Words, begin: np.ndarray, width: np.ndarray):
    """Decimal fields of 1 to 12 digits starting at ``begin``; None if malformed.  Read
    from their start (a block's first line has only 3 bytes before its seconds): the
    field's bytes shifted to the top of the word, "0"s shifted in below."""
    first_w = np.minimum(width, 8)
    first = (words.w8[begin] << (8 * (8 - first_w)).astype(np.uint64)) | _FILL8[first_w]
    first_pairs = _pairs(first, _DEC_PAIRS, 4)
    if first_pairs is None:
        return None
    value = _combine(first_pairs, 10)
    if width.max() > 8:
        rest_w = np.maximum(width - 8, 0)
        # at most 24 bits: a shift by the word's whole width is not defined; the mask
        # drops what a field of no digits would keep
        shift = np.minimum(8 * (4 - rest_w), 24).astype(np.uint32)
        rest = ((words.w4[begin + 8] << shift) & _KEEP4[rest_w]) | _FILL4[rest_w]
        rest_pairs = _pairs(rest, _DEC_PAIRS, 2)
        if rest_pairs is None:
            return None
        value = value * _POW10[rest_w] + _combine(rest_pairs, 10)
    return value


def line_bounds(b: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(first byte, newline) of each line of a block of whole lines, or None if it does
    not end with a newline (or is empty)."""
    nl = np.flatnonzero(b == 10)
    if len(nl) == 0 or nl[-1] != len(b) - 1:
        return None
    starts = np.empty(len(nl), dtype=np.int64)
    starts[0] = 0
    starts[1:] = nl[:-1] + 1
    return starts, nl


def regular_columns(block: bytes | memoryview):
    """(seconds, microseconds, type, code, value) int64 columns of a block of whole lines
    written as evemu writes them (module docstring), or None."""
    b = np.frombuffer(block, dtype=np.uint8)
    lines = line_bounds(b)
    if lines is None:
        return None
    starts, nl = lines
    n = len(nl)
    dot = np.flatnonzero(b == 46)
    # One point per line, after "E: " and 1 to 12 digits, and room for ".uuuuuu tttt cccc v".
    sec_w = dot - starts - 3 if len(dot) == n else None
    if sec_w is None or sec_w.min() < 1 or sec_w.max() > 12 or ((nl - dot) < 19).any():
        return None
    if not ((b[starts] == 69) & (b[starts + 1] == 58) & (b[starts + 2] == 32)).all():
        return None
    if not ((b[dot + 7] == 32) & (b[dot + 12] == 32) & (b[dot + 17] == 32)).all():
        return None
    tabs = np.flatnonzero(b == 9)
    if len(tabs) == 0:
        vend = nl
    elif len(tabs) == n and ((tabs > dot + 18) & (tabs < nl)).all() and (b[tabs + 1] == 35).all():
        vend = tabs  # "value<TAB># comment"
    else:
        return None
    sign = b[dot + 18]
    neg = sign == 45
    vstart = dot + 18 + (neg | (sign == 43))
    value_w = vend - vstart
    if value_w.min() < 1 or value_w.max() > 10:
        return None
    words = _Words(block)
    sec = _left_aligned(words, starts + 3, sec_w)
    value = _right_aligned(words, vend, value_w)
    usec = _pairs(words.w8[dot + 1], _DEC_PAIRS, 3)  # six digits, then " t"
    typ = _pairs(words.w4[dot + 8], _HEX_PAIRS, 2)
    code = _pairs(words.w4[dot + 13], _HEX_PAIRS, 2)
    if sec is None or value is None or usec is None or typ is None or code is None:
        return None
    value = np.where(neg, -value, value)
    if (value < -(2**31)).any() or (value >= 2**31).any():
        return None
    return sec, _combine(usec, 10), _combine(typ, 16), _combine(code, 16), value
