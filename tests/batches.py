"""Comparing pose batches in tests."""

from __future__ import annotations

import numpy as np

from mousedom.fusion.posebatch import PoseBatch


def assert_same_batches(a: PoseBatch, b: PoseBatch) -> None:
    """Every field of every window the same, bit for bit (dtypes too)."""
    for key, value in vars(a).items():
        other = getattr(b, key)
        if isinstance(value, np.ndarray):
            assert value.dtype == other.dtype and value.tobytes() == other.tobytes(), key
        else:
            assert value == other, key
