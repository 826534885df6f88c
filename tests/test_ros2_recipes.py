"""The robot_localization and Nav2 recipes of docs/ros2.md against what mousedom publishes
(issue 25): the topics and frames they name are mousedom's defaults, and the EKF reads
exactly the Odometry fields whose covariance says they are observed.  (Neither package has
a wheel on PyPI: the recipes are checked here, not run.)"""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml
from conftest import REPO

from mousedom.config import Ros2Config
from mousedom.fusion.posebatch import PoseRow
from mousedom.service import ros2conv

DOC = (REPO / "docs" / "ros2.md").read_text()
# x, y, z, roll, pitch, yaw, vx, vy, vz, vroll, vpitch, vyaw, ax, ay, az
POSE_AXES, TWIST_AXES = (0, 1, 2, 3, 4, 5), (6, 7, 8, 9, 10, 11)


def _recipe(title: str) -> dict:
    for m in re.finditer(r"^```text\n(.*?)^```", DOC, re.S | re.M):
        if m.group(1).startswith(f"# {title}"):
            return yaml.safe_load(m.group(1))
    raise AssertionError(f"docs/ros2.md has no recipe '# {title}'")


def _odometry(ok: bool = True, vy_var: float = 4e-6) -> dict:
    cov = [[1e-6, 0, 0], [0, 2e-6, 0], [0, 0, 3e-6]]
    qcov = [[1e-8, 0, 0], [0, vy_var * 1e-4, 0], [0, 0, 2e-8]]
    row = PoseRow(1.0, 0.5, 0.2, 0.1, 0.3, 0.0, 0.05, cov, 3, ok, [], [], [], [], True, qcov)
    return ros2conv.odometry(Ros2Config(), ros2conv.stamp(1.0, 0), (0.5, 0.2, 0.1), cov, row,
                             100.0)  # fmt: skip


def test_the_ekf_recipe_names_mousedoms_topic_and_frames():
    ekf = _recipe("ekf.yaml (robot_localization)")["ekf_filter_node"]["ros__parameters"]
    d = Ros2Config()
    assert ekf["odom0"] == d.odom_topic
    assert ekf["odom_frame"] == d.odom_frame and ekf["base_link_frame"] == d.base_frame
    assert ekf["two_d_mode"] is True
    assert len(ekf["odom0_config"]) == 15


def test_the_ekf_reads_exactly_what_the_mice_observe():
    """The twist entries the recipe turns on are those whose variance in a solved window is
    a measurement (below the 1e6 of 'unobserved'); z, roll, pitch and their rates are off,
    and marked unobserved by mousedom so that two_d_mode can ignore them."""
    ekf = _recipe("ekf.yaml (robot_localization)")["ekf_filter_node"]["ros__parameters"]
    chosen = [i for i, on in enumerate(ekf["odom0_config"]) if on]
    odom = _odometry()
    twist = np.array(odom["twist"]["covariance"]).reshape(6, 6).diagonal()
    pose = np.array(odom["pose"]["covariance"]).reshape(6, 6).diagonal()
    observed = [6 + k for k in range(6) if twist[k] < 1e6]
    assert chosen == observed == [6, 7, 11]
    assert [k for k in range(6) if pose[k] < 1e6] == [0, 1, 5]  # the pose alternative
    assert all(pose[k] >= 1e6 and twist[k] >= 1e6 for k in (2, 3, 4))


def test_an_unsolved_window_says_its_twist_is_unknown():
    twist = np.array(_odometry(ok=False)["twist"]["covariance"]).reshape(6, 6).diagonal()
    assert all(v >= 1e6 for v in twist)


@pytest.mark.parametrize("path", [("bt_navigator",), ("velocity_smoother",)])
def test_nav2_reads_mousedoms_odometry(path):
    nav2 = _recipe("nav2_params.yaml (Nav2)")
    node = nav2
    for key in path:
        node = node[key]
    assert node["ros__parameters"]["odom_topic"] == Ros2Config().odom_topic


def test_nav2_costmaps_use_mousedoms_frames():
    nav2 = _recipe("nav2_params.yaml (Nav2)")
    d = Ros2Config()
    local = nav2["local_costmap"]["local_costmap"]["ros__parameters"]
    glob = nav2["global_costmap"]["global_costmap"]["ros__parameters"]
    assert local["global_frame"] == d.odom_frame and local["robot_base_frame"] == d.base_frame
    assert glob["global_frame"] == d.map_frame and glob["robot_base_frame"] == d.base_frame
    bt = nav2["bt_navigator"]["ros__parameters"]
    assert bt["global_frame"] == d.map_frame and bt["robot_base_frame"] == d.base_frame
