"""Inputs at the edge of what a command can take: one line and a non-zero exit, no
traceback, bounded memory (found by a review of the capture commands)."""

from __future__ import annotations

import resource
import struct
import subprocess
import sys
import zlib

import pytest
from capture_helpers import one_mouse_config
from conftest import mousedom_env, run_mousedom

from mousedom.capture.native_format import MAGIC


def _native_with_header(path, body: bytes) -> None:
    """A native capture whose header is ``body`` (CRC right), no chunks."""
    path.write_bytes(MAGIC + struct.pack("<HHI", 1, 0, len(body)) + body
                     + struct.pack("<I", zlib.crc32(body)))  # fmt: skip


@pytest.mark.parametrize("where", ["top", "device"])
def test_a_native_header_nested_too_deep_is_one_line(tmp_path, where):
    """json's decoder recurses: a 400 kB header of brackets raised RecursionError, a
    traceback from replay and convert (NOTE chunks already caught it)."""
    deep = "[" * 100_000 + "]" * 100_000
    body = (deep if where == "top" else '{"devices": [' + deep + "]}").encode()
    path = tmp_path / "deep.mdcap"
    _native_with_header(path, body)
    cfg = one_mouse_config(tmp_path)
    out = str(tmp_path / "out.mdcap")
    for args in (["replay", "-c", str(cfg), "--capture", str(path)],
                 ["convert", "--capture", str(path), "-o", out]):  # fmt: skip
        p = run_mousedom(*args)
        assert p.returncode != 0 and "Traceback" not in p.stderr, p.stderr
        assert "deep.mdcap" in p.stderr and "byte offset 16" in p.stderr, p.stderr


def test_umbmark_reads_a_bounded_runs_csv_from_stdin():
    """``umbmark - < /dev/zero`` read without end: a MemoryError traceback under a memory
    limit (and a 23 MB RUNS.csv took 981 MB).  Past a RUNS.csv's bound: one line."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))

    with open("/dev/zero", "rb") as zero:
        p = subprocess.run([sys.executable, "-m", "mousedom", "umbmark", "-"], stdin=zero,
                           capture_output=True, text=True, timeout=60, env=mousedom_env(),
                           preexec_fn=limit)  # fmt: skip
    assert p.returncode != 0 and "Traceback" not in p.stderr, p.stderr
    assert "<stdin>: more than 1048576 bytes is no RUNS.csv" in p.stderr, p.stderr


def test_umbmark_refuses_a_file_past_the_bound(tmp_path):
    from mousedom.calibrate.umbmark import HEADER, MAX_RUNS_BYTES

    runs = tmp_path / "RUNS.csv"
    runs.write_text(HEADER + "\n" + "#" * MAX_RUNS_BYTES + "\n")
    p = run_mousedom("umbmark", str(runs))
    assert p.returncode != 0 and "Traceback" not in p.stderr, p.stderr
    assert "RUNS.csv: more than" in p.stderr, p.stderr


@pytest.mark.parametrize("speed", ["1e-17", "2e-12", "0.0009", "1e7", "nan", "inf", "0", "-1"])
def test_replay_speed_out_of_range_is_one_line(tmp_path, speed):
    """--speed 1e-17 passed the check (positive, finite) and the pacer's wait overflowed
    the clock: ``OverflowError: timestamp out of range``."""
    from mousedom.demo import DEMO_CONFIG  # (its mice replay the bundled capture)

    p = run_mousedom("replay", "-c", str(DEMO_CONFIG), "--speed", speed, timeout=60)
    assert p.returncode != 0 and "Traceback" not in p.stderr, p.stderr
    assert "--speed: must be from 0.001 to 1e+06" in p.stderr, p.stderr


def _numeric_options():
    """(subcommand path, option) of every option the CLI parses as a number."""
    import argparse

    from mousedom.cli import build_parser

    out = []

    def walk(parser, path):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, [*path, name])
            elif action.option_strings and action.type is not None and action.nargs is None:
                try:
                    action.type("2")
                except (argparse.ArgumentTypeError, ValueError, TypeError):
                    continue  # not a number at all (a path, a NAME=FILE)
                out.append((tuple(path), action.option_strings[-1]))

    walk(build_parser(), [])
    return out


NUMERIC = _numeric_options()


def test_every_numeric_option_is_found():
    names = {opt for _, opt in NUMERIC}
    assert {"--speed", "--rate", "--count", "--duration", "--timeout", "--angle"} <= names


@pytest.mark.parametrize("path,option", NUMERIC, ids=[" ".join(p) + o for p, o in NUMERIC])
def test_numeric_options_take_numbers_as_people_write_them(path, option, capsys):
    """float() and int() took "1_000", full-width and Arabic-Indic digits: numbers no
    user types and the CSV readers refuse.  Every numeric option refuses them, one line,
    exit 2 (argparse's own exit, before the command runs)."""
    from mousedom.cli import main

    for bad in ("1_0", "\uff12", "\u0663", "0x10"):
        with pytest.raises(SystemExit) as e:
            main([*path, option, bad])
        err = capsys.readouterr().err
        assert e.value.code == 2, (bad, err)
        assert f"argument {option}: not a" in err and repr(bad) in err, err
