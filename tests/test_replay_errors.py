"""``mousedom replay`` / ``convert`` on outputs that fail and inputs that are wrong: one
clear line and a non-zero exit, never a traceback (real processes)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from capture_helpers import external_dir, one_mouse_config
from conftest import mousedom_env, run_mousedom

PS2 = "evemu-devices__PS2_Generic_Mouse.events"

needs_dev_full = pytest.mark.skipif(
    not os.path.exists("/dev/full") and not os.environ.get("CI"), reason="no /dev/full"
)


def _one_error_line(stderr: str, *needles: str) -> str:
    assert "Traceback" not in stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("mousedom: error:"), stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@needs_dev_full
def test_replay_csv_to_a_full_disk_is_one_line(tmp_path):
    cfg = one_mouse_config(tmp_path, rate=1000)
    proc = run_mousedom(
        "replay", "--config", str(cfg), "--capture", f"m={external_dir() / PS2}", "-o", "/dev/full"
    )
    assert proc.returncode != 0
    _one_error_line(proc.stderr, "/dev/full", "cannot write")


@needs_dev_full
@pytest.mark.parametrize("extra", [("-o", "-"), ()], ids=["csv", "summary"])
def test_replay_stdout_on_a_full_disk_is_one_line(tmp_path, extra):
    cfg = one_mouse_config(tmp_path, rate=1000)
    with open("/dev/full", "w") as full:
        proc = subprocess.run(
            [sys.executable, "-m", "mousedom", "replay", "--config", str(cfg)]
            + ["--capture", f"m={external_dir() / PS2}", *extra],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            env=mousedom_env(),
            timeout=120,
        )
    assert proc.returncode != 0
    _one_error_line(proc.stderr, "<stdout>", "cannot write")


@needs_dev_full
def test_convert_to_a_full_disk_or_missing_folder_is_one_line(tmp_path):
    src = f"m={external_dir() / PS2}"
    for out in ("/dev/full", str(tmp_path / "no" / "such" / "x.mdcap")):
        proc = run_mousedom("convert", "--capture", src, "-o", out)
        assert proc.returncode != 0
        _one_error_line(proc.stderr, out, "cannot write")


def test_convert_that_fails_half_way_leaves_no_short_capture(tmp_path):
    """A bad line deep in the input: no output file (it would replay as a short run
    without a word), and an older output of the same name is kept."""
    lines = (external_dir() / PS2).read_text().splitlines()
    at = len(lines) // 2
    lines.insert(at, "garbage")
    bad = tmp_path / "bad.events"
    bad.write_text("\n".join(lines) + "\n")
    (tmp_path / "bad.desc").write_bytes((external_dir() / PS2).with_suffix(".desc").read_bytes())
    out = tmp_path / "out.mdcap"
    proc = run_mousedom("convert", "--capture", f"m={bad}", "-o", str(out))
    assert proc.returncode != 0
    _one_error_line(proc.stderr, f"bad.events:{at + 1}:")
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.desc", "bad.events"]
    out.write_bytes(b"older")
    proc = run_mousedom("convert", "--capture", f"m={bad}", "-o", str(out))
    assert proc.returncode != 0 and out.read_bytes() == b"older"
