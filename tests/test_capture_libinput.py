"""libinput record reader: several devices, mice picked by codes, streamed events."""

from __future__ import annotations

import numpy as np
import pytest
from capture_helpers import drain
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mousedom.capture import open_capture
from mousedom.capture.libinput import LibinputCapture, format_libinput
from mousedom.errors import UserError

KEYBOARD = """\
- node: /dev/input/event3
  evdev:
    # Name: AT Translated Set 2 keyboard
    name: AT Translated Set 2 keyboard
    id: [17, 1, 1, 43841]
    codes:
      0: [0, 1, 4, 17, 20] # EV_SYN
      1: [1, 2, 3, 4, 5, 30] # EV_KEY
      4: [4] # EV_MSC
    properties: []
  hid: [5, 1, 9, 6]
  udev:
    properties:
    - ID_INPUT_KEYBOARD=1
  events:
  # Current time is 12:31:41
  - evdev:
    - [  0,   5000,   4,   4,     30] # EV_MSC / MSC_SCAN             30
    - [  0,   5000,   1,  30,      1] # EV_KEY / KEY_A                 1
    - [  0,   5000,   0,   0,      0] # ------------ SYN_REPORT (0) ---------- +5ms
"""


def _two_mice(tmp_path, n=400, extra=""):
    rng = np.random.default_rng(3)
    t1 = np.cumsum(rng.uniform(0.001, 0.01, n))
    t2 = np.cumsum(rng.uniform(0.001, 0.01, n)) + 0.0005
    d1 = (rng.integers(-9, 9, n), rng.integers(-9, 9, n))
    d2 = (rng.integers(-9, 9, n), rng.integers(-9, 9, n))
    text = format_libinput([("left", t1, *d1), ("right", t2, *d2)]) + extra
    p = tmp_path / "rec.yml"
    p.write_text(text)
    return p, (t1, *d1), (t2, *d2)


def test_two_mice_and_a_keyboard(tmp_path):
    p, left, right = _two_mice(tmp_path, extra=KEYBOARD)
    cap = drain(p)
    assert isinstance(cap, LibinputCapture)
    assert [d.name for d in cap.devices] == ["left", "right", "AT Translated Set 2 keyboard"]
    assert [d.rel_xy for d in cap.devices] == [True, True, False]
    assert cap.devices[0].vendor == 1133
    assert cap.time_base == "relative"
    assert set(cap.motion) == {0, 1}  # the keyboard is no mouse: not fed at all
    for dev, want in ((0, left), (1, right)):
        t, dx, dy = cap.motion[dev]
        keep = (want[1] != 0) | (want[2] != 0)
        np.testing.assert_allclose(t, want[0][keep], atol=6e-7)
        np.testing.assert_array_equal(dx, want[1][keep])
        np.testing.assert_array_equal(dy, want[2][keep])
        assert cap.stats[dev].net_x == int(want[1].sum())


def test_one_feed_per_device_read_from_its_own_byte_range(tmp_path):
    p, _, _ = _two_mice(tmp_path, n=3000)
    small = LibinputCapture(str(p), block_bytes=1000)
    feeds = small.feeds()
    assert [f.devices for f in feeds] == [(0,), (1,)]
    # Interleave the two feeds: possible only because each reads its own range.
    its = [f.batches for f in feeds]
    got = {0: 0, 1: 0}
    done = set()
    while len(done) < 2:
        for i, it in enumerate(its):
            if i in done:
                continue
            b = next(it, None)
            if b is None:
                done.add(i)
                continue
            got[i] += sum(len(m.t) for m in b.motion)
    whole = drain(p)
    assert got == {k: len(v[0]) for k, v in whole.motion.items()}


def test_hid_and_libinput_entries_are_ignored(tmp_path):
    text = format_libinput([("m", np.array([0.01, 0.02]), np.array([1, 2]), np.array([0, 1]))])
    text = text.replace(
        "  events:\n",
        "  events:\n  - hid:\n      time: [0, 100]\n      hidraw0: [1, 2, 3]\n"
        "  - libinput:\n      type: POINTER_MOTION\n      time: 0.001\n",
    )
    p = tmp_path / "h.yml"
    p.write_text(text)
    cap = drain(p)
    assert cap.motion[0][1].tolist() == [1, 2]


def test_unknown_version(tmp_path):
    p = tmp_path / "v.yml"
    p.write_text(
        format_libinput([("m", np.array([0.01]), np.array([1]), np.array([0]))]).replace(
            "version: 1\n", "version: 7\n", 1
        )
    )
    with pytest.raises(UserError, match=r"v.yml:2: unknown libinput record version 7"):
        open_capture(p)


def test_bad_event_row_names_the_line(tmp_path):
    p, _, _ = _two_mice(tmp_path, n=20)
    lines = p.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("    - [") and i > 40)
    lines[k] = "    - [  0,  1000,   2,   0]"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=rf"rec.yml:{k + 1}: an evdev event must be"):
        drain(p)


def test_garbage_line_in_events(tmp_path):
    p, _, _ = _two_mice(tmp_path, n=20)
    lines = p.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("  - evdev:") and i > 30)
    lines.insert(k, "  !!! garbage !!!")
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=rf"rec.yml:{k + 1}: unexpected line"):
        drain(p)


def test_time_going_backwards(tmp_path):
    t = np.array([0.01, 0.02, 0.015])
    p = tmp_path / "b.yml"
    p.write_text(format_libinput([("m", t, np.array([1, 1, 1]), np.array([0, 0, 0]))]))
    with pytest.raises(UserError, match=r"b.yml:\d+: time goes backwards"):
        drain(p)


def test_invalid_yaml_header(tmp_path):
    p = tmp_path / "y.yml"
    p.write_text("version: 1\nndevices: 1\ndevices:\n- node: /dev/input/event1\n  evdev: [\n")
    with pytest.raises(UserError, match="y.yml"):
        drain(p)


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(0, 4000), st.binary(max_size=60))
def test_fuzz_damaged_recordings_never_crash(tmp_path, at, junk):
    base = tmp_path / "base.yml"
    if not base.exists():
        _two_mice(tmp_path, n=40)
        (tmp_path / "rec.yml").rename(base)
    data = base.read_bytes()
    at = min(at, len(data))
    p = tmp_path / "f.yml"
    p.write_bytes(data[:at] + junk + data[at:])
    try:
        drain(p)
    except UserError as e:
        assert "f.yml" in str(e)


@pytest.mark.parametrize("value", ["2147483648", "-2147483649", "99999999999999999999999"])
def test_value_beyond_32_bits_names_the_line(tmp_path, value):
    """An evdev value is an s32: a bigger one is damage (it was summed into the counts,
    and past int64 saturated silently)."""
    p, _, _ = _two_mice(tmp_path, n=20)
    lines = p.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("    - [") and i > 40)
    lines[k] = f"    - [  0,  1000,   2,   0, {value}]"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=rf"rec.yml:{k + 1}: .*signed 32-bit"):
        drain(p)


def test_values_at_the_32_bit_limits_are_kept(tmp_path):
    p, _, _ = _two_mice(tmp_path, n=20)
    lines = p.read_text().splitlines()

    def fields(ln):
        return [f.strip() for f in ln.split("[")[1].split("]")[0].split(",")]

    ks = [
        i
        for i, ln in enumerate(lines)
        if ln.startswith("    - [") and fields(ln)[2:4] == ["2", "0"]
    ]
    for k, v in zip(ks[:2], ("2147483647", "-2147483648"), strict=True):
        sec, usec = fields(lines[k])[:2]
        lines[k] = f"    - [{sec}, {usec}, 2, 0, {v}]"
    p.write_text("\n".join(lines) + "\n")
    cap = drain(p)
    dx = cap.motion[0][1]
    assert dx.max() == 2147483647 and dx.min() == -2147483648


def test_a_hand_written_recording_in_libinput_s_own_format():
    """tests/data/libinput-handwritten.yml is typed from libinput-record(1)'s FILE FORMAT:
    comment headers, a hid descriptor, udev properties, quirks, a "Current time" comment,
    libinput event entries between the evdev ones, MSC_SCAN and buttons, a keyboard.  Its
    counts, summed by hand from the file: REL_X -1 -3 +10 = 6, REL_Y 2 -12 +5 = -5, over
    4 motion frames at 0, 7.996 ms, 23.999 ms and 1.000003 s."""
    from pathlib import Path

    path = Path(__file__).parent / "data" / "libinput-handwritten.yml"
    cap = drain(path)
    assert [d.name for d in cap.devices] == [
        "Logitech USB Optical Mouse",
        "AT Translated Set 2 keyboard",
    ]
    mouse, keyboard = cap.devices
    assert mouse.rel_xy is True and keyboard.rel_xy is False
    assert (mouse.bus, mouse.vendor, mouse.product) == (3, 0x46D, 0xC077)
    assert mouse.extra["node"] == "/dev/input/event5"
    t, dx, dy = cap.motion[0]
    assert dx.tolist() == [-1, -3, 0, 10] and dy.tolist() == [2, 0, -12, 5]
    assert t.tolist() == pytest.approx([0.0, 0.007996, 0.023999, 1.000003], abs=1e-9)
    s = cap.stats[0]
    assert (s.net_x, s.net_y, s.frames, s.reports) == (6, -5, 5, 4)
    assert 1 not in cap.motion  # the keyboard is no mouse: no feed


def test_a_recording_laid_out_as_the_man_page_shows_it():
    """libinput-record(1)'s FILE FORMAT indents the devices under `devices:` and puts
    `- hid:` entries (one with a tab) among the evdev ones, with absinfo-free mouse codes
    and quirks: tests/data/libinput-indented.yml, typed by hand in that layout.  Counts
    by hand: REL_X 4 + 1 = 5, REL_Y -2, two motion frames."""
    from pathlib import Path

    cap = drain(Path(__file__).parent / "data" / "libinput-indented.yml")
    assert [d.name for d in cap.devices] == ["Test Optical Mouse"] and cap.devices[0].rel_xy
    t, dx, dy = cap.motion[0]
    assert dx.tolist() == [4, 1] and dy.tolist() == [-2, 0]
    assert t.tolist() == pytest.approx([0.0, 0.008])
    assert not cap.warnings


def _two_mice_text(n=4):
    rng = np.random.default_rng(8)
    t1 = np.cumsum(rng.uniform(0.001, 0.01, n))
    t2 = np.cumsum(rng.uniform(0.001, 0.01, n)) + 0.0005
    left = (t1, rng.integers(-9, 9, n), rng.integers(-9, 9, n))
    right = (t2, rng.integers(-9, 9, n), rng.integers(-9, 9, n))
    return format_libinput([("left", *left), ("right", *right)]), {"left": left, "right": right}


def _reports_of(t, dx, dy):
    keep = (dx != 0) | (dy != 0)
    rows = zip(t[keep], dx[keep], dy[keep], strict=True)
    return [(round(float(a), 6), int(b), int(c)) for a, b, c in rows]


def test_a_multi_device_recording_cut_anywhere_keeps_what_it_holds_and_says_so(tmp_path):
    """``ndevices: 2`` cut before its second device lost it without a word; cut inside
    the second device's header (``- node: /de``) it made a device named "/de"; cut
    inside a row of the first device it was "invalid YAML", exit 2, where a one-device
    file loses that row only.  At every cut from the first device's events list on: the
    devices read are the recorded ones (never one from a cut header), each gives the
    first of its reports exactly (the last may lack its REL_Y, as any unterminated frame),
    a device missing is said naming the file, and a row cut short is said naming its line
    (a whole row cut in its comment is kept)."""
    text, truth = _two_mice_text()
    raw = text.encode()
    p = tmp_path / "cut.yml"
    second = raw.index(b"- node: /dev/input/event6")
    for cut in range(raw.index(b"  events:") + len(b"  events:\n"), len(raw) + 1):
        p.write_bytes(raw[:cut])
        cap = drain(p)
        names = [d.name for d in cap.devices]
        assert names in (["left"], ["left", "right"]), (cut, names)
        lost = any(f"{p}: 2 devices recorded (ndevices), 1 in the file" in w
                   for w in cap.warnings)  # fmt: skip
        assert lost == (names == ["left"]), (cut, cap.warnings)
        assert (names == ["left"]) == (cut < second + raw[second:].index(b"  events:") + 9)
        for k, name in enumerate(names):
            t, dx, dy = cap.motion.get(k, (np.array([]), np.array([]), np.array([])))
            got = _reports_of(t, dx, dy)
            want = _reports_of(*truth[name])
            assert got[:-1] == want[: max(len(got) - 1, 0)], (cut, name)
            if got:
                last, full = got[-1], want[len(got) - 1]
                assert last[:2] == full[:2] and last[2] in (full[2], 0), (cut, name)
        tail = raw[raw.rfind(b"\n", 0, cut) + 1 : cut].strip()
        if tail.startswith(b"- [") and b"]" not in tail:  # a row cut before its end
            line = raw[:cut].count(b"\n") + 1
            assert any(f"cut.yml:{line}: last line cut off" in w for w in cap.warnings), cut


def test_a_cut_device_header_is_never_a_device(tmp_path):
    text, _ = _two_mice_text()
    at = text.index("- node: /dev/input/event6") + len("- node: /de")
    p = tmp_path / "cut.yml"
    p.write_text(text[:at])
    cap = open_capture(p)
    assert [d.name for d in cap.devices] == ["left"]
    line = text[:at].count("\n") + 1
    assert (
        f"{p}:{line}: the last device's header is cut off before its events list "
        "(truncated recording); that device is skipped" in cap.warnings
    )
    # a one-device file cut in its only header: an error naming the line, not a device
    at = text.index("- node: /dev/input/event5") + len("- node: /dev/input/event5\n  evd")
    p.write_text(text[:at])
    with pytest.raises(UserError, match=r"cut.yml:\d+: the recording is cut off in its first"):
        open_capture(p)


def test_replay_of_two_devices_cut_in_a_row_loses_that_row_only(tmp_path):
    from capture_helpers import one_mouse_config
    from conftest import run_mousedom

    text, truth = _two_mice_text(n=40)
    first_dev_end = text.index("- node: /dev/input/event6")
    at = text.rindex("    - [", 0, first_dev_end) + 9  # inside the first device's last row
    p = tmp_path / "cut.yml"
    p.write_text(text[:at])
    cfg = one_mouse_config(tmp_path, name="left")
    cfg.write_text(cfg.read_text() + f"    replay: {{file: {p}, device: /dev/input/event5}}\n")
    proc = run_mousedom("replay", "-c", str(cfg), "--capture", str(p))
    assert proc.returncode == 0, proc.stderr
    line = text[:at].count("\n") + 1
    assert f"cut.yml:{line}: last line cut off (truncated recording); skipped" in proc.stderr
    assert "2 devices recorded (ndevices), 1 in the file" in proc.stderr
    row = next(ln for ln in proc.stdout.splitlines() if ln.startswith("left "))
    assert int(row.split()[3]) == int(truth["left"][1].sum())  # the cut row was a SYN_REPORT


@pytest.mark.parametrize("first", ["evdev", "udev", "events", "node"])
def test_a_device_written_as_a_flow_mapping_is_read_whatever_key_comes_first(tmp_path, first):
    """A dumper that sorts keys writes '- {evdev: ..., node: ...}': the second device of
    two, so written, was taken for a recording cut before it (the flow-mapping test knew
    only 'node' first) and dropped (tests/regress/libinput-flow-device)."""
    import yaml

    header = "version: 1\nndevices: 2\nlibinput: {version: 1.25.0}\nsystem: {kernel: 6.8.0}\n"
    block = (
        "devices:\n- node: /dev/input/event5\n  evdev:\n    name: a\n"
        "    id: [3, 1133, 49271, 273]\n"
        "    codes: {0: [0], 2: [0, 1]}\n  events:\n"
        "  - evdev:\n    - [  0, 100000,   2,   0,     1]\n    - [  0, 100000,   0,   0,     0]\n"
    )
    device = {
        "node": "/dev/input/event6",
        "evdev": {"name": "b", "id": [3, 1133, 49272, 273], "codes": {0: [0], 2: [0, 1]}},
        "udev": {"properties": ["ID_INPUT_MOUSE=1"]},
        "events": [{"evdev": [[0, 150000, 2, 0, 5], [0, 150000, 0, 0, 0]]}],
    }
    ordered = {first: device[first], **{k: v for k, v in device.items() if k != first}}
    lines = yaml.safe_dump(ordered, default_flow_style=True, sort_keys=False, width=80)
    flow = "- " + lines.replace("\n", "\n  ").rstrip() + "\n"  # one list item, a flow mapping
    p = tmp_path / "two.yml"
    p.write_text(header + block + flow)
    cap = open_capture(str(p))
    assert [d.name for d in cap.devices] == ["a", "b"]
    assert not [w for w in cap.open_warnings if "cut off" in w]
    assert drain(p).stats[1].net_x == 5


def test_a_row_with_a_digit_separator_is_named_by_its_line(tmp_path):
    """int() reads "1_0" as 10: the quick checks refused such a row, and the search for
    the bad line took it, so the error named the block's first line, "malformed events"."""
    p, _, _ = _two_mice(tmp_path, n=20)
    lines = p.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("    - [") and i > 40)
    lines[k] = lines[k].rsplit(",", 1)[0] + ", 1_0]"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=rf"rec.yml:{k + 1}: an evdev event must be"):
        drain(p)


def test_a_recording_re_dumped_as_json_is_read(tmp_path):
    """docs/captures.md: a document as JSON is read.  JSON's keys are strings ("2" for
    EV_REL's codes), and the mouse was refused as "no REL_X/REL_Y motion"."""
    import json

    import yaml

    t = np.arange(1, 51) * 0.01
    text = format_libinput([("m", t, np.ones(50, int), -np.ones(50, int))])
    p = tmp_path / "rec.json"
    p.write_text(json.dumps(yaml.safe_load(text)))
    cap = drain(p)
    assert [d.rel_xy for d in cap.devices] == [True]
    t_read, dx, dy = cap.motion[0]
    assert len(t_read) == 50 and dx.sum() == 50 and dy.sum() == -50


@pytest.mark.parametrize("empty", [" []", " [ ]", " null", " Null", " NULL", " ~",
                                   " null  # none", " ~ "])  # fmt: skip
@pytest.mark.parametrize("alone", [False, True], ids=["after-another", "alone"])
def test_a_device_with_no_events_written_as_yaml_empties_is_no_truncation(tmp_path, empty, alone):
    """``events: []`` (what a re-dump by yq writes for a device without events), and the
    nulls a re-dump by PyYAML writes (``events: null``, found by the fuzzer), were taken
    for a device header cut off: an error with that device alone, false truncation
    warnings after another.  Every spelling YAML reads as an empty list or none is a
    device without events, wherever it stands."""
    t = np.arange(1, 51) * 0.01
    e = np.zeros(0)
    empty_dev = ("k", e, e.astype(int), e.astype(int))
    devices = [empty_dev] if alone else [("m", t, np.ones(50, int), np.zeros(50, int)),
                                         empty_dev]  # fmt: skip
    text = format_libinput(devices)
    p = tmp_path / "rec.yml"
    p.write_text(text.rstrip("\n") + empty + "\n")
    cap = drain(p)
    assert [d.name for d in cap.devices] == (["k"] if alone else ["m", "k"])
    if not alone:
        assert len(cap.motion[0][0]) == 50
    assert not any("cut off" in w or "recorded" in w for w in cap.warnings), cap.warnings


def test_one_over_long_field_is_refused_in_bounded_memory(tmp_path):
    """A row of a few hundred bytes at most is valid: one 60 MB digit field went through
    the array checks at about 21 times its size (a numpy MemoryError traceback under a
    memory limit).  It is the line's error now, before any array is made: past the bound
    of a capture's line (capture.base.MAX_LINE_BYTES)."""
    import resource
    import subprocess
    import sys

    from conftest import mousedom_env

    p, _, _ = _two_mice(tmp_path, n=20)
    lines = p.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("    - [") and i > 40)
    lines[k] = f"    - [  0,  1000,   2,   0, {'7' * (60 << 20)}]"
    p.write_text("\n".join(lines) + "\n")

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))

    out = subprocess.run([sys.executable, "-m", "mousedom", "convert", "--capture", str(p),
                          "-o", str(tmp_path / "out.mdcap")], capture_output=True, text=True,
                         timeout=120, env=mousedom_env(), preexec_fn=limit)  # fmt: skip
    assert out.returncode != 0 and "Traceback" not in out.stderr, out.stderr[-2000:]
    assert f"rec.yml:{k + 1}: a line longer than" in out.stderr, out.stderr[-500:]


@pytest.mark.parametrize("n_devices", [1, 2, 3])
@pytest.mark.parametrize("seed", range(4))
def test_a_device_with_two_events_lists_is_refused_at_the_second(tmp_path, n_devices, seed):
    """A device with two ``events:`` keys had both lists read: its counts summed twice
    over where YAML would keep one. Refused, naming the file and the second key's line,
    whichever device holds it and wherever in its events it stands."""
    rng = np.random.default_rng(seed)
    devices = []
    for k in range(n_devices):
        n = int(rng.integers(3, 30))
        t = np.cumsum(rng.uniform(0.001, 0.01, n))
        devices.append((f"m{k}", t, rng.integers(-9, 9, n), rng.integers(-9, 9, n)))
    lines = format_libinput(devices).splitlines(keepends=True)
    heads = [i for i, ln in enumerate(lines) if ln.lstrip().startswith("- node:")]
    which = int(rng.integers(n_devices))
    first = next(i for i in range(heads[which], len(lines)) if lines[i].strip() == "events:")
    end = heads[which + 1] if which + 1 < n_devices else len(lines)
    # The second list goes before one of the device's later rows, or at its end.
    rows = [i for i in range(first + 2, end) if lines[i].lstrip().startswith("- evdev")]
    at = int(rng.choice(rows + [end]))
    p = tmp_path / "rec.yml"
    p.write_text("".join(lines[:at] + [lines[first]] + lines[first + 1 : first + 5] + lines[at:]))
    with pytest.raises(UserError) as e:
        drain(p)
    assert str(e.value).startswith(f"{p}:{at + 1}: a second 'events:' list in one device")
    assert f"its first is at line {first + 1}" in str(e.value)
