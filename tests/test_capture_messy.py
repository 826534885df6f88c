"""Captures as users really hand them over (issue 11, items 2, 5 and 6).

Line endings from other systems, a byte order mark, compression, flow-style YAML, files
cut off mid-line, hex axis codes, cat-joined recordings and absurd numbers.  The truth
each count is checked against is independent of the readers: the facts of the external
recordings in SOURCES.md (``capture_helpers.EXTERNAL``), or the simulated reports a test
wrote itself.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import zlib

import numpy as np
import pytest
from capture_helpers import EXTERNAL, drain, one_mouse_config
from conftest import external_dir, run_mousedom

from mousedom.capture import CaptureError, assign, open_capture
from mousedom.capture.evemu import format_evemu
from mousedom.capture.libinput import format_libinput
from mousedom.capture.replay import Replay
from mousedom.config import load_config

ULTRATHIN = EXTERNAL[2]  # single-file evemu 1.2 with a header and an A: line


def _messy(raw: bytes) -> dict[str, bytes]:
    crlf = raw.replace(b"\n", b"\r\n")
    return {
        "crlf": crlf,
        "cr": raw.replace(b"\n", b"\r"),
        "bom": b"\xef\xbb\xbf" + raw,
        "bom-crlf": b"\xef\xbb\xbf" + crlf,
        "gz": gzip.compress(raw),
        "xz": lzma.compress(raw),
        "bz2": bz2.compress(raw),
        "gz-crlf": gzip.compress(crlf),
        "two-gz-members": gzip.compress(raw[: len(raw) // 2]) + gzip.compress(raw[len(raw) // 2 :]),
    }


@pytest.mark.parametrize("kind", list(_messy(b"")))
def test_a_real_evemu_recording_in_any_dress_gives_the_published_counts(tmp_path, kind):
    name, events, frames, motion, net_x, net_y, path_x, path_y = ULTRATHIN
    raw = (external_dir() / name).read_bytes()
    path = tmp_path / f"rec.{kind}"
    path.write_bytes(_messy(raw)[kind])
    cap = drain(path)
    s = cap.stats[0]
    assert (s.events, s.frames, s.net_x, s.net_y, s.path_x, s.path_y) == (
        events, frames, net_x, net_y, path_x, path_y,
    )  # fmt: skip
    assert cap.devices[0].name == "Ultrathin Touch Mouse" and cap.devices[0].rel_xy
    assert not [w for w in cap.warnings if "cut off" in w]


def _reports(n=300, seed=1):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.004, 0.012, n))
    return t, rng.integers(-9, 10, n), rng.integers(-9, 10, n)


@pytest.mark.parametrize("kind", list(_messy(b"")))
def test_libinput_in_any_dress_gives_every_count(tmp_path, kind):
    """A CRLF libinput file once gave 0 reports and exit 0."""
    t, dx, dy = _reports()
    raw = format_libinput([("a", t, dx, dy)]).encode()
    path = tmp_path / f"rec.{kind}"
    path.write_bytes(_messy(raw)[kind])
    cap = drain(path)
    assert cap.format == "libinput"
    s = cap.stats[0]
    assert (s.net_x, s.net_y, s.path_x, s.path_y) == (
        dx.sum(),
        dy.sum(),
        np.abs(dx).sum(),
        np.abs(dy).sum(),
    )
    assert s.reports == np.count_nonzero((dx != 0) | (dy != 0))


def test_crlf_mouse_in_a_two_mouse_rig_is_not_fused_as_standing_still(tmp_path):
    """The silent wrong answer of item 2: one CRLF file in a two-mouse rig read as no
    motion.  Both mice now carry their counts into the fusion."""
    t, dx, dy = _reports()
    a = tmp_path / "a.yml"
    b = tmp_path / "b.yml"
    a.write_text(format_libinput([("a", t, dx, dy)]))
    b.write_bytes(format_libinput([("b", t, dx, dy)]).encode().replace(b"\n", b"\r\n"))
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "model: lsq\nmice:\n"
        "  a: {cpi: 400, mount: {x: 0, y: 0.1, yaw: 0}}\n"
        "  b: {cpi: 400, mount: {x: 0, y: -0.1, yaw: 0}}\n"
    )
    config = load_config(cfg, need_sources=False)
    replay = Replay(config, assign(config, [("a", str(a)), ("b", str(b))]))
    summary = replay.run(lambda batch: None)
    for mouse in summary.mice:
        assert mouse.counts_in == (float(dx.sum()), float(dy.sum())), mouse.name
        assert mouse.counts_out == pytest.approx(mouse.counts_in)
    # Equal motion of both mice is a pure translation: forward = -REL_Y, left = -REL_X.
    metres = 0.0254 / 400
    assert summary.final["theta"] == pytest.approx(0, abs=1e-9)
    assert summary.final["x"] == pytest.approx(-dy.sum() * metres, abs=1e-9)
    assert summary.final["y"] == pytest.approx(-dx.sum() * metres, abs=1e-9)


def test_flow_style_event_lists_keep_rel_x(tmp_path):
    """``- evdev: [[0, 10000, 2, 0, 1], ...]`` once dropped REL_X silently."""
    t, dx, dy = _reports(50)
    lines = format_libinput([("a", t, dx, dy)]).splitlines()
    head = lines[: lines.index("  events:") + 1]
    us = np.round(t * 1e6).astype(np.int64)
    for u, x, y in zip(us.tolist(), dx.tolist(), dy.tolist(), strict=True):
        s, u = divmod(u, 1_000_000)
        head.append(
            f"  - evdev: [[{s}, {u}, 2, 0, {x}], [{s}, {u}, 2, 1, {y}], [{s}, {u}, 0, 0, 0]]"
        )
    path = tmp_path / "flow.yml"
    path.write_text("\n".join(head) + "\n")
    s = drain(path).stats[0]
    assert (s.net_x, s.net_y, s.path_x) == (dx.sum(), dy.sum(), np.abs(dx).sum())


def test_flow_style_with_a_bad_row_names_its_line(tmp_path):
    lines = format_libinput([("a", *_reports(5))]).splitlines()
    at = lines.index("  events:") + 1
    lines.insert(at, "  - evdev: [[0, 10, 2, 0, 1], [0, 10, 2, zero, 1]]")
    path = tmp_path / "flow.yml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(CaptureError, match=rf"flow.yml:{at + 1}: an evdev event must be"):
        drain(path)


def test_libinput_cut_in_its_last_row_keeps_every_whole_row(tmp_path):
    t, dx, dy = _reports(40)
    text = format_libinput([("a", t, dx, dy)])
    cut = text[: text.rstrip("\n").rfind("[") + 6]  # inside the last row (its SYN_REPORT)
    path = tmp_path / "cut.yml"
    path.write_text(cut)
    cap = drain(path)
    s = cap.stats[0]
    assert (s.net_x, s.net_y) == (dx.sum(), dy.sum())  # the torn row was a SYN_REPORT
    assert s.torn_bytes > 0 and any("last line cut off" in w for w in cap.warnings)


def test_trailing_tabs_in_libinput_yaml_are_accepted(tmp_path):
    t, dx, dy = _reports(20)
    text = format_libinput([("a", t, dx, dy)]).replace("version: 1\n", "version: 1\t\n")
    text = text.replace("  evdev:\n", "  evdev:\t\n").replace("]\n", "]\t\n")
    path = tmp_path / "tabs.yml"
    path.write_text(text)
    assert drain(path).stats[0].net_x == dx.sum()


def test_two_libinput_files_joined_with_cat_say_what_to_do(tmp_path):
    text = format_libinput([("a", *_reports(20))])
    path = tmp_path / "joined.yml"
    path.write_text(text + text)
    second = text.count("\n") + text.splitlines().index("version: 1") + 1
    with pytest.raises(CaptureError, match=rf"joined.yml:{second}: a second recording.*cat"):
        open_capture(path)


def test_evemu_axis_codes_are_hex(tmp_path):
    """evemu writes ``A: %02x %d %d %d %d %d``; 2f (ABS_MT_SLOT) was refused as malformed."""
    body = format_evemu(*_reports(10))
    path = tmp_path / "abs.evemu"
    path.write_text(body.replace("B: 02 03", "A: 2f 0 15 0 0 0\nA: 35 -100 5676 0 0 42\nB: 02 03"))
    assert drain(path).stats[0].net_x == _reports(10)[1].sum()
    bad = tmp_path / "bad.evemu"
    bad.write_text(body.replace("B: 02 03", "A: zz 0 15 0 0 0\nB: 02 03"))
    with pytest.raises(CaptureError, match="malformed A: line"):
        open_capture(bad)


def test_a_touchpad_is_not_a_mouse(tmp_path):
    path = tmp_path / "touchpad.evemu"
    path.write_text(
        "# EVEMU 1.3\nN: SynPS/2 Synaptics TouchPad\nI: 0011 0002 0007 01b1\n"
        "B: 00 0b 00 00 00 00 00 00 00\nB: 02 00 00 00 00 00 00 00 00\n"
        "B: 03 03 00 00 00 00 80 f3 02\nA: 00 1266 5676 0 0 42\nA: 2f 0 1 0 0 0\n"
        "E: 0.000001 0003 0035 3000\nE: 0.000001 0000 0000 0000\n"
    )
    cfg = one_mouse_config(tmp_path)
    proc = run_mousedom("replay", "--config", str(cfg), "--capture", f"m={path}")
    assert proc.returncode == 2 and "not a mouse" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    "line, words",
    [
        ("E: " + "9" * 320 + ".000001 0002 0000 1", "time out of range"),
        ("E: 1." + "1" * 40 + " 0002 0000 1", "time out of range"),
        ("E: 1.000001 0002 0000 " + "9" * 5000, "value beyond the signed 32 bits"),
        # (past a line's bound: refused as a line before its value is read)
        ("E: 1.000001 0002 0000 -" + "9" * 3_000_000, "a line longer than 1048576 bytes"),
        ("E: 1.000001 0002 0000 " + "0" * 5000 + "2147483648", "value beyond the signed 32"),
        ("E: 1.000001 0002 0000 -2147483649", "value beyond the signed 32 bits"),
    ],
)
def test_evemu_absurd_numbers_are_one_clear_error(tmp_path, line, words):
    """A value of thousands of digits got Python's own message ("Exceeds the limit (4300
    digits) for integer string conversion ... use sys.set_int_max_str_digits()"): it is
    the project's, naming the file and line, as for a value just past 32 bits."""
    body = format_evemu(*_reports(5)).splitlines()
    at = len(body) - 2
    body.insert(at, line)
    path = tmp_path / "big.evemu"
    path.write_text("\n".join(body) + "\n")
    with pytest.raises(CaptureError, match=rf"big.evemu:{at + 1}: .*{words}") as e:
        drain(path)
    assert "set_int_max_str_digits" not in str(e.value) and "Exceeds" not in str(e.value)


def test_evemu_value_of_leading_zeros_within_32_bits_is_read():
    """The digits counted are the significant ones: zeros in front change nothing."""
    from mousedom.capture.evemu_lines import event_line

    assert event_line(b"E: 1.000001 0002 0000 -" + b"0" * 5000 + b"2147483648")[3] == -(2**31)
    assert event_line(b"E: 1.000001 0002 0000 +0002147483647")[3] == 2**31 - 1


@pytest.mark.parametrize(
    "row",
    [
        "[99999999999, 0, 2, 0, 1]",
        "[0, 0, 2, 0, " + "9" * 5000 + "]",
        "[-1, 0, 2, 0, 1]",
        "[0, 10000, 2, 0, ]",  # numpy's fromstring reads a blank field as 0: a silent REL_X 0
        "[1, , 2, 0, 5]",
        "[1, +, 2, 0, 5]",  # a lone sign is a 0 to numpy, too
        "[1, 5, 2, 0, -]",
    ],
)
def test_libinput_absurd_numbers_are_one_clear_error(tmp_path, row):
    lines = format_libinput([("a", *_reports(5))]).splitlines()
    at = lines.index("  events:") + 2
    lines.insert(at, f"    - {row}")
    path = tmp_path / "big.yml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(CaptureError, match=rf"big.yml:{at + 1}: an evdev event must be"):
        drain(path)


def test_libinput_header_with_a_huge_integer_names_its_line(tmp_path):
    text = format_libinput([("a", *_reports(5))])
    text = text.replace("id: [3, 1133,", "id: [3, " + "1" * 5000 + ",")
    path = tmp_path / "big.yml"
    path.write_text(text)
    with pytest.raises(CaptureError, match=r"big.yml:\d+: invalid YAML: an integer of 5000"):
        open_capture(path)


def test_a_corrupt_or_bomb_compressed_file_is_one_clear_error(tmp_path):
    junk = tmp_path / "junk.gz"
    junk.write_bytes(b"\x1f\x8b" + b"not gzip at all" * 10)
    with pytest.raises(CaptureError, match="junk.gz: .*corrupt"):
        open_capture(junk)
    empty = tmp_path / "zeros.xz"
    empty.write_bytes(lzma.compress(b"\0" * 1000))
    with pytest.raises(CaptureError, match="not a capture"):
        open_capture(empty)


def test_a_compressed_recording_cut_off_keeps_what_it_held(tmp_path):
    t, dx, dy = _reports(3000)
    raw = format_evemu(t, dx, dy).encode()
    path = tmp_path / "cut.gz"
    path.write_bytes(gzip.compress(raw)[:-2000])
    cap = drain(path)
    assert any("gzip stream is cut off" in w for w in cap.warnings)
    # What was kept is exactly the first reports of the truth (those with motion).
    moved = (dx != 0) | (dy != 0)
    got_t, got_dx, got_dy = cap.motion[0]
    k = len(got_t)
    assert 0 < k < moved.sum()
    assert got_dx.tolist() == dx[moved][:k].tolist() and got_dy.tolist() == dy[moved][:k].tolist()
    assert got_t == pytest.approx(t[moved][:k], abs=1e-6)


def test_replay_device_that_is_not_in_the_file_is_an_error(tmp_path):
    """``replay: {file, device}`` naming a node the one-mouse file does not have was
    ignored; now it is refused, naming what the file holds."""
    t, dx, dy = _reports(20)
    rec = tmp_path / "one.yml"
    rec.write_text(format_libinput([("a", t, dx, dy)]))  # its node is /dev/input/event5
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "model: diff-drive\nmice:\n  m:\n    cpi: 400\n    mount: {x: 0.1, y: 0, yaw: 0}\n"
        f"    replay: {{file: {rec}, device: /dev/input/event4}}\n"
    )
    proc = run_mousedom("replay", "--config", str(cfg))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "/dev/input/event4" in proc.stderr and "/dev/input/event5" in proc.stderr
    ok = cfg.read_text().replace("event4", "event5")
    cfg.write_text(ok)
    assert run_mousedom("replay", "--config", str(cfg)).returncode == 0


def test_a_gzip_recording_cut_inside_a_number_keeps_whole_lines_only(tmp_path):
    """Decompressed, a cut-off .gz ends where the stream was cut, inside a line: that
    line (here "... 0002 0000 12" of "... 1234") is skipped with the warning naming it,
    never kept with a wrong count, next to the warning that the stream is cut off."""
    t = np.array([0.0, 0.008, 0.016])
    text = format_evemu(t, np.array([7, 1234, 5]), np.array([0, 0, 0]))
    cut = text.index("1234") + 2
    z = zlib.compressobj(wbits=31)  # gzip, flushed at the cut and never finished
    path = tmp_path / "cut.evemu.gz"
    path.write_bytes(z.compress(text[:cut].encode()) + z.flush(zlib.Z_SYNC_FLUSH))
    cap = drain(path)
    assert cap.stats[0].net_x == 7
    line = text[:cut].count("\n") + 1
    assert any("gzip stream is cut off" in w for w in cap.warnings)
    assert any(f"cut.evemu.gz:{line}: last line cut off" in w for w in cap.warnings)
