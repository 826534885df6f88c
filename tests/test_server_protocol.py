"""The pure half of the socket protocol: line framing, command parsing, message encoding."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mousedom.service.protocol import (
    COMMANDS,
    LineBuffer,
    ProtocolError,
    TooLong,
    encode,
    error_message,
    parse_command,
    pose_message,
    source_message,
    version_message,
)


def test_lines_split_across_reads_are_joined():
    buf = LineBuffer(64)
    assert buf.feed(b'{"cmd": "sta') == []
    assert buf.feed(b'tus"}\n{"cmd"') == [b'{"cmd": "status"}']
    assert buf.feed(b': "reset"}\r\n') == [b'{"cmd": "reset"}']


def test_long_line_is_reported_once_and_skipped_without_buffering_it():
    buf = LineBuffer(10)
    assert buf.feed(b"x" * 8) == []
    assert buf.feed(b"y" * 1000) == []
    assert len(buf._buf) <= 10  # never holds more than the limit
    out = buf.feed(b"zz\nok\n")
    assert len(out) == 2
    assert isinstance(out[0], TooLong) and out[0].size == 1010
    assert out[1] == b"ok"


def test_line_of_exactly_the_limit_passes():
    out = LineBuffer(5).feed(b"12345\n123456\n")
    assert out[0] == b"12345"
    assert isinstance(out[1], TooLong) and out[1].size == 6


@given(st.lists(st.binary(max_size=40), max_size=20), st.integers(1, 30))
def test_framing_never_loses_or_invents_short_lines(chunks, limit):
    """Whatever the chunking, the lines out are the newline-split input (short ones verbatim)."""
    data = b"".join(chunks)
    buf = LineBuffer(limit)
    out = []
    for c in chunks:
        out += buf.feed(c)
    expected = data.split(b"\n")[:-1]  # the tail without a newline is still pending
    assert len(out) == len(expected)
    for got, want in zip(out, expected, strict=True):
        if len(want) > limit:
            assert isinstance(got, TooLong) and got.size == len(want)
        else:
            assert got == want.rstrip(b"\r")


def test_valid_commands():
    c = parse_command(b'{"cmd": "fix", "x": 1.5, "theta": -0.25, "id": 7}')
    assert (c.name, c.args, c.id) == ("fix", {"x": 1.5, "theta": -0.25}, 7)
    assert parse_command(b'{"cmd":"reset"}').args == {}
    assert parse_command(b'{"cmd":"reset","x":1,"y":2,"theta":3}').args == {
        "x": 1.0,
        "y": 2.0,
        "theta": 3.0,
    }
    assert parse_command(b'{"cmd":"status"}').name == "status"
    assert parse_command(b'{"cmd":"rate","hz":0}').args == {"hz": 0.0}


@pytest.mark.parametrize(
    "line, words",
    [
        (b"{not json", "invalid JSON at column 2"),
        (b"[1, 2]", "JSON object"),
        (b'{"x": 1}', 'missing "cmd"'),
        (b'{"cmd": "explode"}', "unknown command 'explode'"),
        (b'{"cmd": "fix"}', "at least one of x, y, theta"),
        (b'{"cmd": "fix", "z": 1}', "unknown key 'z'"),
        (b'{"cmd": "fix", "x": "1"}', "x must be a number"),
        (b'{"cmd": "fix", "x": true}', "x must be a number"),
        (b'{"cmd": "fix", "x": NaN}', "invalid JSON"),
        (b'{"cmd": "fix", "x": 1e999}', "x must be finite"),
        (b'{"cmd": "rate"}', "needs hz"),
        (b'{"cmd": "rate", "hz": -1}', "between 0 and"),
        (b'{"cmd": "status", "verbose": 1}', "takes no arguments"),
        (b'{"cmd": "status"}\xff', "byte offset 17: not UTF-8"),
        # json.loads keeps a key's last value: a "status" that was a reset, answered OK
        (b'{"cmd": "status", "cmd": "reset"}', "key 'cmd' given twice"),
        (b'{"cmd": "reset", "x": 1, "x": 2}', "key 'x' given twice"),
        (b'{"cmd": "status", "id": {"a": 1, "a": 2}}', "key 'a' given twice"),
        # valid JSON text, but no character: echoed, the reply was a line strict parsers refuse
        (b'{"cmd": "status", "id": "\\ud800"}', "no lone surrogate"),
    ],
)
def test_bad_commands_say_what_is_wrong(line, words):
    with pytest.raises(ProtocolError, match=None) as info:
        parse_command(line)
    assert words in str(info.value)


@given(st.binary(max_size=200))
def test_any_bytes_parse_or_raise_protocol_error(data):
    """Anything a client sends either is a command that was there to read, or an error
    that says what is wrong (not an empty or generic message)."""
    try:
        cmd = parse_command(data)
    except ProtocolError as e:
        assert str(e) and len(str(e)) < 200
        return
    obj = json.loads(data.decode("utf-8"))
    assert obj["cmd"] == cmd.name and set(cmd.args) == set(obj) - {"cmd", "id"}


def test_messages_are_one_json_line_with_a_class():
    pose = pose_message(
        1.25, (1.0, 2.0, 0.5), (0.1, 0.0, -0.2), [[1e-6, 0, 0], [0, 1e-6, 0], [0, 0, 1e-4]], 3, True
    )
    line = encode(pose)
    assert line.endswith(b"\n") and line.count(b"\n") == 1
    back = json.loads(line)
    assert back["class"] == "POSE"
    assert (back["x"], back["y"], back["theta"], back["omega"]) == (1.0, 2.0, 0.5, -0.2)
    assert back["cov"][2][2] == 1e-4 and back["used"] == 3 and back["updating"] is True


def test_non_finite_values_become_null_not_invalid_json():
    nan = math.nan
    msg = pose_message(0.0, (nan, 0, 0), (0, 0, math.inf), [[nan] * 3] * 3, 0, False, ["left"])
    back = json.loads(encode(msg))
    assert back["x"] is None and back["omega"] is None and back["cov"][0][0] is None
    assert back["missing"] == ["left"] and back["updating"] is False
    src = json.loads(encode(source_message({"name": "a", "rate_hz": nan}, residual=None)))
    assert src == {"class": "SOURCE", "name": "a", "rate_hz": None, "residual": None}


def test_version_and_error():
    v = version_message(100.0, ["l", "r"], False, "lsq")
    assert v["class"] == "VERSION" and v["proto_major"] == 1 and v["sensors"] == ["l", "r"]
    assert error_message("bad", id=3) == {"class": "ERROR", "message": "bad", "id": 3}


def test_errors_keep_the_id_of_a_bad_command():
    with pytest.raises(ProtocolError) as info:
        parse_command(b'{"cmd": "fix", "id": 42}')
    assert info.value.id == 42
    with pytest.raises(ProtocolError) as info:
        parse_command(b"[42]")
    assert info.value.id is None


@pytest.mark.parametrize(
    "line, words",
    [
        (b'{"cmd":"status","id":1e999}', "id must be"),
        (b'{"cmd":"status","id":[1,2]}', "id must be"),
        (b'{"cmd":"status","id":"' + b"x" * 200 + b'"}', "id must be"),
        (b"[" * 2000, "nested deeper than 8"),
        (b'{"cmd":' + b"{" * 50 + b"}" * 50 + b"}", "nested deeper than 8"),
        (b'{"cmd":"status","id":' + b"9" * 5000 + b"}", "invalid JSON"),
    ],
)
def test_lines_that_once_crashed_the_daemon_are_protocol_errors(line, words):
    """Issue 11: each of these raised something other than ProtocolError (or built a
    reply that could not be encoded).  Now each is a ProtocolError whose ERROR encodes."""
    with pytest.raises(ProtocolError, match=words) as info:
        parse_command(line)
    assert json.loads(encode(error_message(str(info.value), info.value.id)))["class"] == "ERROR"


def test_brackets_inside_strings_do_not_count_as_nesting():
    cmd = parse_command(b'{"cmd":"status","id":"' + b"[" * 100 + b'"}')
    assert cmd.id == "[" * 100


@given(st.binary(max_size=300))
def test_any_bytes_give_a_command_or_an_error_that_encodes(data):
    """Whatever a client sends, the answer is a Command of a known name with finite
    arguments, or a ProtocolError whose ERROR reply (id included) is valid JSON."""
    try:
        cmd = parse_command(data)
    except ProtocolError as e:
        assert json.loads(encode(error_message(str(e), e.id)))["message"]
        return
    assert cmd.name in COMMANDS
    assert all(math.isfinite(v) for v in cmd.args.values())
    json.dumps({"id": cmd.id}, allow_nan=False)


@pytest.mark.parametrize("line", [b'{"cmd":"reset","x":1e308}', b'{"cmd":"fix","theta":1e300}',
                                  b'{"cmd":"fix","y":-2e7}'])  # fmt: skip
def test_poses_no_float_can_hold_are_refused(line):
    """A reset or fix far beyond any map (1e308 m) would turn the pose and its covariance
    into inf and NaN for every later window."""
    with pytest.raises(ProtocolError, match="must be within"):
        parse_command(line)
    assert parse_command(b'{"cmd":"fix","x":9999999.5,"theta":-9999}').args["x"] == 9999999.5
