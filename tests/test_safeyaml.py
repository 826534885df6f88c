"""Bounded YAML (mousedom.safeyaml): what it refuses, with the line, and what it accepts."""

from __future__ import annotations

import pytest
import yaml

from mousedom import safeyaml
from mousedom.config import ConfigError, parse_config


def _bomb(levels: int) -> str:
    text = "a0: &a0 [x, x, x, x, x, x, x, x, x]\n"
    for i in range(1, levels + 1):
        text += f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n"
    return text


@pytest.mark.parametrize(
    "text, words, line",
    [
        (_bomb(8), "aliases expand to more than", 6),  # a5 stands for 9**6 nodes
        ("a: &x [1, *x]\n", "a cycle", 1),
        ("x: " + "[" * 40 + "]" * 40 + "\n", "nested deeper than 32", 1),
        ("a: 1\nb: " + "7" * 500 + "\n", "an integer of 500 characters", 2),
        ("a: 1\nb: \x05\n", "not allowed in YAML", 2),
    ],
)
def test_what_is_refused_names_its_line(text, words, line):
    with pytest.raises(yaml.MarkedYAMLError) as info:
        safeyaml.load(text)
    e = info.value
    assert words in e.problem and e.problem_mark.line + 1 == line


def test_a_small_alias_is_fine_and_expands():
    assert safeyaml.load("a: &m {x: 1}\nb: *m\n") == {"a": {"x": 1}, "b": {"x": 1}}


def test_trailing_tabs_are_accepted_as_libyaml_does():
    assert safeyaml.load("a: 1\t\nb: [1, 2]\t \n") == {"a": 1, "b": [1, 2]}


def test_a_config_error_names_file_and_line():
    with pytest.raises(ConfigError, match=r"rig.yaml:7: invalid YAML: aliases expand"):
        parse_config("rate_hz: 100\n" + _bomb(8).replace("a0:", "x0:", 1), "rig.yaml")


def test_size_limit(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * (safeyaml.MAX_BYTES + 10) + b"\n")
    with pytest.raises(OSError, match="too large"):
        safeyaml.read_text(big)
