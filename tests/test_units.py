"""Counts -> body-frame metres: the evdev axis convention, CPI per axis, mount yaw, flip."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mousedom.config import Mount, MouseConfig
from mousedom.fusion.units import INCH, body_to_counts, counts_to_body


def mouse(yaw_deg=0.0, cpi=(400.0, 800.0), flip=False) -> MouseConfig:
    return MouseConfig("m", cpi[0], cpi[1], Mount(0.1, 0.2, math.radians(yaw_deg)), flip=flip)


def test_evdev_axes_to_mouse_frame():
    m = mouse()
    # REL_Y negative = moved away from the user = forward (+x body when yaw 0).
    assert counts_to_body(m, 0, -800) == pytest.approx((INCH, 0.0))
    # REL_X positive = moved to its right = -y body.
    assert counts_to_body(m, 400, 0) == pytest.approx((0.0, -INCH))


def test_yaw_rotates_into_body():
    m = mouse(yaw_deg=90)  # mouse forward points to body left
    assert counts_to_body(m, 0, -800) == pytest.approx((0.0, INCH))
    assert counts_to_body(m, 400, 0) == pytest.approx((INCH, 0.0))


def test_flip_mirrors_the_lateral_axis():
    assert counts_to_body(mouse(flip=True), 400, 0) == pytest.approx((0.0, INCH))
    assert counts_to_body(mouse(flip=True), 0, -800) == pytest.approx((INCH, 0.0))


@given(
    st.floats(-180, 180),
    st.floats(100, 8000),
    st.floats(100, 8000),
    st.booleans(),
    st.floats(-1e4, 1e4),
    st.floats(-1e4, 1e4),
)
def test_round_trip(yaw, cx, cy, flip, dx, dy):
    m = mouse(yaw, (cx, cy), flip)
    bx, by = counts_to_body(m, dx, dy)
    assert np.allclose(body_to_counts(m, bx, by), (dx, dy), atol=1e-6)
    # A rotation and axis scaling: the length in metres is the length in inches of counts.
    assert math.hypot(bx, by) == pytest.approx(math.hypot(dx / cx, dy / cy) * INCH, abs=1e-12)
