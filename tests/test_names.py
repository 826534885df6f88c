"""A mouse's name where it names something else (mousedom.config.names): the replay CSV's
column suffixes and ROS 2 names (the counts topics and TF frames, live and in MCAP).

A config may call a mouse "front-left" or "2nd"; ROS 2 names take neither (tokens of
letters, digits and single underscores, not starting with a digit), so /mousedom/2nd/counts
was a topic no ROS 2 node could subscribe to.  Two mice whose names became the same column
suffix shared their CSV columns without a word."""

from __future__ import annotations

import dataclasses
import re

import pytest
from capture_helpers import evemu_captures
from conftest import run_mousedom
from hypothesis import given
from hypothesis import strategies as st

from mousedom.config import ConfigError, parse_config
from mousedom.config.names import column_suffix, ros_token
from mousedom.fusion import sim

# design.ros2.org, "Topic and Service names": a token is letters, digits and underscores,
# not starting with a digit, with no repeated underscore; none ends with one either.
ROS_TOKEN = re.compile(r"[A-Za-z][A-Za-z0-9]*(_[A-Za-z0-9]+)*")


@given(st.text(min_size=1, max_size=40))
def test_any_name_becomes_a_ros_token_and_a_csv_suffix(name):
    assert ROS_TOKEN.fullmatch(ros_token(name)), ros_token(name)
    suffix = column_suffix(name)
    assert not set(suffix) & set(',"\r\n') and len(suffix) == len(name)


@pytest.mark.parametrize("name", ["front", "left_2", "m0", "RearRight"])
def test_a_name_that_is_a_token_is_kept(name):
    assert ros_token(name) == name == column_suffix(name)


@pytest.mark.parametrize(
    "name, token", [("front-left", "front_left"), ("2nd", "m_2nd"), ("Mouse A", "Mouse_A"),
                    ("--", "m"), ("_x__y_", "x_y"), ("é", "m")],
)  # fmt: skip
def test_other_names_become_tokens(name, token):
    assert ros_token(name) == token


def _config(names: list[str]) -> str:
    mounts = [(0.1, 0.0), (-0.05, 0.08), (-0.05, -0.08)]
    lines = ["rate_hz: 100", "model: lsq", "mice:"]
    for n, (x, y) in zip(names, mounts, strict=False):
        lines.append(f"  {n!r}: {{cpi: 1000, mount: {{x: {x}, y: {y}}}}}")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    "names, said",
    [(["a,b", "a_b", "c"], "the replay CSV's column suffix 'a_b'"),
     (["front-left", "front_left", "c"], "the ROS 2 name 'front_left'"),
     (["2nd", "m_2nd", "c"], "the ROS 2 name 'm_2nd'")],
)  # fmt: skip
def test_mice_whose_names_become_the_same_are_refused(names, said):
    with pytest.raises(ConfigError) as e:
        parse_config(_config(names), "rig.yaml", need_sources=False)
    assert said in str(e.value) and "rig.yaml" in str(e.value)


def test_replay_names_topics_and_frames_by_the_tokens(tmp_path):
    """Replayed into MCAP, a rig with mice "front-left" and "2nd": their counts topics and
    frames are the tokens, and every report of each is on its topic; the CSV's columns
    keep the names (a hyphen is fine in a CSV)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    names = {"front": "front-left", "left": "2nd", "right": "right"}
    base = sim.three_mouse_rig()
    rig = dataclasses.replace(
        base, mice=tuple(dataclasses.replace(m, name=names[m.name]) for m in base.mice)
    )
    config = tmp_path / "rig.yaml"
    config.write_text(sim.rig_yaml(rig).replace("front-left:", "'front-left':")
                      .replace("2nd:", "'2nd':"))  # fmt: skip
    res = sim.simulate(rig, sim.umbmark_square(cw=True, side=0.3, speed=0.3, turn_rate=1.0))
    args = evemu_captures(tmp_path, res)
    out = tmp_path / "run.mcap"
    csv = tmp_path / "run.csv"
    proc = run_mousedom("replay", "--config", str(config), *args, "-o", str(csv),
                        "--mcap", str(out))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    header = csv.read_text().splitlines()[0].split(",")
    assert "state_front-left" in header and "state_2nd" in header
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        topics = {c.topic for c in reader.get_summary().channels.values()}
        frames = {}
        for _, channel, _, m in reader.iter_decoded_messages():
            if channel.topic.endswith("/counts"):
                frames.setdefault(channel.topic, set()).add(m.header.frame_id)
    for topic in topics:
        assert all(ROS_TOKEN.fullmatch(t) for t in topic.strip("/").split("/")), topic
    assert frames == {
        "/mousedom/front_left/counts": {"front_left_mouse"},
        "/mousedom/m_2nd/counts": {"m_2nd_mouse"},
        "/mousedom/right/counts": {"right_mouse"},
    }
