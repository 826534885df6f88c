"""Text captures (evemu, libinput record) refuse a line longer than MAX_LINE_BYTES, naming
it, wherever it stands and whatever the reader's block size.

The readers carry a partial line from one block to the next: one line of hundreds of
megabytes was copied again with every block read (a 400 MB comment: 22 s and 1.7 GB for
evemu, 40 s for libinput), and evemu's header held its lines whole (a 300 MB comment:
0.9 GB).  The bound here is made small so that the files stay small; the CLI test uses
the real one."""

from __future__ import annotations

import numpy as np
import pytest
from capture_helpers import drain
from conftest import run_mousedom

from mousedom.capture import base
from mousedom.capture.evemu import EvemuCapture, format_evemu
from mousedom.capture.libinput import LibinputCapture, format_libinput
from mousedom.errors import UserError

LIMIT = 2000  # MAX_LINE_BYTES in these tests


@pytest.fixture
def small_limit(monkeypatch):
    monkeypatch.setattr(base, "MAX_LINE_BYTES", LIMIT)


def _motion(seed: int, n: int = 200):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.001, 0.01, n))
    return t, rng.integers(1, 9, n), rng.integers(-9, 9, n)


def _long(kind: str, size: int) -> str:
    """A line of ``size`` bytes without its newline: a comment, or an event whose value
    is zero-padded (a value the careful parser reads)."""
    if kind == "comment":
        return "# " + "x" * (size - 2)
    head = "E: 9.000000 0002 0000 "
    return head + "0" * (size - len(head) - 1) + "1"


def _evemu_lines(seed: int) -> list[str]:
    return format_evemu(*_motion(seed), name="m").splitlines(keepends=True)


def _libinput_lines(seed: int) -> list[str]:
    return format_libinput([("m", *_motion(seed))]).splitlines(keepends=True)


def _drain(fmt: str, path, block: int):
    cls = EvemuCapture if fmt == "evemu" else LibinputCapture
    cap = cls(str(path), block_bytes=block)
    for feed in cap.feeds():
        for _ in feed.batches:
            pass
    return cap


PLACES = {"evemu": ("header", "events", "last"), "libinput": ("header", "events", "last")}
CASES = [(fmt, where) for fmt, places in PLACES.items() for where in places]


@pytest.mark.parametrize("fmt,where", CASES)
@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("block", [97, 1500, 4096, 1 << 20])
def test_a_line_past_the_bound_is_refused_by_its_line_whatever_the_block(
    tmp_path, small_limit, fmt, where, seed, block
):
    rng = np.random.default_rng(seed)
    lines = _evemu_lines(seed) if fmt == "evemu" else _libinput_lines(seed)
    first_event = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith(("E:", "- evdev")))
    kind = "comment" if where == "header" or fmt == "libinput" else str(
        rng.choice(["comment", "event"]))  # fmt: skip
    size = LIMIT + int(rng.integers(1, 3 * LIMIT))
    text = ("  " if fmt == "libinput" and where != "header" else "") + _long(kind, size)
    if where == "header":
        at = int(rng.integers(1, first_event))
    elif where == "events":
        at = int(rng.integers(first_event + 1, len(lines)))
    else:
        at = len(lines)
    lines.insert(at, text + ("" if where == "last" else "\n"))
    p = tmp_path / ("m.evemu" if fmt == "evemu" else "m.yml")
    p.write_text("".join(lines))
    with pytest.raises(UserError) as e:
        _drain(fmt, p, block)
    assert str(e.value) == f"{p}:{at + 1}: a line longer than {LIMIT} bytes: not a capture's line"


@pytest.mark.parametrize("fmt", ["evemu", "libinput"])
@pytest.mark.parametrize("block", [97, 1500, 4096])
def test_lines_up_to_the_bound_are_read(tmp_path, small_limit, fmt, block):
    """A comment of exactly the bound (its newline not counted), in the header and among
    the events: the same reports as without it."""
    lines = _evemu_lines(5) if fmt == "evemu" else _libinput_lines(5)
    p = tmp_path / ("m.evemu" if fmt == "evemu" else "m.yml")
    p.write_text("".join(lines))
    want = drain(p).motion[0]
    first_event = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith(("E:", "- evdev")))
    pad = "  " if fmt == "libinput" else ""
    lines.insert(first_event + 3, pad + _long("comment", LIMIT - len(pad)) + "\n")
    lines.insert(1, _long("comment", LIMIT) + "\n")
    p.write_text("".join(lines))
    cap = _drain(fmt, p, block)
    assert cap.stats[0].net_x == int(want[1].sum())
    for a, b in zip(drain(p).motion[0], want, strict=True):
        np.testing.assert_array_equal(a, b)


def test_too_much_header_before_the_first_event_is_refused(tmp_path):
    """Many short comment lines before the first event were all held (a file of nothing
    else grew without bound); a header past a device description's bound is refused."""
    lines = _evemu_lines(1)
    lines[1:1] = ["# " + "y" * 60 + "\n"] * 20_000
    p = tmp_path / "m.evemu"
    p.write_text("".join(lines))
    with pytest.raises(UserError, match=r"m\.evemu:\d+: more than 1048576 bytes before the first"):
        drain(p)


@pytest.mark.parametrize("fmt", ["evemu", "libinput"])
def test_the_cli_refuses_a_long_line_in_one_line(tmp_path, fmt):
    lines = _evemu_lines(2) if fmt == "evemu" else _libinput_lines(2)
    k = len(lines) // 2
    lines.insert(k, "  # " + "z" * (3 << 20) + "\n")
    p = tmp_path / ("m.evemu" if fmt == "evemu" else "m.yml")
    p.write_text("".join(lines))
    out = run_mousedom("convert", "--capture", str(p), "-o", str(tmp_path / "out.mdcap"))
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().splitlines() == [
        f"mousedom: error: {p}:{k + 1}: a line longer than {base.MAX_LINE_BYTES} bytes: "
        "not a capture's line"
    ]
