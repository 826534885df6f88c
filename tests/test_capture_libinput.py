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
