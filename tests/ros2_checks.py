"""Checks shared by the tests that receive mousedom's ROS 2 messages (a Cyclone subscriber
built from ROS 2's definitions, tests/test_ros2.py; a real rclpy node,
tests/test_ros2_interop.py): messages as nested dicts, POSE lines as the socket sends them."""

from __future__ import annotations

import math

import numpy as np
import pytest


def yaw(q: dict) -> float:
    return math.atan2(2 * (q["w"] * q["z"] + q["x"] * q["y"]), 1 - 2 * (q["y"] ** 2 + q["z"] ** 2))


def stamp_of(msg: dict) -> float:
    st = msg["header"]["stamp"]
    return round(st["sec"] + st["nanosec"] * 1e-9, 6)


def match_odometry(poses: list[dict], odoms: list[dict]) -> list[tuple[dict, dict]]:
    """(POSE, Odometry) pairs of one window each (the stamps are the POSE times, as with
    ``stamps: monotonic``), each checked field by field: frames, pose, heading, twist and
    the pose covariance's x, y, yaw block."""
    by_t = {stamp_of(o): o for o in odoms}
    matched = [(p, by_t[round(p["t"], 6)]) for p in poses if round(p["t"], 6) in by_t]
    for p, o in matched:
        assert o["header"]["frame_id"] == "odom" and o["child_frame_id"] == "base_link"
        pos = o["pose"]["pose"]["position"]
        assert (pos["x"], pos["y"]) == pytest.approx((p["x"], p["y"]), abs=1e-9)
        assert yaw(o["pose"]["pose"]["orientation"]) == pytest.approx(p["theta"], abs=1e-9)
        tw = o["twist"]["twist"]
        assert (tw["linear"]["x"], tw["angular"]["z"]) == pytest.approx(
            (p["vx"], p["omega"]), abs=1e-9)  # fmt: skip
        cov = np.array(o["pose"]["covariance"]).reshape(6, 6)
        np.testing.assert_allclose(cov[np.ix_([0, 1, 5], [0, 1, 5])], p["cov"],
                                   rtol=1e-9, atol=1e-15)  # fmt: skip
    return matched
