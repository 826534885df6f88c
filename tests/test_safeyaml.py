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
        (_bomb(8), "nodes (aliases expanded)", 6),  # a5 stands for 9**6 nodes
        ("a: &x [1, *x]\n", "a cycle", 1),
        ("x: " + "[" * 40 + "]" * 40 + "\n", "nested deeper than 32", 1),
        ("a: 1\nb: " + "7" * 500 + "\n", "an integer of 500 characters", 2),
        ("a: 1\nb: \x05\n", "not allowed in YAML", 2),
        # YAML 1.1 reads these as numbers (90, 100, 5400.5), YAML 1.2 as text: a yaw of
        # 1:30 was taken as 90 degrees without a word
        ("a: 1\nyaw: 1:30\n", "a base-60 number is ambiguous", 2),
        ("rate: 1_00\n", "digit separators is ambiguous", 1),
        ("x:\n  y: 1:30:00.5\n", "a base-60 number", 2),
        ("x: 1_0.5\n", "digit separators", 1),
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
    # a config's limit is 10,000 nodes (safeyaml.CONFIG_MAX_NODES): a4 stands for 9**5
    with pytest.raises(ConfigError, match=r"rig.yaml:6: invalid YAML: more than 10000 nodes"):
        parse_config("rate_hz: 100\n" + _bomb(8).replace("a0:", "x0:", 1), "rig.yaml")


def test_a_config_past_its_limits_is_refused_before_a_long_parse(tmp_path):
    """A config of 199,000 short items (4.2 MB, within the old 4 MiB and 200,000 nodes)
    stalled a reload 4.4 s in the pure-Python composer; a config's limits are 256 KiB and
    10,000 nodes, refused before the composer runs (about 20 us a node: 0.2 s at the
    limit)."""
    from mousedom.config import load_config

    rig = "rate_hz: 50\nmodel: lsq\nmice:\n  a: {cpi: 800, mount: {x: 0.1, y: 0}}\n"
    big = tmp_path / "big.yaml"
    big.write_text(rig + "# " + "x" * (256 << 10) + "\n")
    with pytest.raises(ConfigError, match="big.yaml: .*too large"):
        load_config(big, need_sources=False)
    many = tmp_path / "many.yaml"
    many.write_text(rig + "junk: [" + ",".join(["ab"] * 10_000) + "]\n")
    with pytest.raises(ConfigError, match=r"many.yaml:5: invalid YAML: more than 10000 nodes"):
        load_config(many, need_sources=False)
    at = tmp_path / "at.yaml"
    at.write_text(rig + "junk: [" + ",".join(["ab"] * 9_980) + "]\n")
    with pytest.raises(ConfigError, match="at.yaml:5: junk: unknown key"):
        load_config(at, need_sources=False)


def test_size_limit(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * (safeyaml.MAX_BYTES + 10) + b"\n")
    with pytest.raises(OSError, match="too large"):
        safeyaml.read_text(big)


def test_text_that_looks_like_those_numbers_is_still_text():
    assert safeyaml.load('a: "1:30"\nb: 1_x\nc: "1_00"\nd: 12:30x\n') == {
        "a": "1:30",
        "b": "1_x",
        "c": "1_00",
        "d": "12:30x",
    }


@pytest.mark.parametrize("mantissa", ["1", "16", "1.6", "1.", ".16", "0.0016"])
@pytest.mark.parametrize("exponent", ["3", "+3", "-3", "03"])
@pytest.mark.parametrize("e", ["e", "E"])
@pytest.mark.parametrize("sign", ["", "-", "+"])
def test_every_exponent_form_is_the_number_python_reads(mantissa, exponent, e, sign):
    """YAML 1.1 (PyYAML's) needs a dot and a sign after the e (1.6e3 was the text
    "1.6e3", and `cpi: 1.6e3` was refused as not a number); YAML 1.2, Python and people
    read every such form as one number."""
    text = f"{sign}{mantissa}{e}{exponent}"
    assert safeyaml.load(f"x: {text}\n") == {"x": float(text)}
