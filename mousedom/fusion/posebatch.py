"""The tracker's output: poses after consecutive windows, as arrays or as rows of floats.

Replay closes millions of windows per call and wants arrays; the daemon closes one per
call and writes it out as JSON, for which numpy arrays are only a detour (building a dozen
one-element arrays and converting them back cost more than the maths).  So a batch is
made either from arrays (``PoseBatch(...)``) or from rows of Python values
(``PoseBatch.from_rows``), and offers both views: the fields, built from the rows on first
access, and ``rows()``, made from the arrays when asked.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np


class PoseRow(NamedTuple):
    """One window's pose, in Python floats, ints, bools and lists."""

    t: float
    x: float
    y: float
    theta: float
    vx: float
    vy: float
    omega: float
    cov: list[list[float]]  # 3x3
    used: int
    ok: bool
    residual: list[list[float]]  # N x 2
    counts: list[list[float]] | list[tuple[float, float]]  # N x 2
    state: tuple[int, ...] | list[int]  # per mouse: robust.STATES index after the window
    reason: tuple[int, ...] | list[int]  # per mouse: robust.REASONS index
    consistent: bool  # False: the mice disagreed and nobody could be blamed
    qcov: list[list[float]]  # 3x3 covariance of the window's twist increment (u_x, u_y, a)
    # N x 2: each mouse's learnt scale per axis (REL_X, REL_Y) applied in the window, the
    # factor its counts were multiplied by (robust.ScaleLearner); () where none is learnt
    scale: list[list[float]] | tuple = ()
    # The gyro's word on the window (fusion.gyro.GyroWindow.row: turn, bias, bias_sigma,
    # stat, scale); () where the rig has no gyro
    gyro: list[float] | tuple = ()


GYRO_FIELDS = 5  # PoseRow.gyro: turn, bias, bias sigma, agreement, scale

_EMPTY: dict[int, PoseBatch] = {}  # PoseBatch.empty's, per number of mice
_DTYPES = {"used": int, "ok": bool, "state": np.int8, "reason": np.int8, "consistent": bool}


@dataclass
class PoseBatch:
    """Poses after consecutive windows; every field's first axis is the window."""

    t: np.ndarray  # window end times
    x: np.ndarray
    y: np.ndarray
    theta: np.ndarray
    vx: np.ndarray  # body-frame twist over the window (m/s, m/s, rad/s)
    vy: np.ndarray
    omega: np.ndarray
    cov: np.ndarray  # (n,3,3) covariance of (x, y, theta)
    used: np.ndarray  # number of sensors used
    ok: np.ndarray  # False: the live mice could not determine the motion; pose held
    residual: np.ndarray  # (n,N,2) metres, body frame: d - A q
    counts: np.ndarray  # (n,N,2) counts (REL_X, REL_Y) that fell into the window
    state: np.ndarray  # (n,N) int8: each mouse's health after the window (robust.STATES)
    reason: np.ndarray  # (n,N) int8: why, for suspect and excluded mice (robust.REASONS)
    consistent: np.ndarray  # (n,) bool: False where the mice disagreed, nobody blamed
    qcov: np.ndarray  # (n,3,3) covariance of the window's twist increment (u_x, u_y, a)
    scale: np.ndarray | None = None  # (n,N,2) learnt scale per mouse and axis; None: all 1
    # (n,5) the gyro's turn (rad), bias (rad/s), bias sigma (rad/s), agreement statistic
    # (chi-square, 1 dof) and scale error per window, NaN where it had no samples; None: no
    # gyro
    gyro: np.ndarray | None = None

    @classmethod
    def from_rows(cls, rows: list[PoseRow]) -> PoseBatch:
        """A batch of at least one row whose arrays are built only if a field is read."""
        batch = cls.__new__(cls)
        batch.__dict__["_rows"] = rows
        return batch

    def __getattr__(self, name: str) -> Any:
        # Only called for attributes not set: the fields of a batch made from rows.
        rows = self.__dict__.get("_rows")
        if rows is None or name not in PoseRow._fields:
            raise AttributeError(name)
        for k, column in zip(PoseRow._fields, zip(*rows, strict=True), strict=True):
            if k == "scale":
                self.__dict__[k] = _scale_column(column)
                continue
            if k == "gyro":
                self.__dict__[k] = _gyro_column(column)
                continue
            self.__dict__[k] = np.array(column, dtype=_DTYPES.get(k, np.float64))
        del self.__dict__["_rows"]
        return self.__dict__[name]

    def rows(self) -> Sequence[PoseRow]:
        """The poses as Python values (the rows it was made from, or the arrays' values)."""
        rows = self.__dict__.get("_rows")
        if rows is not None:
            return rows
        columns = [getattr(self, k).tolist() for k in PoseRow._fields[:-2]]
        scale, gyro = self.scale, self.gyro
        columns.append(scale.tolist() if scale is not None else [[] for _ in range(len(self))])
        columns.append(gyro.tolist() if gyro is not None else [[] for _ in range(len(self))])
        return [PoseRow(*values) for values in zip(*columns, strict=True)]

    def scales(self) -> np.ndarray:
        """(n, N, 2) the learnt scale of each mouse and axis per window (1 where none)."""
        if self.scale is not None:
            return self.scale
        return np.ones(self.counts.shape)

    def __len__(self) -> int:
        rows = self.__dict__.get("_rows")
        return len(rows) if rows is not None else len(self.t)

    @classmethod
    def empty(cls, n_mice: int) -> PoseBatch:
        """No window: one shared batch per number of mice (the daemon's poll returns one at
        most of its wakes; its arrays have no element to change, and no one sets a field).
        Its rows are an empty tuple, so ``rows()`` is as cheap as for a batch of rows."""
        batch = _EMPTY.get(n_mice)
        if batch is None:
            z = np.zeros(0)
            batch = _EMPTY[n_mice] = cls(
                t=z, x=z, y=z, theta=z, vx=z, vy=z, omega=z,
                cov=np.zeros((0, 3, 3)), used=np.zeros(0, dtype=int), ok=np.zeros(0, dtype=bool),
                residual=np.zeros((0, n_mice, 2)), counts=np.zeros((0, n_mice, 2)),
                state=np.zeros((0, n_mice), dtype=np.int8),
                reason=np.zeros((0, n_mice), dtype=np.int8), consistent=np.zeros(0, dtype=bool),
                qcov=np.zeros((0, 3, 3)),
            )  # fmt: skip
            batch.__dict__["_rows"] = ()
            for value in batch.__dict__.values():
                if isinstance(value, np.ndarray):
                    value.flags.writeable = False  # shared: no one may change it
        return batch

    @classmethod
    def concat(cls, batches: list[PoseBatch], n_mice: int | None = None) -> PoseBatch:
        batches = [b for b in batches if len(b)]
        if not batches:
            return cls.empty(n_mice or 0)
        columns = {
            f.name: np.concatenate([getattr(b, f.name) for b in batches])
            for f in fields(cls)
            if f.name not in ("scale", "gyro")
        }
        if any(b.scale is not None for b in batches):
            columns["scale"] = np.concatenate([b.scales() for b in batches])
        if any(b.gyro is not None for b in batches):
            columns["gyro"] = np.concatenate(
                [
                    b.gyro if b.gyro is not None else np.full((len(b), GYRO_FIELDS), np.nan)
                    for b in batches
                ]
            )
        return cls(**columns)

    def last(self) -> dict[str, float]:
        """The final pose as plain floats (for summaries)."""
        return {k: float(getattr(self, k)[-1]) for k in ("t", "x", "y", "theta")}


def _scale_column(column: tuple) -> np.ndarray | None:
    """The ``scale`` field of rows as an (n, N, 2) array, None if no row has one."""
    if all(len(v) == 0 for v in column):
        return None
    n_mice = next(len(v) for v in column if len(v))
    return np.array([v if len(v) else [[1.0, 1.0]] * n_mice for v in column], dtype=np.float64)


def _gyro_column(column: tuple) -> np.ndarray | None:
    """The ``gyro`` field of rows as an (n, GYRO_FIELDS) array (NaN rows where a row has none), None
    if no row has one."""
    if all(len(v) == 0 for v in column):
        return None
    return np.array([v if len(v) else (np.nan,) * GYRO_FIELDS for v in column], dtype=np.float64)
