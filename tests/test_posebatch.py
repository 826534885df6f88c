"""PoseBatch made from rows (the daemon's one-window path) and from arrays agree."""

from __future__ import annotations

import numpy as np
import pytest

from mousedom.fusion.posebatch import PoseBatch, PoseRow


def _row(k: int) -> PoseRow:
    cov = [[1e-6 * (k + 1), 2e-9, 0.0], [2e-9, 3e-6, 1e-9], [0.0, 1e-9, 4e-5]]
    res = [[1e-5 * k, -2e-5], [0.0, 0.0]]
    health = ((0, 2 * (k % 2)), (0, k % 2), k != 1)
    return PoseRow(0.01 * k, 0.1 * k, -0.2, 0.3, 1.0, 0.0, -0.5, cov, 2 - k % 2, k % 3 != 0,
                   res, [(k, -3.0), (0.5, 2.0)], *health, cov)  # fmt: skip


def test_rows_become_arrays_of_the_array_layout_on_first_read():
    rows = [_row(k) for k in range(3)]
    batch = PoseBatch.from_rows(rows)
    assert len(batch) == 3 and batch.rows() is rows  # no conversion for the daemon
    assert batch.cov.shape == (3, 3, 3) and batch.residual.shape == (3, 2, 2)
    assert batch.counts.shape == (3, 2, 2) and batch.t.dtype == np.float64
    assert batch.used.dtype.kind == "i" and batch.ok.dtype == bool
    assert batch.ok.tolist() == [False, True, True]
    assert batch.state.shape == (3, 2) and batch.state.dtype == np.int8
    assert batch.state[1].tolist() == [0, 2] and batch.consistent.tolist() == [True, False, True]
    assert np.array_equal(batch.counts[1], [[1.0, -3.0], [0.5, 2.0]])
    # once materialised it is an ordinary batch: rows() from the arrays give the same values
    assert batch.rows() == [PoseRow(*[np.asarray(v).tolist() for v in r]) for r in rows]
    assert "_rows" not in vars(batch)
    arrays = PoseBatch(**vars(batch))
    joined = PoseBatch.concat([arrays, PoseBatch.from_rows([_row(7)])])
    assert len(joined) == 4 and joined.x[-1] == 0.1 * 7 and joined.cov[-1, 0, 0] == 1e-6 * 8


def test_unknown_attributes_still_raise():
    batch = PoseBatch.from_rows([_row(1)])
    with pytest.raises(AttributeError):
        batch.nope  # noqa: B018
    assert batch.last() == {"t": 0.01, "x": 0.1, "y": -0.2, "theta": 0.3}
