"""evemu-record reader: real recordings, both parsers, every kind of bad input."""

from __future__ import annotations

import cores
import numpy as np
import pytest
from capture_helpers import EXTERNAL, drain, external_dir, one_mouse_config
from conftest import run_mousedom
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mousedom.capture import CaptureError, open_capture
from mousedom.capture.evemu import (
    EvemuCapture,
    _fast_events,
    _slow_events,
    format_evemu,
)
from mousedom.errors import UserError


@pytest.mark.parametrize("row", EXTERNAL, ids=[r[0].split("__")[1] for r in EXTERNAL])
def test_external_recordings_match_sources_md(row):
    name, events, frames, motion, net_x, net_y, path_x, path_y = row
    cap = drain(external_dir() / name)
    s = cap.stats[0]
    assert (s.events, s.frames, s.reports) == (events, frames, motion)
    assert (s.net_x, s.net_y) == (net_x, net_y)
    assert (s.path_x, s.path_y) == (path_x, path_y)
    assert s.dropped_frames == 0 and s.unterminated == 0 and not cap.warnings
    t, dx, dy = cap.motion[0]
    assert (int(dx.sum()), int(dy.sum())) == (net_x, net_y)
    assert np.all(np.diff(t) >= 0)


def test_desc_companion_gives_the_device_and_epoch_times():
    d = external_dir()
    cap = open_capture(d / "evemu-devices__PS2_Generic_Mouse.events")
    assert cap.desc_path.endswith(".desc")
    dev = cap.devices[0]
    assert dev.name == "PS/2 Generic Mouse"
    assert (dev.bus, dev.vendor, dev.product) == (0x11, 0x02, 0x01)
    assert dev.rel_xy is True
    assert cap.time_base == "epoch"
    assert cap.first_time() == pytest.approx(1329846856.201613, abs=1e-6)
    # Naming the .desc opens the pair too.
    same = open_capture(d / "evemu-devices__PS2_Generic_Mouse.desc")
    assert same.path == cap.path


def test_single_file_1_2_with_tab_comments_and_leading_zeros():
    cap = drain(external_dir() / "evemu-devices__Ultrathin_Touch_Mouse.events")
    assert cap.time_base == "relative"
    assert cap.devices[0].extra["evemu_version"] == "1.2"
    t, dx, dy = cap.motion[0]
    # The first frame: "E: 0.000000 0002 0000 0008" and "... 0001 -013".
    assert (t[0], dx[0], dy[0]) == (0.0, 8, -13)
    # Buttons, wheel and MSC_SCAN are skipped and counted, never motion.
    assert cap.stats[0].skipped == 87


def test_saitek_buttons_and_msc_scan_are_skipped_and_counted():
    path = external_dir() / "evemu-devices__Saitek_Cyborg_RAT5_Mouse.events"
    cap = drain(path)
    # Independent count: event lines that are neither REL_X/REL_Y nor SYN_REPORT.
    other = 0
    for line in path.read_text().splitlines():
        f = line.split()
        if f and f[0] == "E:" and (f[2], f[3]) not in (("0002", "0000"), ("0002", "0001")):
            other += (f[2], f[3]) != ("0000", "0000")
    assert cap.stats[0].skipped == other == 13


def test_frames_are_grouped_by_syn_report_not_by_timestamp(tmp_path):
    # Two frames with the very same timestamp, and one frame whose events differ in time.
    text = (
        "E: 1.000000 0002 0000 3\nE: 1.000000 0000 0000 0\n"
        "E: 1.000000 0002 0001 -2\nE: 1.000000 0000 0000 0\n"
        "E: 1.100000 0002 0000 1\nE: 1.100007 0002 0001 1\nE: 1.100009 0000 0000 0\n"
    )
    p = tmp_path / "a.evemu"
    p.write_text(text)
    t, dx, dy = drain(p).motion[0]
    assert t.tolist() == [1.0, 1.0, 1.100009]
    assert dx.tolist() == [3, 0, 1] and dy.tolist() == [0, -2, 1]


def test_syn_dropped_frame_is_dropped_and_counted(tmp_path):
    text = (
        "E: 1.0 0002 0000 5\nE: 1.0 0000 0000 0\n"
        "E: 1.1 0002 0000 7\nE: 1.1 0000 0003 0\nE: 1.1 0002 0001 9\nE: 1.1 0000 0000 0\n"
        "E: 1.2 0002 0000 1\nE: 1.2 0000 0000 0\n"
    )
    p = tmp_path / "d.evemu"
    p.write_text(text)
    cap = drain(p)
    t, dx, dy = cap.motion[0]
    assert dx.tolist() == [5, 1]
    assert cap.stats[0].dropped_frames == 1
    assert (cap.stats[0].lost_x, cap.stats[0].lost_y) == (7, 9)


@pytest.mark.parametrize("comments", [False, True])
@pytest.mark.parametrize("version", [None, "1.0", "1.3"])
def test_small_blocks_give_the_same_reports(tmp_path, comments, version):
    rng = np.random.default_rng(1)
    n = 3000
    t = np.cumsum(rng.uniform(0.0005, 0.02, n)) + 100.0
    dx = rng.integers(-40, 40, n)
    dy = rng.integers(-40, 40, n)
    keep = (dx != 0) | (dy != 0)
    t, dx, dy = t[keep], dx[keep], dy[keep]
    p = tmp_path / "m.evemu"
    p.write_text(format_evemu(t, dx, dy, version=version, comments=comments))
    whole = drain(p).motion[0]
    cap = EvemuCapture(str(p), block_bytes=977)  # cut lines and frames everywhere
    parts = [m for f in cap.feeds() for b in f.batches for m in b.motion]
    small = [np.concatenate([getattr(m, k) for m in parts]) for k in ("t", "dx", "dy")]
    for a, b, want in zip(whole, small, (t, dx, dy), strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_allclose(a, want, atol=5e-7)


def test_small_blocks_name_the_right_line(tmp_path):
    """Blocks taken by the vectorised parsers count their lines too: a bad line after
    many small blocks is named by its own number."""
    n = 400
    text = format_evemu(np.arange(1, n + 1) * 0.001, np.ones(n, int), -np.ones(n, int))
    lines = text.splitlines(keepends=True)
    bad = len(lines) - 10  # 1-based number of the line made bad
    lines[bad - 1] = "E: 0.390000 0002 00z0 1\n"
    p = tmp_path / "m.evemu"
    p.write_text("".join(lines))
    cap = EvemuCapture(str(p), block_bytes=977)
    with pytest.raises(CaptureError) as e:
        for f in cap.feeds():
            for _ in f.batches:
                pass
    assert f"m.evemu:{bad}:" in str(e.value)


# ------------------------------------------------------------------ fast == slow parser

_line = st.tuples(
    st.integers(0, 2**33),
    st.integers(0, 999_999),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF),
    st.integers(-(2**31), 2**31 - 1),
    st.sampled_from(["", "\t# EV_REL / REL_X   3", "  # c", " "]),
    st.sampled_from(["{:04d}", "{:d}", "{:+d}"]),
    st.sampled_from(["{:04x}", "{:x}", "{:04X}"]),
)


_evemu_line = st.tuples(
    st.integers(0, 10**12 - 1), st.integers(0, 999999), st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF), st.integers(-(2**31), 2**31 - 1),
)  # fmt: skip
_REGULAR = b"E: 12.000250 0002 0001 -0013\t# EV_REL / REL_Y   -13\n"


@settings(max_examples=200, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_evemu_line, min_size=1, max_size=40), st.booleans())
def test_regular_parser_takes_what_evemu_writes(lines, comments):
    """Lines as evemu writes them (``%lu.%06u %04x %04x``, then ``%d`` (1.0-1.2) or
    ``%04d<TAB># comment`` (1.3)) take the fixed-offset parser, with the line parser's
    results."""
    from mousedom.capture.evemu_lines import regular_events

    text = ""
    for sec, usec, ty, co, va in lines:
        value = f"{va:04d}\t# EV_REL / REL_X   {va}" if comments else f"{va:d}"
        text += f"E: {sec}.{usec:06d} {ty:04x} {co:04x} {value}\n"
    block = text.encode()
    regular = regular_events(block, 7)
    slow = _slow_events("x", block, 7, at_eof=False)
    assert regular is not None
    for k in ("t", "typ", "code", "value", "line"):
        np.testing.assert_array_equal(getattr(regular, k), getattr(slow, k))


@settings(max_examples=200, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_line, min_size=1, max_size=40))
def test_vectorised_parser_equals_line_parser(lines):
    text = ""
    for sec, usec, ty, co, va, comment, vfmt, hfmt in lines:
        text += (
            f"E: {sec}.{usec:06d} {hfmt.format(ty)} {hfmt.format(co)} {vfmt.format(va)}{comment}\n"
        )
    block = text.encode()
    fast = _fast_events(block, 7)
    slow = _slow_events("x", block, 7, at_eof=False)
    assert fast is not None
    for k in ("t", "typ", "code", "value", "line"):
        np.testing.assert_array_equal(getattr(fast, k), getattr(slow, k))


@pytest.mark.parametrize("parser", ["fast_events", "regular_events", "general_events"])
@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.one_of(
    st.binary(max_size=300),
    # near misses of evemu's own lines: one byte of a regular line changed
    st.tuples(st.integers(0, 40), st.binary(min_size=1, max_size=1)).map(
        lambda p: _REGULAR[: p[0]] + p[1] + _REGULAR[p[0] + 1 :]
    ),
))  # fmt: skip
def test_vectorised_parser_never_accepts_what_the_line_parser_rejects(parser, data):
    from mousedom.capture import evemu_lines

    block = data if data.endswith(b"\n") else data + b"\n"
    fast = getattr(evemu_lines, parser)(block, 1)
    try:
        slow = _slow_events("x", block, 1, at_eof=False)
    except CaptureError:
        assert fast is None
        return
    if fast is not None:
        for k in ("t", "typ", "code", "value", "line"):
            np.testing.assert_array_equal(getattr(fast, k), getattr(slow, k))


# ------------------------------------------------------------------ bad input


def _bad(tmp_path, text: str | bytes, name="bad.evemu") -> str:
    p = tmp_path / name
    p.write_bytes(text.encode() if isinstance(text, str) else text)
    with pytest.raises(UserError) as e:
        drain(p)
    return str(e.value)


def test_garbage_line_names_file_and_line(tmp_path):
    msg = _bad(tmp_path, "E: 1.0 0002 0000 1\nE: 1.0 0000 0000 0\nhello world\n")
    assert "bad.evemu:3:" in msg


def test_unknown_version(tmp_path):
    msg = _bad(tmp_path, "# EVEMU 2.0\nN: x\nE: 1.0 0002 0000 1\n")
    assert "bad.evemu:1:" in msg and "unknown evemu version 2.0" in msg


def test_time_going_backwards(tmp_path):
    msg = _bad(
        tmp_path,
        "E: 2.0 0002 0000 1\nE: 2.0 0000 0000 0\nE: 1.5 0002 0000 1\nE: 1.5 0000 0000 0\n",
    )
    assert "bad.evemu:3:" in msg and "backwards" in msg


def test_header_line_among_events(tmp_path):
    msg = _bad(tmp_path, "N: m\nE: 1.0 0002 0000 1\nE: 1.0 0000 0000 0\nB: 02 03\n")
    assert "bad.evemu:4:" in msg and "header line" in msg


def test_bad_hex_and_bad_value(tmp_path):
    assert "bad.evemu:2:" in _bad(tmp_path, "E: 1.0 0002 0000 1\nE: 1.0 00g2 0000 1\n")
    assert "bad.evemu:1:" in _bad(tmp_path, "E: 1.0 0002 0000 1.5\nE: 1.0 0000 0000 0\n")
    assert "bad.evemu:1:" in _bad(tmp_path, "E: 1.0 0002 0000\n")


def test_bad_header_line(tmp_path):
    msg = _bad(tmp_path, "# EVEMU 1.3\nN: m\nI: 0003 zz 0001 0001\nE: 1.0 0000 0000 0\n")
    assert "bad.evemu:3:" in msg


def test_desc_without_events(tmp_path):
    (tmp_path / "lonely.desc").write_text("N: m\n")
    with pytest.raises(UserError, match="lonely.events is missing"):
        open_capture(tmp_path / "lonely.desc")


def test_truncated_recording_keeps_everything_before_the_cut(tmp_path):
    text = format_evemu(np.array([1.0, 1.01, 1.02]), np.array([1, 2, 3]), np.array([0, 0, 4]))
    cut = text[: text.rindex("E: 1.020000 0002 0001") + 14]  # inside the last frame's line
    p = tmp_path / "cut.evemu"
    p.write_text(cut)
    cap = drain(p)
    t, dx, dy = cap.motion[0]
    # The third frame lost its torn REL_Y line and its SYN_REPORT: its REL_X is kept.
    assert dx.tolist() == [1, 2, 3] and dy.tolist() == [0, 0, 0]
    assert cap.stats[0].unterminated == 1 and cap.stats[0].torn_bytes > 0
    assert any("cut off" in w for w in cap.warnings)


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=400))
def test_fuzz_random_bytes_never_crash(tmp_path, data):
    p = tmp_path / "fuzz.events"
    p.write_bytes(data)
    try:
        drain(p)
    except UserError as e:
        assert "fuzz.events" in str(e)


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.lists(
        st.sampled_from(
            [
                "E: 1.000000 0002 0000 0003",
                "E: 1.000100 0000 0000 0000",
                "E: 0.5 0002 0001 -7",
                "E: 1.000100 0001 0110 0001",
                "# comment",
                "",
                "N: x",
                "E: x",
                "E: 1.0 0000 0003 0",
                "E: 2.000000 0002 000b 120",
                "garbage",
                "E: 1.0 0002 0000 99999999999",
            ]
        ),
        max_size=30,
    )
)
def test_fuzz_event_line_soup(tmp_path, lines):
    p = tmp_path / "soup.evemu"
    p.write_text("\n".join(lines) + "\n")
    try:
        cap = drain(p)
    except UserError as e:
        assert str(e).startswith(str(p))
        return
    s = cap.stats[0]
    motion = cap.motion.get(0)
    if motion is not None:
        assert s.net_x == int(motion[1].sum()) and s.net_y == int(motion[2].sum())


@pytest.mark.parametrize("text", ["", "\n\n", "  \n"])
def test_an_empty_file_is_an_error_but_an_empty_events_file_beside_its_desc_is_not(tmp_path, text):
    """A 0-byte .events replayed to a header-only CSV with exit 0; with its .desc it is a
    recording in which nothing happened (a warning, as any capture without motion)."""
    p = tmp_path / "run.events"
    p.write_text(text)
    with pytest.raises(UserError, match=r"run\.events: empty file"):
        open_capture(p)
    (tmp_path / "run.desc").write_bytes(
        (external_dir() / "evemu-devices__PS2_Generic_Mouse.desc").read_bytes()
    )
    cap = drain(p)
    assert cap.devices[0].name == "PS/2 Generic Mouse" and cap.stats[0].reports == 0


@pytest.mark.parametrize(
    "line, want",
    [
        (b"E: 1.000005 0002 0000 -13", (1.000005, 2, 0, -13)),
        (b"E: 1.000005 0002 0001 -013", (1.000005, 2, 1, -13)),  # evemu pads: minus thirteen
        (b"E: 0.5 0002 0001 +7", (0.5, 2, 1, 7)),
        (b"E: 12.000000 0000 0000 0000", (12.0, 0, 0, 0)),
        (b"E: 3.250000 0002 0008 -1", (3.25, 2, 8, -1)),
    ],
)
def test_event_lines_by_hand_both_parsers(line, want):
    """Hand-written lines with their meaning spelled out: the careful parser and the
    vectorised one each give it (a parser taking abs(value) was caught only by the two
    agreeing with each other)."""
    from mousedom.capture.evemu_lines import event_line, fast_events

    assert event_line(line) == pytest.approx(want, abs=1e-12)
    fast = fast_events(line + b"\n", 1)
    if fast is not None:  # "+7" and short fractions take the careful path
        got = (float(fast.t[0]), int(fast.typ[0]), int(fast.code[0]), int(fast.value[0]))
        assert got == pytest.approx(want, abs=1e-12)


def _cut_recording() -> str:
    """Two frames of REL_X 7 and 1234, as evemu writes them (every line ends with \\n)."""
    return (
        "# EVEMU 1.3\nN: M\nI: 0003 046d c077 0111\nP: 00 00 00 00 00 00 00 00\n"
        "B: 00 0b 00 00 00 00 00 00 00\nB: 02 03 00 00 00 00 00 00 00\n"
        "E: 0.000000 0002 0000 7\nE: 0.000000 0000 0000 0\n"
        "E: 0.008000 0002 0000 1234\tcomment\nE: 0.008000 0000 0000 0\n"
    ).replace("\tcomment", "\t# EV_REL / REL_X 1234")


@pytest.mark.parametrize("core_name", cores.names())
def test_a_last_line_cut_anywhere_is_skipped_never_kept(tmp_path, core_name):
    """A last line cut inside its number ("... 0000 12" of "... 0000 1234") read as an
    event and kept the wrong count (net x 19 for 7): evemu ends every line with a newline,
    so a last line without one is skipped with the warning naming it, at every cut, with
    either core; only whole lines count."""
    text = _cut_recording()
    body = text.index("E: 0.008000 0002")
    p = tmp_path / "cut.evemu"
    with cores.using(core_name):
        for cut in range(body - 3, len(text) + 1):
            p.write_text(text[:cut])
            cap = drain(p)
            whole = text[:cut][: text[:cut].rfind("\n") + 1]
            want_x = 7 + (1234 if "0000 1234" in whole else 0)
            assert cap.stats[0].net_x == want_x, (cut, text[:cut][-20:])
            torn = not text[:cut].endswith("\n")
            line = whole.count("\n") + 1
            assert any(f"cut.evemu:{line}: last line cut off" in w for w in cap.warnings) == torn
            assert (cap.stats[0].torn_bytes > 0) == torn


def test_a_cut_only_event_line_gives_no_first_time(tmp_path):
    """first_time read the cut line's stamp (it anchors the window grid and the time
    base): a line without its newline is no event there either."""
    p = tmp_path / "one.evemu"
    p.write_text(_cut_recording().split("E:")[0] + "E: 1700000000.5 0002 0000 3")
    cap = open_capture(p)
    assert cap.first_time() is None and cap.time_base == "relative"
    cap = drain(p)
    assert cap.stats[0].reports == 0 and any(":7: last line cut off" in w for w in cap.warnings)


def test_replay_of_a_recording_cut_in_its_last_number_counts_whole_lines_only(tmp_path):
    text = _cut_recording()
    p = tmp_path / "cut.evemu"
    p.write_text(text[: text.index("1234") + 2])
    proc = run_mousedom("replay", "-c", str(one_mouse_config(tmp_path)), "--capture", f"m={p}")
    assert proc.returncode == 0, proc.stderr
    row = next(ln for ln in proc.stdout.splitlines() if ln.startswith("m "))
    assert row.split()[3] == "7", row  # net x: the first frame's only
    assert "cut.evemu:9: last line cut off (truncated recording); skipped" in proc.stderr


@pytest.mark.parametrize("value", ["1_000", "1_0", "-1_0", "٣"])
def test_a_value_with_a_digit_separator_or_non_ascii_digit_is_refused(tmp_path, value):
    """Python's int() reads "1_000" as 1000: such a value (no evemu writes one) was taken
    silently; it is refused naming the line, as the fast scanners refuse it."""
    text = format_evemu(np.arange(1, 6) * 0.01, np.ones(5, int), np.ones(5, int))
    lines = text.splitlines(keepends=True)
    k = next(i for i, ln in enumerate(lines) if ln.startswith("E: 0.030000 0002 0000"))
    lines[k] = f"E: 0.030000 0002 0000 {value}\n"
    p = tmp_path / "u.evemu"
    p.write_text("".join(lines))
    with pytest.raises(CaptureError, match=rf"u.evemu:{k + 1}: value must be a decimal integer"):
        drain(p)
