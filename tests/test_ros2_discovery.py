"""The Cyclone DDS configuration of mousedom's ROS 2 output (issue 25): what makes a ROS 2
node on Fast DDS (ROS 2's default middleware) receive our topics, and ROS 2's discovery
variables as rmw reads them.  The real exchange with an rclpy node is in
tests/test_ros2_interop.py."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from mousedom.service.ros2out import DDS_COMPAT, dds_config


def _fragments(uri: str) -> list[ET.Element]:
    return [ET.fromstring(part) for part in uri.split(",") if part.startswith("<")]


def test_fast_dds_type_information_is_ignored_by_default():
    """Fast DDS (RTPS vendor 1.15) announces TypeObjects whose collection element flags
    Cyclone refuses, so Cyclone never matched a ROS 2 reader of any type holding an array
    or a sequence (Odometry, DiagnosticArray, TFMessage); matching by name, as Fast DDS
    itself does with other vendors' types, is what works."""
    cfg = dds_config({})
    assert cfg == DDS_COMPAT
    (root,) = _fragments(cfg)
    assert root.find("./Domain/Compatibility/IgnoreTypeInformation").text == "1.15"


def test_a_users_cyclonedds_uri_comes_last_and_may_override():
    cfg = dds_config({"CYCLONEDDS_URI": "file:///etc/cyclone.xml"})
    assert cfg.endswith(",file:///etc/cyclone.xml") and DDS_COMPAT in cfg


def _discovery(env: dict[str, str]) -> tuple[str | None, list[str]]:
    frags = _fragments(dds_config(env))
    multicast = [f.find("./Domain/General/AllowMulticast") for f in frags]
    peers = [p.get("address") for f in frags for p in f.iterfind("./Domain/Discovery/Peers/Peer")]
    allowed = next((m.text for m in multicast if m is not None), None)
    return allowed, peers


def test_ros_discovery_variables_as_rmw_reads_them():
    assert _discovery({}) == (None, [])  # SUBNET, the default: multicast as usual
    assert _discovery({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}) == (None, [])
    assert _discovery({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}) == ("false", ["localhost"])
    assert _discovery({"ROS_AUTOMATIC_DISCOVERY_RANGE": "localhost "}) == ("false", ["localhost"])
    assert _discovery({"ROS_LOCALHOST_ONLY": "1"}) == ("false", ["localhost"])
    # The range, when set, wins over the older variable.
    assert _discovery({"ROS_LOCALHOST_ONLY": "1", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}) == (
        None,
        [],
    )
    assert _discovery({"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}) == ("false", [])
    assert _discovery({"ROS_STATIC_PEERS": "10.0.0.2; robot.local;"}) == (
        None,
        ["10.0.0.2", "robot.local"],
    )
    assert _discovery(
        {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_STATIC_PEERS": "10.0.0.2"}
    ) == ("false", ["localhost", "10.0.0.2"])


def test_peer_names_cannot_break_the_xml():
    allowed, peers = _discovery({"ROS_STATIC_PEERS": 'a"/><x y="1'})
    assert peers == ['a"/><x y="1']


def test_localhost_announces_loopback_locators_only():
    """On a host with a network, Cyclone would announce the locators of its chosen
    interface; peers limited to this host look on 127.0.0.1 only."""

    def interfaces(env):
        return [i.get("address") for f in _fragments(dds_config(env))
                for i in f.iterfind("./Domain/General/Interfaces/NetworkInterface")]  # fmt: skip

    assert interfaces({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}) == ["127.0.0.1"]
    assert interfaces({"ROS_LOCALHOST_ONLY": "1"}) == ["127.0.0.1"]
    assert interfaces({}) == [] and interfaces({"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}) == []
