"""Config loader: valid rigs load into frozen dataclasses; every mistake names file, line, key."""

from __future__ import annotations

import math
import re

import pytest

from mousedom.config import ConfigError, load_config, parse_config

GOOD = """\
rate_hz: 100
model: lsq
integrator: exact
mice:
  left:
    cpi: 450
    mount: {x: 0.0, y: 0.135, yaw: 0.0}
    replay: left.events
  right:
    cpi: {x: 450, y: 452}
    mount: {x: 0.0, y: -0.135, yaw: 90}
    evdev: {path: /dev/input/by-path/pci-0000:00:14.0-usb-0:2:1.0-event-mouse}
"""


def test_good_config_loads(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(GOOD)
    cfg = load_config(path)
    assert cfg.rate_hz == 100 and cfg.model == "lsq" and cfg.integrator == "exact"
    assert cfg.names == ("left", "right")
    left, right = cfg.mice
    assert (left.cpi_x, left.cpi_y) == (450, 450)
    assert (right.cpi_x, right.cpi_y) == (450, 452)
    assert right.mount.yaw == pytest.approx(math.pi / 2)
    assert left.replay == str(tmp_path / "left.events")
    assert right.evdev.grab is True
    with pytest.raises(AttributeError):
        cfg.rate_hz = 5  # frozen


@pytest.mark.parametrize(
    "old, new, line, key, words",
    [
        ("cpi: 450\n", "cpi: -3\n", 6, "mice.left.cpi", "positive"),
        ("model: lsq", "model: kalman", 2, "model", "lsq, diff-drive, bonarini"),
        ("rate_hz: 100", "rate_hz: fast", 1, "rate_hz", "number"),
        ("yaw: 90}", "yaw: 90, z: 1}", 11, "mice.right.mount.z", "unknown key"),
        ("    replay: left.events\n", "", 5, "mice.left", "nowhere"),
        ("integrator: exact", "integrator: rk4", 3, "integrator", "exact, taylor"),
        # `mount:` left empty was read as (0, 0, 0), where leaving it out is an error
        ("mount: {x: 0.0, y: 0.135, yaw: 0.0}", "mount:", 7, "mice.left.mount", "is empty"),
    ],
)
def test_mistakes_name_file_line_and_key(tmp_path, old, new, line, key, words):
    path = tmp_path / "rig.yaml"
    assert old in GOOD
    path.write_text(GOOD.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}:{line}: {key}:"), msg
    assert words in msg


def test_rank_problem_names_the_mice():
    text = GOOD.replace("y: -0.135, yaw: 90", "y: 0.135, yaw: 90")
    with pytest.raises(ConfigError) as err:
        parse_config(text, "rig.yaml")
    assert "left, right" in str(err.value) and "one point" in str(err.value)


def test_single_mouse_needs_diff_drive():
    one = "model: lsq\nmice:\n  m: {cpi: 400, mount: {x: 0.1, y: 0}, replay: a}\n"
    with pytest.raises(ConfigError, match="diff-drive"):
        parse_config(one, "one.yaml")
    cfg = parse_config(one.replace("lsq", "diff-drive"), "one.yaml")
    assert cfg.model == "diff-drive"
    on_axle = one.replace("lsq", "diff-drive").replace("x: 0.1", "x: 0.0")
    with pytest.raises(ConfigError, match="cannot see rotation"):
        parse_config(on_axle, "one.yaml")


def test_invalid_yaml_names_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("rate_hz: 100\nmice: [\n  left: {\n")
    with pytest.raises(ConfigError, match=rf"{path}:\d+: invalid YAML"):
        load_config(path)


def test_missing_file_and_not_utf8(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yaml")
    p = tmp_path / "bin.yaml"
    p.write_bytes(b"rate_hz: 1\n\xff\xfe")
    with pytest.raises(ConfigError, match="byte offset 11"):
        load_config(p)


def test_calibration_file_overrides(tmp_path):
    (tmp_path / "rig.yaml").write_text(GOOD + "calibration: rig.calib.yaml\n")
    cfg = load_config(tmp_path / "rig.yaml")  # file absent: not calibrated yet, fine
    assert cfg.mouse("left").cpi_x == 450
    (tmp_path / "rig.calib.yaml").write_text(
        "mice:\n  left:\n    cpi: {x: 455.5, y: 456.5}\n    mount: {x: 0.01, y: 0.14, yaw: 1}\n"
    )
    cfg = load_config(tmp_path / "rig.yaml")
    left = cfg.mouse("left")
    assert (left.cpi_x, left.cpi_y) == (455.5, 456.5)
    assert (left.mount.x, left.mount.y) == (0.01, 0.14)
    assert left.mount.yaw == pytest.approx(math.radians(1))
    (tmp_path / "rig.calib.yaml").write_text("mice:\n  middle:\n    cpi: 400\n")
    with pytest.raises(ConfigError, match=r"rig.calib.yaml:2: mice.middle: calibration for"):
        load_config(tmp_path / "rig.yaml")


def test_cli_reports_config_error_without_traceback(tmp_path):
    from conftest import run_mousedom

    path = tmp_path / "rig.yaml"
    path.write_text(GOOD.replace("cpi: 450\n", "cpi: zero\n", 1))
    # Any subcommand that loads a config will do; `check-config` is the lead's.
    proc = run_mousedom("check-config", "--config", str(path))
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert f"{path}:6: mice.left.cpi: must be a number" in proc.stderr


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=300))
def test_any_text_is_a_config_or_a_config_error(text):
    """Garbage never escapes as another exception (which the CLI would show as a traceback)."""
    try:
        parse_config(text, "fuzz.yaml")
    except ConfigError as e:
        assert str(e).startswith("fuzz.yaml")


@settings(max_examples=200, deadline=None)
@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
        lambda kids: st.lists(kids, max_size=3) | st.dictionaries(st.text(max_size=8), kids),
        max_leaves=12,
    )
)
def test_any_yaml_value_under_a_mouse_is_handled(value):
    import yaml

    doc = {"mice": {"a": value, "b": {"cpi": 400, "mount": {"x": 0, "y": 1}, "replay": "x"}}}
    try:
        cfg = parse_config(yaml.safe_dump(doc), "fuzz.yaml")
    except ConfigError as e:
        # One line, naming the file and the mouse it is about (a parser that accepts
        # everything, or says nothing useful, fails here).
        lines = str(e).splitlines()
        assert lines and all(ln.startswith("fuzz.yaml:") for ln in lines), lines
        assert all("mice" in ln for ln in lines), lines
        return
    # Accepted: then mouse a is a complete mouse, as the value said.
    a = cfg.mouse("a")
    assert isinstance(value, dict) and a.cpi_x > 0 and a.cpi_y > 0
    assert (a.mount.x, a.mount.y) == (float(value["mount"]["x"]), float(value["mount"]["y"]))


def test_serial_mouse_report_rate_follows_k():
    text = "model: diff-drive\nmice:\n  adns:\n    cpi: 1600\n    mount: {x: 0.2, y: 0}\n"
    cfg = parse_config(text + "    serial: {port: 'loop://', k: 12}\n", "s.yaml")
    assert cfg.mouse("adns").report_hz == pytest.approx(1e6 / (12 * 1250))
    cfg = parse_config(text + "    serial: {port: 'loop://'}\n    report_hz: 50\n", "s.yaml")
    assert cfg.mouse("adns").report_hz == 50


def test_binary_calibration_file_is_a_config_error(tmp_path):
    (tmp_path / "rig.yaml").write_text(GOOD + "calibration: rig.calib.yaml\n")
    (tmp_path / "rig.calib.yaml").write_bytes(b"mice:\n\x00\xff\xfe")
    with pytest.raises(ConfigError, match=r"rig.calib.yaml: byte offset 7: not UTF-8"):
        load_config(tmp_path / "rig.yaml")


def test_a_key_given_twice_is_an_error():
    text = GOOD + "  left:\n    cpi: 800\n    mount: {x: 0, y: 0}\n    replay: x\n"
    with pytest.raises(
        ConfigError, match=r"rig.yaml:13: mice.left: given twice \(first on line 5\)"
    ):
        parse_config(text, "rig.yaml")
    with pytest.raises(ConfigError, match=r"rig.yaml:4: rate_hz: given twice \(first on line 1\)"):
        parse_config(GOOD.replace("mice:", "rate_hz: 50\nmice:"), "rig.yaml")


@pytest.mark.parametrize("wheels", [
    "{radius: -0.05, track: 0.3, ticks_per_rev: 360}",
    "{radius: 0, radius_left: 0.05, radius_right: 0.05, track: 0.3, ticks_per_rev: 360}",
])  # fmt: skip
def test_a_wheel_radius_that_is_no_radius_names_the_key_written(wheels):
    """wheels.radius -0.05 was refused as 'wheels.radius_left' (a key nobody wrote), and
    accepted without a word where both wheels' own radii stood beside it."""
    text = GOOD.replace("integrator: exact\n", f"integrator: exact\nwheels: {wheels}\n")
    with pytest.raises(ConfigError) as err:
        parse_config(text, "rig.yaml", need_sources=False)
    assert str(err.value).startswith("rig.yaml:4: wheels.radius: must be a positive number")


def test_a_merge_key_may_be_overridden_as_yaml_says():
    """``b: {<<: *m, cpi: 900}``: b takes m's keys but its own cpi.  The keys were indexed
    after PyYAML had folded the merged ones in, and cpi looked given twice."""
    text = (
        "rate_hz: 100\nmice:\n"
        "  a: &m {cpi: 800, mount: {x: 0.1, y: 0.0, yaw: 0}, replay: a.events}\n"
        "  b: {<<: *m, cpi: 900, mount: {x: -0.1, y: 0.1, yaw: 0}}\n"
        "  c:\n    <<: *m\n    mount: {x: -0.1, y: -0.1, yaw: 0}\n"
    )
    cfg = parse_config(text, "rig.yaml")
    assert [(m.name, m.cpi_x, m.mount.x) for m in cfg.mice] == [
        ("a", 800, 0.1),
        ("b", 900, -0.1),
        ("c", 800, -0.1),
    ]
    # a key given twice among a mapping's own keys is still an error, with its line
    with pytest.raises(ConfigError, match=r"rig.yaml:4: mice.b.cpi: given twice"):
        parse_config(text.replace("cpi: 900,", "cpi: 900, cpi: 901,"), "rig.yaml")


@pytest.mark.parametrize("key, words", [
    ("true", "mice.true: a mouse's name must be text, got True: quote it"),
    ("null", "mice.null: a mouse's name must be text, got None: quote it"),
    ("7", "mice.7: a mouse's name must be text, got 7: quote it"),
    ('""', "a mouse's name is empty"),
    ('"ri\\nght"', "a mouse's name may not hold control characters"),
    ('"ri\\tght"', "a mouse's name may not hold control characters"),
])  # fmt: skip
def test_a_mouse_name_yaml_reads_as_no_text_is_refused(key, words):
    """A key YAML reads as a boolean, null or number was the mouse "True", "None", "7";
    an empty one, a mouse with no name in any column or topic."""
    text = GOOD.replace("  right:", f"  {key}:")
    with pytest.raises(ConfigError) as err:
        parse_config(text, "rig.yaml")
    assert words in str(err.value) and "rig.yaml:9:" in str(err.value), str(err.value)


def test_an_empty_socket_path_is_refused_and_a_yaw_beyond_a_turn_is_warned_of():
    with pytest.raises(ConfigError, match=r"rig.yaml:\d+: server.socket: is empty"):
        parse_config(GOOD + 'server: {socket: ""}\n', "rig.yaml")
    cfg = parse_config(GOOD.replace("yaw: 90}", "yaw: 1e30}"), "rig.yaml")
    assert any("mice.right.mount.yaw: 1e+30 degrees is more than a turn" in w
               for w in cfg.warnings), cfg.warnings  # fmt: skip
    assert not parse_config(GOOD, "rig.yaml").warnings


_ONE = "rate_hz: 50\nmodel: lsq\nmice:\n  a: {{{a}}}\n  b: {{cpi: 800, mount: {{x: -0.1, y: 0}}}}\n"


@pytest.mark.parametrize("a,said", [
    ("cpi: 1e-300, mount: {x: 0.1, y: 0}", "mice.a.cpi: must be between 1 and 1e+06"),
    ("cpi: {x: 800, y: 2e6}, mount: {x: 0.1, y: 0}", "mice.a.cpi.y: must be between 1 and 1e+06"),
    ("cpi: 800, mount: {x: 1e308, y: 0}", "mice.a.mount.x: must be between -1000 and 1000"),
    ("cpi: 800, mount: {x: 0.1, y: -2000}", "mice.a.mount.y: must be between -1000 and 1000"),
    ("cpi: 800, mount: {x: 0.1, y: 0}, sigma: 1e-9", "mice.a.sigma: must be between 0.01 and"),
    ("cpi: 800, mount: {x: 0.1, y: 0}, sigma: 2e4", "mice.a.sigma: must be between 0.01 and"),
])  # fmt: skip
def test_values_no_rig_has_are_refused_naming_the_line(a, said):
    """A CPI of 1e-300 passed (a warning) and overflowed replay (a traceback); a mount of
    1e308 said the mice were all at one point; a sigma 1e9 times smaller than another
    mouse's passed check-config and killed the daemon at its reload (singular weights)."""
    with pytest.raises(ConfigError, match=re.escape("rig.yaml:4: " + said)):
        parse_config(_ONE.format(a=a), "rig.yaml", need_sources=False)


@pytest.mark.parametrize("sa,sb", [(0.01, 1e4), (1e4, 0.01), (0.01, 0.01), (1e4, 1e4)])
def test_sigmas_at_the_limits_make_a_fusion_that_runs(sa, sb):
    """The limits are what the arithmetic takes: the most different sigmas allowed solve
    (the weights' ratio 1e12; 1e16 was singular) on the demo's drive, and every pose is
    finite."""
    import numpy as np

    from mousedom.capture import assign
    from mousedom.capture.replay import Replay
    from mousedom.demo import DEMO_CONFIG

    text = open(DEMO_CONFIG).read()
    first = text.index("sigma: 1.0")
    text = text[:first] + f"sigma: {sa}" + text[first + 10 :]
    second = text.index("sigma: 1.0")
    text = text[:second] + f"sigma: {sb}" + text[second + 10 :]
    config = parse_config(text, str(DEMO_CONFIG), need_sources=False)
    assert [m.sigma for m in config.mice][:2] == [sa, sb]
    batches = []
    Replay(config, assign(config, [])).run(batches.append)
    x = np.concatenate([b.x for b in batches])
    assert len(x) > 100 and np.all(np.isfinite(x))
    assert all(np.all(np.isfinite(b.cov)) for b in batches)


_TWO = "rate_hz: 50\nmodel: lsq\nmice:\n  a: {cpi: 800, mount: {x: 0.1, y: 0}}\n" \
       "  b: {cpi: 800, mount: {x: -0.1, y: 0}}\n"  # fmt: skip


@pytest.mark.parametrize("tail,said", [
    ("server: {socket: /run/" + "s" * 104 + "}", "server.socket: is 109 bytes, longer than"),
    ("server: {control_uids: [true]}", "server.control_uids: must be a list of numeric ids"),
    ("server: {control_gids: [0, yes]}", "server.control_gids: must be a list of numeric ids"),
    ("server: {control_uids: [4294967295]}", "server.control_uids: must be a list of numeric"),
    ("calibration: ''", "calibration: is empty: a file name, or leave the key out"),
])  # fmt: skip
def test_what_the_daemon_would_refuse_or_misread_check_config_refuses(tail, said):
    """check-config said 0 ("it would run") for a socket path run refuses as too long for
    a Unix address; a YAML true in control_uids gave uid 1 control (1 in (True,)); an
    empty calibration was read as none without a word."""
    with pytest.raises(ConfigError, match=re.escape("rig.yaml:6: " + said)):
        parse_config(_TWO + tail + "\n", "rig.yaml", need_sources=False)


def test_a_socket_path_at_the_limit_and_ids_at_theirs_are_taken():
    text = _TWO + "server: {socket: /run/" + "s" * 102 + ", control_uids: [0, 4294967294]}\n"
    c = parse_config(text, "rig.yaml", need_sources=False)
    assert len(c.server.socket) == 107 and c.server.control_uids == (0, 4294967294)


@pytest.mark.parametrize("mice", [2, 3, 9])
def test_a_queue_too_short_for_a_status_answer_is_refused(mice):
    """``server.queue_lines`` must hold a status answer and what goes ahead of it, twice
    over (the server answers while the queue is under half full): 4 x (sensors + 2).
    Shorter, the config was taken and the daemon never answered a command (1 line) or
    dropped a client that read as fast as it could ("queue full", 2-4 lines)."""
    from mousedom.config.load import queue_lines_needed

    names = [f"m{k}" for k in range(mice)]
    text = "rate_hz: 100\nmodel: lsq\nmice:\n" + "".join(
        f"  {n}:\n    cpi: 800\n    mount: {{x: {0.1 * (k % 3)}, y: {0.05 * k}, yaw: 0}}\n"
        f"    replay: {n}.events\n"
        for k, n in enumerate(names)
    )
    least = queue_lines_needed(mice)
    assert least == 4 * (mice + 2)
    for lines in (1, 2, least - 1):
        with pytest.raises(ConfigError) as err:
            parse_config(text + f"server: {{queue_lines: {lines}}}\n", "rig.yaml")
        message = str(err.value)
        assert re.search(r"rig\.yaml:\d+: server\.queue_lines: ", message), message
        assert f"at least {least}" in message, message
    cfg = parse_config(text + f"server: {{queue_lines: {least}}}\n", "rig.yaml")
    assert cfg.server.queue_lines == least
