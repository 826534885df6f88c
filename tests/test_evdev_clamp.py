"""evdev source: the stamp clamp (a kernel stamp behind the previous one is raised to it),
in its bulk form and its list form, against hand-written cases and each other."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.sources.base import clamp_forward as _clamp_forward
from mousedom.sources.base import clamp_list as _clamp_list

stamps = st.floats(-10.0, 10.0, allow_nan=False)

CASES = [
    # (stamps, last, clamped, moved): written out by hand
    ([1.0, 2.0, 3.0], -np.inf, [1.0, 2.0, 3.0], 0),
    ([1.0, 0.5, 3.0], -np.inf, [1.0, 1.0, 3.0], 1),
    ([1.0, 2.0], 5.0, [5.0, 5.0], 2),
    ([3.0, 1.0, 2.0, 4.0], 0.0, [3.0, 3.0, 3.0, 4.0], 2),
    ([2.0, 2.0, 1.0], 2.0, [2.0, 2.0, 2.0], 1),  # equal is in order
]


@pytest.mark.parametrize("values, last, want, moved", CASES)
def test_both_clamps_on_hand_written_cases(values, last, want, moved):
    got, back = _clamp_forward(np.array(values), last)
    assert got.tolist() == want and back == moved
    as_list = list(values)
    assert _clamp_list(as_list, last) == moved and as_list == want


@settings(max_examples=300, deadline=None)
@given(st.lists(stamps, min_size=1, max_size=80), st.one_of(st.just(-np.inf), stamps))
def test_the_list_clamp_equals_the_bulk_clamp(values, last):
    got, back = _clamp_forward(np.array(values), last)
    as_list = list(values)
    assert _clamp_list(as_list, last) == back
    assert as_list == got.tolist()
    assert all(b >= a for a, b in zip(as_list, as_list[1:], strict=False))
    assert all(v >= last for v in as_list)
