"""evdev source: the float path of the stamp clamp equals the array path."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.sources.evdev import _clamp_forward

stamps = st.floats(-10.0, 10.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(st.lists(stamps, min_size=1, max_size=80), st.one_of(st.just(-np.inf), stamps))
def test_clamp_forward(values, last):
    t = np.array(values)
    want = np.maximum.accumulate(np.concatenate([[last], t]))[1:]
    got, back = _clamp_forward(t, last)
    assert np.array_equal(got, want)
    assert back == int(np.count_nonzero(want > t))
