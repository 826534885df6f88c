"""protocol.encode_pose (the daemon's per-window POSE line) equals encode(pose_message(...))."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.service.protocol import encode, encode_pose, pose_message

# every float, NaN and the infinities included (they must become null)
anyfloat = st.floats(allow_nan=True, allow_infinity=True)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-1e9, 1e9, allow_nan=False),
    st.tuples(anyfloat, anyfloat, anyfloat),
    st.tuples(anyfloat, anyfloat, anyfloat),
    st.lists(st.lists(anyfloat, min_size=3, max_size=3), min_size=3, max_size=3),
    st.integers(0, 64),
    st.booleans(),
    st.lists(st.text(max_size=12), max_size=4),
    st.lists(st.text(max_size=12), max_size=3),
    st.lists(st.text(max_size=12), max_size=3),
    st.booleans(),
)
def test_encode_pose_is_byte_identical(
    t, pose, twist, cov, used, updating, missing, excluded, suspect, consistent
):
    health = (excluded, suspect, consistent)
    want = encode(pose_message(t, pose, twist, np.array(cov), used, updating, missing, *health))
    got = encode_pose(t, pose, twist, cov, used, updating, tuple(missing), tuple(excluded),
                      tuple(suspect), consistent)  # fmt: skip
    assert got == want
    json.loads(got)  # and it is strict JSON


finite = st.floats(allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-1e9, 1e9, allow_nan=False),
    st.tuples(finite, finite, finite),
    st.tuples(finite, finite, finite),
    st.lists(st.lists(finite, min_size=3, max_size=3), min_size=3, max_size=3),
)
def test_encode_pose_all_finite_path_is_byte_identical(t, pose, twist, cov):
    """The usual POSE, every value a finite float (rare among the draws above)."""
    want = encode(pose_message(t, pose, twist, np.array(cov), 3, True, ["a"]))
    assert encode_pose(t, pose, twist, cov, 3, True, ("a",)) == want


def test_encode_pose_takes_numpy_scalars():
    cov = np.eye(3).tolist()
    args = (np.float64(1.5), (np.float64(0.1), 0.2, 0.3), (0.0, -0.0, np.inf), cov, np.int64(3))
    want = encode(pose_message(*args, True, ["rear"]))
    assert encode_pose(*args, True, ("rear",)) == want


def test_every_field_lands_where_the_protocol_says():
    """Against the input itself, not the other encoder: distinct values everywhere, so a
    swapped row, column or field cannot pass (both encoders swapping the covariance's x
    and y rows once passed every test but one end-to-end check of cov[0][0])."""
    cov = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
    health = (("front",), ("left",), False)
    for line in (
        encode_pose(12.5, (0.1, 0.2, 0.3), (0.4, 0.5, 0.6), cov, 3, True, ("rear",), *health),
        encode(
            pose_message(
                12.5, (0.1, 0.2, 0.3), (0.4, 0.5, 0.6), np.array(cov), 3, True, ["rear"], *health
            )
        ),  # fmt: skip
    ):
        msg = json.loads(line)
        assert msg == {
            "class": "POSE",
            "t": 12.5,
            "x": 0.1,
            "y": 0.2,
            "theta": 0.3,
            "vx": 0.4,
            "vy": 0.5,
            "omega": 0.6,
            "cov": cov,
            "used": 3,
            "updating": True,
            "missing": ["rear"],
            "excluded": ["front"],
            "suspect": ["left"],
            "consistent": False,
        }
