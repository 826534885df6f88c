"""The compiled core (issue 28; csrc/*.c, mousedom/core.py) equals its Python reference
bit for bit, on generated streams, hostile bytes and any cut; it falls back to the Python
where its int64 sums would overflow; and a user can see and choose which core runs.

The compiled core's memory safety under AddressSanitizer and UBSan: test_core_sanitized.py."""

from __future__ import annotations

import math
import os
import struct
import subprocess
import sys

import cores
import pytest
from conftest import REPO, mousedom_env, run_mousedom
from hypothesis import given, settings
from hypothesis import strategies as st
from test_evdev_readpath import cut, records, to_bytes

from mousedom import core
from mousedom.fusion.countfunction import _ingest_loop
from mousedom.sources.events import _STAT_FIELDS, EV_REL, REL_X, SYN_REPORT, FrameAssembler

needs_core = pytest.mark.skipif(
    core.native is None and not cores.REQUIRED,
    reason="the compiled core is not built here (CI builds it: MOUSEDOM_REQUIRE_CORE=1)",
)


def test_the_core_is_built_where_ci_requires_it():
    """In CI (MOUSEDOM_REQUIRE_CORE=1) a missing compiled core is a failure, not a skip."""
    if cores.REQUIRED:
        assert core.native is not None, core.NAME
        assert core.NAME == "c"
    else:
        assert core.NAME == "c" or core.NAME.startswith("python (")


def _state(a: FrameAssembler) -> tuple:
    return (a._open_dx, a._open_dy, a._open_motion, a._open_dropped, a._open_events,
            a._open_nonsyn, struct.pack("<d", a._open_t), a.stats.as_dict())  # fmt: skip


def _run(name: str, chunks: list[bytes]) -> list:
    """Each read's frames (times as their bytes) and leftover, then the state and the flush."""
    a = FrameAssembler()
    out, rest = [], b""
    with cores.using(name):
        for chunk in chunks:
            t, dx, dy, rest = a.feed_bytes(rest + chunk)
            assert all(type(v) is float for v in t) and all(type(v) is int for v in dx + dy)
            out.append(([struct.pack("<d", v) for v in t], dx, dy, rest, _state(a)))
    f = a.flush()
    out.append((f.t.tobytes(), f.dx.tolist(), f.dy.tolist(), _state(a)))
    return out


@needs_core
@settings(max_examples=400, deadline=None)
@given(records, st.lists(st.integers(0, 24 * 120), max_size=10))
def test_feed_bytes_is_the_python_bit_for_bit(rows, offsets):
    """Events of every kind (SYN_DROPPED, other SYN, buttons, any type and code), values
    to the int32 limits, stamps running backwards or near 2^40 s, cut at any byte: the
    frames, times, leftovers, open frame and statistics are the Python's after every read."""
    chunks = list(cut(to_bytes(rows), offsets))
    assert _run("c", chunks) == _run("python", chunks)


@needs_core
@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=24 * 40), st.lists(st.integers(0, 24 * 40), max_size=6))
def test_feed_bytes_on_hostile_bytes_is_the_python(data, offsets):
    """Any bytes at all (negative seconds, microseconds beyond a second, keys no kernel
    sends), cut anywhere: the same as the Python, and nothing read past the buffer."""
    chunks = list(cut(data, offsets))
    assert _run("c", chunks) == _run("python", chunks)


def _rec(sec: int, usec: int, type_: int, code: int, value: int) -> bytes:
    return struct.pack("<qqHHi", sec, usec, type_, code, value)


@needs_core
@pytest.mark.parametrize("start", [2**63 - 5, -(2**63) + 5, 2**70])
def test_an_overflowing_sum_falls_back_to_the_python(start):
    """A frame whose REL_X sum leaves int64 (an open frame carried that far; no device gets
    there, but Python's integers do not overflow): the compiled core declines, the Python
    runs, and the result is the Python's exactly."""
    away, back = (2**31 - 1, -(2**31)) if start > 0 else (-(2**31), 2**31 - 1)
    data = _rec(1, 0, EV_REL, REL_X, away) * 3 + _rec(1, 0, EV_REL, REL_X, back) * 3
    data += _rec(1, 1, 0, SYN_REPORT, 0)
    assert core.native.feed_bytes(data, (start, 0, True, False, 1, 1, 0.0)) is None
    results = []
    for name in ("c", "python"):
        a = FrameAssembler()
        a._open_dx, a._open_motion, a._open_events, a._open_nonsyn = start, True, 1, 1
        with cores.using(name):
            results.append((a.feed_bytes(data), a.stats.as_dict()))
    assert results[0] == results[1]
    assert results[0][0][1] == [start + 3 * away + 3 * back]


@needs_core
def test_the_core_refuses_a_malformed_state_with_a_python_error():
    """The open frame it is handed is checked, not trusted."""
    with pytest.raises(ValueError, match="7 fields"):
        core.native.feed_bytes(b"", (0, 0))
    with pytest.raises(TypeError):
        core.native.feed_bytes(b"", (0, 0, False, False, 0, 0, "t"))
    with pytest.raises(TypeError):
        core.native.feed_bytes("not bytes", (0, 0, False, False, 0, 0, 0.0))
    empty = (0, 0, False, False, 0, 0, 0.0)
    frame = struct.pack("<qqHHi", 1, 5, EV_REL, REL_X, 7) + struct.pack("<qqHHi", 1, 5, 0, 0, 0)
    stats = FrameAssembler().stats
    with pytest.raises(TypeError, match="go together"):
        core.native.feed_bytes(frame, empty, stats)
    with pytest.raises(ValueError, match="11 stats"):
        core.native.feed_bytes(frame, empty, stats, ("events",))
    with pytest.raises(AttributeError):
        core.native.feed_bytes(frame, empty, object(), _STAT_FIELDS)
    assert core.native.feed_bytes(frame, empty, stats, _STAT_FIELDS)[5] is None
    assert (stats.events, stats.frames, stats.rel_x_in, stats.rel_y_in) == (2, 1, 7, 0)


def _version(env_core: str | None) -> subprocess.CompletedProcess:
    env = mousedom_env()
    env.pop("MOUSEDOM_CORE", None)
    if env_core is not None:
        env["MOUSEDOM_CORE"] = env_core
    return run_mousedom("--version", env=env)


def test_version_says_which_core_runs_and_the_switch_forces_the_python():
    out = _version(None)
    assert out.returncode == 0
    assert f"(core: {core.NAME})" in out.stdout
    forced = _version("python")
    assert forced.returncode == 0
    assert "(core: python (MOUSEDOM_CORE=python))" in forced.stdout


def test_a_wrong_switch_value_is_a_clear_error():
    out = _version("fortran")
    assert out.returncode == 2
    assert "MOUSEDOM_CORE='fortran': expected 'c' or 'python'" in out.stderr
    assert "Traceback" not in out.stderr


def test_requiring_the_compiled_core_where_it_is_missing_is_a_clear_error(tmp_path):
    """MOUSEDOM_CORE=c on a checkout without the built module: exit 2, one line, what to do.
    (A copy of the package without its compiled module stands for such a machine.)"""
    import shutil

    pkg = tmp_path / "mousedom"
    shutil.copytree(REPO / "mousedom", pkg, ignore=shutil.ignore_patterns("_core*", "__pycache__"))
    env = {**os.environ, "MOUSEDOM_CORE": "c", "PYTHONPATH": str(tmp_path)}
    # The copy's `mousedom._core`, not found in it, fell through to an editable install's
    # finder (pip install -e: a meta path finder mapping the package to the checkout),
    # which loaded the checkout's: the copy is run without such finders.
    run_copy = ("import runpy, sys; sys.argv = ['mousedom', '--version']; "
                "sys.meta_path[:] = [f for f in sys.meta_path "
                "if 'Editable' not in getattr(f, '__name__', type(f).__name__)]; "
                "runpy.run_module('mousedom', run_name='__main__', alter_sys=True)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", run_copy], env=env,
                         capture_output=True, text=True, cwd=tmp_path, timeout=60)  # fmt: skip
    assert out.returncode == 2, out.stderr
    assert "MOUSEDOM_CORE=c, but the compiled core does not load" in out.stderr
    assert "docs/install.md" in out.stderr and "Traceback" not in out.stderr
    env["MOUSEDOM_CORE"] = ""
    out = subprocess.run([sys.executable, "-c", run_copy], env=env,
                         capture_output=True, text=True, cwd=tmp_path, timeout=60)  # fmt: skip
    assert out.returncode == 0 and "(core: python (no compiled core built))" in out.stdout


# ----------------------------------------------------------------- reports -> knots

stamps = st.floats(-1.0, 1.0, allow_nan=False).map(lambda v: round(v, 4))
whole = st.integers(-(2**31), 2**31 - 1) | st.integers(-40, 40)
counts = st.lists(whole, min_size=1, max_size=40) | st.lists(
    st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=40
)


@st.composite
def ingests(draw):
    """(t, dx, dy, kt, kx, ky, knot_t, edge, period, bridge, join) as the tracker hands
    them: reports in any order (stamps running backwards, behind the edge, bunched or far
    apart), counts whole or fractional per axis, knots already held."""
    dx = draw(counts)
    n = len(dx)
    dy = draw(st.lists(whole, min_size=n, max_size=n) | st.lists(
        st.floats(-1e6, 1e6, allow_nan=False), min_size=n, max_size=n))  # fmt: skip
    t = sorted(draw(st.lists(stamps, min_size=n, max_size=n)))
    for k in draw(st.lists(st.integers(0, n - 1), max_size=3)):  # a few run backwards
        t[k] = draw(stamps)
    nk = draw(st.integers(0, 3)) * 2
    kt = sorted(draw(st.lists(stamps, min_size=nk, max_size=nk)))
    kx = [float(v) for v in draw(st.lists(st.integers(-100, 100), min_size=nk, max_size=nk))]
    ky = [float(v) for v in draw(st.lists(st.integers(-100, 100), min_size=nk, max_size=nk))]
    knot_t = kt[-1] if kt and draw(st.booleans()) else draw(stamps | st.just(-math.inf))
    edge = draw(stamps | st.just(-math.inf))
    period = draw(st.sampled_from([0.001, 0.002, 0.008]))
    bridge = max(period, draw(st.sampled_from([0.0, 0.1, 0.15])))
    return (t, dx, dy, kt, kx, ky, knot_t, edge, period, bridge, 0.5 * period)


def _bits(values: list) -> list:
    return [struct.pack("<d", v) if isinstance(v, float) else ("int", v) for v in values]


@needs_core
@settings(max_examples=400, deadline=None)
@given(ingests())
def test_ingest_small_is_the_python_bit_for_bit(case):
    """The knots (appended and joined), the sums (ints stay ints), the counts of reports
    run backwards and behind the edge, and the last stamp: the Python's, bit for bit."""
    t, dx, dy, kt, kx, ky, *rest = case
    py_lists = [kt[:], kx[:], ky[:]]
    c_lists = [kt[:], kx[:], ky[:]]
    want = _ingest_loop(t, dx, dy, *py_lists, *rest)
    got = core.native.ingest_small(t, dx, dy, *c_lists, *rest)
    assert got is not None
    assert _bits(list(got)) == _bits(list(want))
    assert [_bits(v) for v in c_lists] == [_bits(v) for v in py_lists]


@needs_core
@pytest.mark.parametrize(
    "dx",
    [[1, 2.5], [True, 1], [2**63, 1], [2**62, 2**62], [1, "x"]],
    ids=["mixed", "bool", "too-big", "sum-too-big", "not-a-number"],
)
def test_ingest_small_declines_what_it_cannot_do_exactly_and_touches_nothing(dx):
    """Counts that are not all ints or all floats on an axis, or int sums beyond int64:
    None, the knot lists as they were (the Python then runs, with Python's numbers)."""
    kt, kx, ky = [0.0, 0.001], [0.0, 1.0], [0.0, 0.0]
    lists = (kt[:], kx[:], ky[:])
    got = core.native.ingest_small([0.002, 0.003], dx, [0, 0], *lists, 0.001, 0.0, 0.001,
                                   0.1, 0.0005)  # fmt: skip
    assert got is None
    assert lists == (kt, kx, ky)


stamp_values = st.floats(99.0, 101.5) | st.sampled_from(
    [math.nan, math.inf, -math.inf, 0.0, 1e300, 40.0, 38.9, 101.0]
)


@needs_core
@settings(max_examples=400, deadline=None)
@given(st.lists(stamp_values, max_size=40), st.floats(99.0, 101.0),
       st.floats(99.0, 101.0) | st.sampled_from([-math.inf, math.nan]))  # fmt: skip
def test_forward_list_is_the_python_bit_for_bit(t, now, last):
    """A read's stamps: far ones (and NaN) re-stamped to the read's time, then made
    non-decreasing, in place; the counts and the largest distance the same."""
    from mousedom.sources.base import forward_list

    out = {}
    for name in cores.names():
        lst = list(t)
        with cores.using(name):
            far, worst, moved = forward_list(lst, now, last)
        out[name] = ([struct.pack("<d", v) for v in lst], far, struct.pack("<d", worst), moved)
    assert len(set(map(repr, out.values()))) == 1, out


@needs_core
def test_forward_list_declines_other_than_floats_and_changes_nothing():
    lst = [1.0, 2, 0.5]
    assert core.native.forward_list(lst, 1.0, 0.0, 60.0, 1.0) is None
    assert lst == [1.0, 2, 0.5]
    assert core.native.forward_list([1.0], 1, 0.0, 60.0, 1.0) is None


# evemu event lines (csrc/evemu.c): valid lines of any widths built from pieces, and now
# and then one piece of one line swapped for a near miss (a width past the limit, a tab
# for a space, a stray byte, no point, a sign alone, junk after the value), so that both
# sides of every rule are drawn.
_VALID_PIECES = (
    st.just("E: "),
    st.text("0123456789", min_size=1, max_size=12),
    st.just("."),
    st.text("0123456789", min_size=1, max_size=9),
    st.just(" "), st.text("0123456789abcdefABCDEF", min_size=1, max_size=4),
    st.just(" "), st.text("0123456789abcdefABCDEF", min_size=1, max_size=4),
    st.just(" "),
    st.sampled_from(["", "-", "+"]),
    st.text("0123456789", min_size=1, max_size=9),
    st.sampled_from(["", " ", "\t# EV_REL / REL_X 5", "  # c", " \r", " # é", "\t#"]),
)  # fmt: skip
_NEAR_MISS = st.one_of(
    st.sampled_from(["", "E:", "E:\t", "e: ", "N: ", "E:  ", "..", "\t", "  ", "\r", "--",
                     "+-", " x", "#", "x", "\x00", "é", "0" * 13, "1" * 10, "f" * 5]),
    st.text("0123456789", min_size=10, max_size=14),
    st.integers(-(2**33), 2**33).map(str),
    st.text(max_size=3),
)  # fmt: skip
_evemu_piece_line = st.tuples(*_VALID_PIECES).map(list)


@st.composite
def _evemu_block(draw) -> str:
    lines = draw(st.lists(_evemu_piece_line, min_size=0, max_size=12))
    if lines and draw(st.booleans()):
        line = lines[draw(st.integers(0, len(lines) - 1))]
        line[draw(st.integers(0, len(line) - 1))] = draw(_NEAR_MISS)
    return "".join("".join(line) + "\n" for line in lines)


def _as_events(ev) -> tuple | None:
    if ev is None:
        return None
    return tuple(getattr(ev, k).tobytes() for k in ("t", "typ", "code", "value", "line"))


@needs_core
@settings(max_examples=1500, deadline=None)
@given(_evemu_block(), st.binary(max_size=3))
def test_evemu_events_is_general_events_bit_for_bit(text, tail):
    """The compiled scanner takes exactly the blocks general_events takes, with the same
    columns bit for bit (times from any width of fraction), and refuses the others (the
    line parser then names the bad line); also for a block not ending in a newline."""
    from mousedom.capture.evemu_lines import general_events, native_events

    block = text.encode("utf-8", "surrogatepass")
    for data in (block, block + tail):
        want = _as_events(general_events(data, 5))
        got = _as_events(native_events(core.native, memoryview(data), 5))
        assert got == want


@needs_core
@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(0, 10**12 - 1), st.integers(0, 999_999_999), st.integers(1, 9),
            st.integers(0, 0xFFFF), st.integers(0, 0xFFFF), st.integers(-(2**31), 2**31 - 1),
        ),
        min_size=1, max_size=30,
    )
)  # fmt: skip
def test_evemu_events_takes_every_valid_line_as_the_line_parser_reads_it(lines):
    """Every valid line of any widths (within the parsers' limits) is taken, and its time,
    type, code and value are the line parser's (the specification) bit for bit."""
    from mousedom.capture.evemu_lines import native_events, slow_events

    text = "".join(
        f"E: {sec}.{frac % 10**w:0{w}d} {ty:x} {co:04X} {va:+d}\n"
        for sec, frac, w, ty, co, va in lines
    )
    block = text.encode()
    got = native_events(core.native, block, 1)
    assert got is not None
    assert _as_events(got) == _as_events(slow_events("x", block, 1, at_eof=False))


@needs_core
@pytest.mark.parametrize("cut", range(1, 12))
def test_a_last_line_cut_inside_its_number_is_refused_by_both_and_skipped_by_both(tmp_path, cut):
    """A recording whose last line was cut (no newline; "... 0000 12" of "... 1234"
    still reads as an event): no scanner takes that block, the compiled one as the
    Python ones, and the reader on either core skips the line with the same warning and
    the same counts (the whole lines only)."""
    from capture_helpers import drain

    from mousedom.capture.evemu_lines import general_events, native_events, regular_events

    whole = b"E: 0.000000 0002 0000 7\nE: 0.000000 0000 0000 0\n"
    last = b"E: 0.008000 0002 0000 1234\t# EV_REL / REL_X"
    block = whole + last[: len(last) - cut]
    assert general_events(block, 1) is None and regular_events(block, 1) is None
    assert native_events(core.native, block, 1) is None
    p = tmp_path / "cut.evemu"
    p.write_bytes(b"N: M\nB: 02 03 00 00 00 00 00 00 00\n" + block)
    got = []
    for name in cores.names():
        with cores.using(name):
            cap = drain(p)
        got.append((cap.stats[0].as_dict(), cap.warnings))
    assert got[0] == got[-1]
    stats, warnings = got[0]
    assert (stats["net_x"], stats["reports"]) == (7, 1)
    assert warnings == [f"{p}:5: last line cut off (truncated recording); skipped"]


@needs_core
def test_evemu_events_refuses_outputs_too_short_with_a_python_error():
    import numpy as np

    block = b"E: 1.000001 0002 0000 5\n" * 3
    short = np.empty(0)
    with pytest.raises(ValueError, match="too short"):
        core.native.evemu_events(block, short, short, short, short)
