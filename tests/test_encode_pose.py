"""protocol.encode_pose (the daemon's per-window POSE line) equals encode(pose_message(...))."""

from __future__ import annotations

import json
import math

import cores
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_core import needs_core

from mousedom import core
from mousedom.fusion import scenarios, sim
from mousedom.fusion.tracker import Tracker
from mousedom.service.protocol import _json_names, encode, encode_pose, pose_message

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


# The compiled core's line (csrc/poseline.c) against the Python's, byte for byte: every
# float (NaN, the infinities, -0.0, subnormals: the core declines what is not finite),
# names in any text (JSON escapes them), any count used.
names = st.lists(st.text(max_size=8), max_size=3).map(tuple)


@needs_core
@settings(max_examples=300, deadline=None)
@given(
    st.floats(allow_nan=False, allow_infinity=False),
    st.lists(anyfloat | finite, min_size=15, max_size=15),
    st.integers(-(2**70), 2**70) | st.integers(0, 8),
    st.booleans(),
    names,
    names,
    names,
    st.booleans(),
    st.sampled_from([tuple, list]),
)
def test_the_compiled_pose_line_is_the_pythons(t, v, used, updating, missing, excluded,
                                               suspect, consistent, seq):  # fmt: skip
    args = (t, seq(v[0:3]), seq(v[3:6]), [seq(v[6:9]), seq(v[9:12]), seq(v[12:15])], used,
            updating, missing, excluded, suspect, consistent)  # fmt: skip
    lines = []
    for name in ("c", "python"):
        with cores.using(name):
            lines.append(encode_pose(*args))
    assert lines[0] == lines[1]
    native = core.native.pose_line(round(t, 6), *args[1:6], *map(_json_names, args[6:9]),
                                   consistent)  # fmt: skip
    # it writes every line whose numbers are finite (a core that declines all fails here)
    finite_line = all(math.isfinite(x) for x in (round(t, 6), *v)) and -(2**63) <= used < 2**63
    assert (native is not None) == finite_line
    assert native is None or native == lines[1]


@needs_core
def test_the_daemons_rows_are_written_by_the_compiled_core():
    """What the daemon hands encode_pose (a PoseRow's Python values, a simulated drive's
    windows on the one-window path) is of the types the core takes: it declines none."""
    rig = scenarios.rig("square")
    result = sim.simulate(rig, scenarios.drive(8.0, 5), seed=5)
    tracker = Tracker(scenarios.config(rig), t0=float(result.motion.starts[0]))
    rows = [r for b in sim.run_tracker_live(result, tracker) for r in b.rows()]
    assert len(rows) >= 250
    for r in rows:
        pose, twist = (r.x, r.y, r.theta), (r.vx, r.vy, r.omega)
        line = core.native.pose_line(round(r.t, 6), pose, twist, r.cov, r.used, r.ok, "[]", "[]",
                                     "[]", r.consistent)  # fmt: skip
        assert line is not None
        with cores.using("python"):
            assert line == encode_pose(r.t, pose, twist, r.cov, r.used, r.ok, (), (), (),
                                       r.consistent)  # fmt: skip
