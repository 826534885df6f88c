"""The replay's pose CSV: ``CsvSink`` writes pose batches as rows, ``read_csv`` reads them
back (tests, golden files, the plot)."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from mousedom.capture.fixedpoint import fixed_bytes
from mousedom.capture.scientific import scientific_bytes
from mousedom.config.names import column_suffix
from mousedom.fusion.tracker import PoseBatch

CSV_COLUMNS = ("t", "x", "y", "theta", "vx", "vy", "omega", "used", "ok", "consistent")
_ROW = "%.6f,%.9f,%.9f,%.9f,%.6f,%.6f,%.6f,%d,%d,%d"
# Then per mouse: state_<name> (fusion.robust.STATES: 0 tracking, 1 suspect, 2 excluded,
# 3 missing, 4 late) and reason_<name> (fusion.robust.REASONS: 0 none, 1 inconsistent, 2 silent
# while others move, 3 saturated, 4 low quality), as numbers so the file stays numeric.
# Then the pose covariance, the upper triangle of the batch's cov over (x, y, theta) in the
# units of the pose columns (m^2, m^2, m rad, m^2, m rad, rad^2), exponent form, and per
# mouse scale_x_<name>, scale_y_<name>: the learnt scale of its counts along its own axes
# (REL_X, REL_Y; 1 where none is learnt).
COV_COLUMNS = ("cov_xx", "cov_xy", "cov_xt", "cov_yy", "cov_yt", "cov_tt")
# Last, for a rig with a gyro (replayed with it): its bias after the window (rad/s), the
# bias's standard deviation (rad/s), the agreement statistic of the window (mice against
# gyro, chi-square with 1 degree of freedom) and its scale error (it reads 1 + scale times
# the turn), exponent form; nan where the gyro had no samples yet (PoseBatch.gyro's
# columns 1 to 4).
GYRO_COLUMNS = ("gyro_bias", "gyro_bias_sigma", "gyro_agree", "gyro_scale")
_COV_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_COV_DIGITS = 6  # "%.6e": seven significant digits
_SCALE_DIGITS = 6  # "%.6f"


def health_columns(names: tuple[str, ...]) -> list[str]:
    """The per-mouse state and reason columns."""
    return [f"{kind}_{n}" for n in map(column_suffix, names) for kind in ("state", "reason")]


def scale_columns(names: tuple[str, ...]) -> list[str]:
    """The per-mouse learnt scale columns, after the covariance."""
    return [f"{kind}_{n}" for n in map(column_suffix, names) for kind in ("scale_x", "scale_y")]


def gyro_columns() -> list[str]:
    """The gyro's columns, after the scales (a rig replayed with its gyro only)."""
    return list(GYRO_COLUMNS)


def csv_columns(names: tuple[str, ...], gyro: bool = False) -> list[str]:
    """The header of the replay CSV of a rig whose mice are ``names`` (and its gyro)."""
    return [*CSV_COLUMNS, *health_columns(names), *COV_COLUMNS, *scale_columns(names),
            *(gyro_columns() if gyro else [])]  # fmt: skip


class TextOut(Protocol):
    """Where CsvSink writes: a text file, or a wrapper that names it in write errors."""

    def write(self, text: str, /) -> object: ...


class CsvSink:
    """Writes pose batches as CSV rows (header first)."""

    def __init__(self, out: TextOut, names: tuple[str, ...] = (), gyro: bool = False) -> None:
        self.out = out
        self.rows = 0
        self.n = len(names)
        self.gyro = gyro  # the gyro's columns (GYRO_COLUMNS) after the scales
        self._tails: dict[int, str] = {}
        self.radix = max(self.n + 1, 5)  # used <= N mice, states < 4, reasons < 5
        out.write(",".join(csv_columns(names, gyro)) + "\n")
        # One row by %-format, for batches the array formatters do not take (not finite).
        fmt = _FLOATS + "%s" + "%.6e," * len(COV_COLUMNS) + "%.6f," * (2 * self.n)
        fmt += "%.6e," * (len(GYRO_COLUMNS) if gyro else 0)
        self._row_format = fmt[:-1] + "\n"

    def __call__(self, b: PoseBatch) -> None:
        n = len(b)
        if not n:
            return
        # The whole-number columns (used, ok, consistent, each mouse's state and reason)
        # take few distinct values: each distinct tail of a row is formatted once.
        ints = np.column_stack([b.used, b.ok, b.consistent]).astype(np.int64)
        if self.n:
            both = np.stack([b.state, b.reason], axis=2).reshape(n, 2 * self.n)
            ints = np.column_stack([ints, both.astype(np.int64)])
        codes, inverse = _row_codes(ints, self.radix)
        tails = []
        for code, row in zip(codes.tolist(), ints[_first_of(inverse, len(codes))].tolist(),
                             strict=True):  # fmt: skip
            tail = self._tails.get(code) if code >= 0 else None
            if tail is None:
                tail = ",".join(map(str, row)) + ","
                if code >= 0 and len(self._tails) < 4096:
                    self._tails[code] = tail
            tails.append(tail)
        floats = np.column_stack([b.t, b.x, b.y, b.theta, b.vx, b.vy, b.omega])
        cov = np.asarray(b.cov)[:, [i for i, _ in _COV_INDEX], [j for _, j in _COV_INDEX]]
        scales = b.scales()[:, : self.n].reshape(n, 2 * self.n) if self.n else np.zeros((n, 0))
        gyro = self._gyro(b)
        fields = fixed_bytes(floats, _DIGITS)
        cov_fields = scientific_bytes(cov, _COV_DIGITS)
        scale_fields = fixed_bytes(scales, np.full(2 * self.n, _SCALE_DIGITS)) if self.n else None
        gyro_fields = scientific_bytes(gyro, _COV_DIGITS) if self.gyro else None
        if (fields is None or cov_fields is None or (self.n and scale_fields is None)
                or (self.gyro and gyro_fields is None)):  # fmt: skip
            # Not finite, or too large for the array formatters: one %-operation per row.
            values = np.column_stack([floats, cov, scales, gyro]).tolist()
            fmt, rows = self._row_format, zip(values, inverse.tolist(), strict=True)
            self.out.write("".join(fmt % (*v[:7], tails[i], *v[7:]) for v, i in rows))
        else:
            more = [f for f in (scale_fields, gyro_fields) if f is not None]
            blocks = [fields, cov_fields, *more]
            self.out.write(_join_rows(blocks, tails, inverse))
        self.rows += n

    def _gyro(self, b: PoseBatch) -> np.ndarray:
        """The batch's gyro columns (n, 3); none without a gyro, nan if it has none."""
        if not self.gyro:
            return np.zeros((len(b), 0))
        if b.gyro is None:
            return np.full((len(b), len(GYRO_COLUMNS)), np.nan)
        return np.asarray(b.gyro, dtype=np.float64)[:, 1 : 1 + len(GYRO_COLUMNS)]


def _join_rows(
    blocks: list[tuple[np.ndarray, np.ndarray]], tails: list[str], inverse: np.ndarray
) -> str:
    """The rows' text: each row's float fields (the first block, with their separators),
    then its tail, then the other blocks (at least one; fixed layouts, a separator after
    each field); the row's last separator becomes its newline."""
    raw = [t.encode("ascii") for t in tails]
    lengths = np.array([len(t) for t in raw])
    width = int(lengths.max())
    table = np.zeros((len(raw), width), dtype=np.uint8)
    for i, t in enumerate(raw):
        table[i, : len(t)] = np.frombuffer(t, dtype=np.uint8)
    (first, first_keep), rest = blocks[0], blocks[1:]
    n = len(first)
    text = np.concatenate(
        [first.reshape(n, -1), table[inverse]] + [t.reshape(n, -1) for t, _ in rest], axis=1
    )
    keep = np.concatenate([first_keep.reshape(n, -1), np.arange(width) < lengths[inverse, None]]
                          + [k.reshape(n, -1) for _, k in rest], axis=1)  # fmt: skip
    # The last kept byte is the separator after the last field, at the same place in every
    # row (the last block's fields have a fixed layout): it becomes the newline.
    last = keep.shape[1] - 1 - int(np.argmax(rest[-1][1][0, ::-1]))
    text[:, last] = ord("\n")
    return text[keep].tobytes().decode("ascii")


_FLOATS = _ROW[: _ROW.index(",%d") + 1]  # with the comma before the tail
_DIGITS = np.array([int(f[2]) for f in _FLOATS.split(",")[:-1]])  # decimals per float column


def _row_codes(ints: np.ndarray, radix: int) -> tuple[np.ndarray, np.ndarray]:
    """Distinct rows of small non-negative ints (each < radix) as one int64 code each,
    the same in every batch, and each row's index among them (np.unique of rows without
    its slow axis=0 path)."""
    weights = np.int64(radix) ** np.arange(ints.shape[1], dtype=np.int64)
    if radix ** ints.shape[1] >= 2**62 or (ints.size and not 0 <= ints.min() <= ints.max() < radix):
        # too many columns for one code, or values out of range: rows as they are
        rows, inverse = np.unique(ints, axis=0, return_inverse=True)
        return -1 - np.arange(len(rows)), inverse.ravel()  # codes not cached across calls
    codes, inverse = np.unique(ints @ weights, return_inverse=True)
    return codes, inverse.ravel()


def _first_of(inverse: np.ndarray, k: int) -> np.ndarray:
    """For each of k distinct values, the first row that has it."""
    first = np.full(k, len(inverse), dtype=np.int64)
    np.minimum.at(first, inverse, np.arange(len(inverse)))
    return first


def read_csv(text: str) -> dict[str, np.ndarray]:
    """Parse what ``CsvSink`` wrote (for tests, golden files and the plot)."""
    lines = text.strip().splitlines()
    header = lines[0].split(",")
    data = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]]).reshape(
        -1, len(header)
    )
    return {name: data[:, i] for i, name in enumerate(header)}
